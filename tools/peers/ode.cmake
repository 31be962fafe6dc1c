# ODE 0.16 (libode-dev) through pkg-config only (no CMake package). Debian's build is double
# precision: ode.pc has no -DdDOUBLE in its Cflags but a `precision` variable, and
# <ode/precision.h> picks double unless dIDESINGLE is defined. The adapter must use the
# library's precision (dReal is its ABI), so a single-precision ode.pc gets dIDESINGLE.
find_package(PkgConfig)
if(PKG_CONFIG_FOUND)
  pkg_check_modules(ODE IMPORTED_TARGET ode)
endif()
if(ODE_FOUND)
  pkg_get_variable(ODE_PRECISION ode precision)
  target_sources(phys_peers PRIVATE ${CMAKE_CURRENT_LIST_DIR}/ode_peer.cpp)
  target_link_libraries(phys_peers PRIVATE PkgConfig::ODE)
  target_compile_definitions(phys_peers PUBLIC PHYS_PEER_ODE)
  if(ODE_PRECISION STREQUAL "dSINGLE")
    target_compile_definitions(phys_peers PRIVATE dIDESINGLE)
  endif()
else()
  message(STATUS "ODE (pkg-config ode) not found: the ODE peer is not built")
endif()
