# Bullet 3.24 (libbullet-dev) through CMake's own FindBullet (its version string comes back
# empty; Bullet reports btGetVersion() at run time). The single-precision libraries: the
# headers are used without BT_USE_DOUBLE_PRECISION.
find_package(Bullet)
if(BULLET_FOUND)
  target_sources(phys_peers PRIVATE ${CMAKE_CURRENT_LIST_DIR}/bullet_peer.cpp)
  target_include_directories(phys_peers SYSTEM PRIVATE ${BULLET_INCLUDE_DIRS})
  target_link_libraries(phys_peers PRIVATE ${BULLET_LIBRARIES})
  target_compile_definitions(phys_peers PUBLIC PHYS_PEER_BULLET)
endif()
