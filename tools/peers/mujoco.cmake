# MuJoCo 2.2.2 (libmujoco-dev) through its CMake package (no .pc file). Its imported target
# names /usr/include/libqhull_r/ as an include directory, which exists only with libqhull-dev
# installed; a missing one would fail the whole configure, so the peer is skipped instead.
find_package(mujoco CONFIG QUIET)
if(TARGET mujoco::mujoco)
  get_target_property(MUJOCO_INCLUDES mujoco::mujoco INTERFACE_INCLUDE_DIRECTORIES)
  set(MUJOCO_MISSING_INCLUDES)
  foreach(dir ${MUJOCO_INCLUDES})
    if(NOT EXISTS ${dir})
      list(APPEND MUJOCO_MISSING_INCLUDES ${dir})
    endif()
  endforeach()
endif()
if(NOT TARGET mujoco::mujoco)
  message(STATUS "MuJoCo (find_package(mujoco)) not found: the MuJoCo peer is not built")
elseif(MUJOCO_MISSING_INCLUDES)
  message(STATUS "MuJoCo's target needs ${MUJOCO_MISSING_INCLUDES} (install libqhull-dev): "
                 "the MuJoCo peer is not built")
else()
  target_sources(phys_peers PRIVATE ${CMAKE_CURRENT_LIST_DIR}/mujoco_peer.cpp)
  target_link_libraries(phys_peers PRIVATE mujoco::mujoco)
  target_compile_definitions(phys_peers PUBLIC PHYS_PEER_MUJOCO)
endif()
