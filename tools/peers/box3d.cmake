# Box3D (github.com/erincatto/box3d, MIT) from a source tree outside the repository:
# -DPHYS_BOX3D_DIR=<a Box3D checkout>. There is no package of it to find: Box3D is built here,
# from that tree, as a static library. Empty (the default): no Box3D peer, nothing else changes.
# docs/PEERS.md says how to get the tree and which commit was measured.
if(NOT PHYS_BOX3D_DIR)
  return()
endif()
if(NOT EXISTS ${PHYS_BOX3D_DIR}/include/box3d/box3d.h OR NOT EXISTS ${PHYS_BOX3D_DIR}/src/CMakeLists.txt)
  message(FATAL_ERROR "PHYS_BOX3D_DIR=${PHYS_BOX3D_DIR} is not a Box3D source tree "
                      "(no include/box3d/box3d.h and src/CMakeLists.txt there)")
endif()

# Box3D's own options, as a library inside another project: no samples, unit tests,
# benchmarks, docs, validation or Tracy profiling (most are defined only when Box3D is the
# top-level project; set here too so that they stay off whatever its CMake does). Single
# precision (b3Pos is a float vector, as our Vec3). SIMD: Box3D's default, i.e. SSE2 on
# x86-64 and NEON on arm64; its CMake offers only BOX3D_DISABLE_SIMD (scalar), no AVX switch.
set(BOX3D_SAMPLES OFF)
set(BOX3D_UNIT_TESTS OFF)
set(BOX3D_BENCHMARKS OFF)
set(BOX3D_DOCS OFF)
set(BOX3D_VALIDATE OFF)
set(BOX3D_PROFILE OFF)
set(BOX3D_BUILD_SHADERS OFF)
set(BOX3D_DISABLE_SIMD OFF)
set(BOX3D_DOUBLE_PRECISION OFF)
set(BOX3D_SANITIZE OFF)
# Box3D's CMakeLists would otherwise put FETCHCONTENT_BASE_DIR (FetchContent's download
# cache, unused here) into our cache, pointing into our source tree.
set(FETCHCONTENT_BASE_DIR ${CMAKE_BINARY_DIR}/_deps)
set(CMAKE_POLICY_DEFAULT_CMP0077 NEW)  # option() keeps the variables above
add_subdirectory(${PHYS_BOX3D_DIR} ${CMAKE_BINARY_DIR}/box3d EXCLUDE_FROM_ALL)

# Release-like whatever our build type: Box3D's Release is -O3 -DNDEBUG. Its CMake turns its
# assertions on in RelWithDebInfo (B3_ENABLE_ASSERT, PUBLIC); measured as a peer it runs as a
# game ships it, without them.
foreach(prop COMPILE_DEFINITIONS INTERFACE_COMPILE_DEFINITIONS)
  get_target_property(defs box3d ${prop})
  if(defs)
    list(FILTER defs EXCLUDE REGEX "B3_ENABLE_ASSERT")
    set_target_properties(box3d PROPERTIES ${prop} "${defs}")
  endif()
endforeach()
target_compile_options(box3d PRIVATE -O3)
target_compile_definitions(box3d PRIVATE NDEBUG)

target_sources(phys_peers PRIVATE ${CMAKE_CURRENT_LIST_DIR}/box3d_peer.cpp)
target_link_libraries(phys_peers PRIVATE box3d)
target_compile_definitions(phys_peers PUBLIC PHYS_PEER_BOX3D)
message(STATUS "Box3D peer: built from ${PHYS_BOX3D_DIR}")
