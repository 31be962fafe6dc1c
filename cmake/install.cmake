# `cmake --install build [--prefix P]`: the client SDK as a package (docs/CLIENT.md "Linking
# the SDK from another project").
#
#   lib/libphysclient.a, libphys_protocol.a          the SDK (phys::client, on phys::defs)
#   lib/libphys_core.a (+ libphys_gpu.a when built)  the engine (phys::core), a component
#   include/phys/...                 the definitions', the SDK's, the protocol's and the
#                                    engine's public headers
#   lib/cmake/phys/physConfig.cmake  find_package(phys CONFIG): phys::client;
#                                    find_package(phys CONFIG COMPONENTS core): phys::core too
#   lib/pkgconfig/phys-client.pc     pkg-config --cflags --libs phys-client
#
# Static libraries, as in the tree: a program that links phys::client carries the SDK and
# needs at run time only the system's shared libraries of Cyclone DDS and OpenSSL; nothing of
# the engine (no Eigen, qhull or Vulkan: phys::defs is headers of plain data). phys::core is
# the engine, for programs that step worlds in process; only it asks for qhull and Vulkan.
include(GNUInstallDirs)
include(CMakePackageConfigHelpers)

# Two export sets: the client's (physTargets.cmake) and the engine's (physCoreTargets.cmake),
# so that importing the client never names a target of the engine's dependencies.
set(_phys_client_targets phys_defs phys_protocol physclient)
set(_phys_core_targets phys_core)
if(TARGET phys_gpu)
  list(APPEND _phys_core_targets phys_gpu)
endif()
# The installed headers are C++20 (std::span, concepts): the exported targets say so, so a
# project that sets no standard of its own compiles them (CMake adds -std=c++20 or newer).
# phys_defs says it itself (physics/CMakeLists.txt).
foreach(_t phys_protocol physclient ${_phys_core_targets})
  target_compile_features(${_t} PUBLIC cxx_std_20)
endforeach()
install(TARGETS ${_phys_client_targets} EXPORT physTargets
        ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR}
        INCLUDES DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
install(TARGETS ${_phys_core_targets} EXPORT physCoreTargets
        ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR}
        INCLUDES DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})

# Headers: every room's include/ tree merges into include/phys/.
foreach(_dir client_sdk/include protocol/include physics/defs/include physics/collision/include
             physics/world/include)
  install(DIRECTORY ${PROJECT_SOURCE_DIR}/${_dir}/ DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
endforeach()
if(TARGET phys_gpu)
  install(DIRECTORY ${PROJECT_SOURCE_DIR}/gpu_solver/include/ DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
endif()
# Generated: the FlatBuffers schema's header and the DDS envelope's (included as "envelope.h").
install(FILES ${PROJECT_BINARY_DIR}/protocol/generated/phys/protocol/physics_generated.h
        DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/phys/protocol)
install(FILES ${PROJECT_BINARY_DIR}/protocol/envelope.h DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})

set(_phys_cmake_dir ${CMAKE_INSTALL_LIBDIR}/cmake/phys)
install(EXPORT physTargets NAMESPACE phys:: DESTINATION ${_phys_cmake_dir})
install(EXPORT physCoreTargets NAMESPACE phys:: DESTINATION ${_phys_cmake_dir})
if(TARGET phys_gpu)
  set(PHYS_PACKAGE_WITH_GPU ON)
else()
  set(PHYS_PACKAGE_WITH_GPU OFF)
endif()
configure_package_config_file(${PROJECT_SOURCE_DIR}/cmake/physConfig.cmake.in
                              ${PROJECT_BINARY_DIR}/physConfig.cmake
                              INSTALL_DESTINATION ${_phys_cmake_dir})
write_basic_package_version_file(${PROJECT_BINARY_DIR}/physConfigVersion.cmake
                                 COMPATIBILITY SameMinorVersion)
install(FILES ${PROJECT_BINARY_DIR}/physConfig.cmake ${PROJECT_BINARY_DIR}/physConfigVersion.cmake
        DESTINATION ${_phys_cmake_dir})

# pkg-config: static libraries, so every library the SDK needs is in Libs (none of the engine).
set(PHYS_PC_LIBS "-lphysclient -lphys_protocol -lddsc -lflatbuffers -lcrypto -lpthread")
# Relocatable: the .pc finds the prefix from its own folder, so --prefix at install time works.
file(RELATIVE_PATH PHYS_PC_TO_PREFIX /p/${CMAKE_INSTALL_LIBDIR}/pkgconfig /p)
configure_file(${PROJECT_SOURCE_DIR}/cmake/phys-client.pc.in ${PROJECT_BINARY_DIR}/phys-client.pc
               @ONLY)
install(FILES ${PROJECT_BINARY_DIR}/phys-client.pc DESTINATION ${CMAKE_INSTALL_LIBDIR}/pkgconfig)
