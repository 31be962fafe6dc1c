# phys_add_gtest_suites(TARGET PREFIX [TIMEOUT s] [LABELS ...] [ENVIRONMENT ...]
#                       [FIXTURES_REQUIRED ...]): one ctest test per
# GoogleTest suite of TARGET (named PREFIX<Suite>, running --gtest_filter=<Suite>.*), instead
# of gtest_discover_tests' one process per test. For suites whose tests share something
# costly to make in a process: the GPU tests' Vulkan device and kernels (seconds on lavapipe).
# The suites are read from the target's sources (lines starting TEST(Suite, / TEST_F / TEST_P),
# and CMake configures again when a source changes, so a new suite gets its test.
function(phys_add_gtest_suites target prefix)
  cmake_parse_arguments(ARG "" "TIMEOUT" "LABELS;ENVIRONMENT;FIXTURES_REQUIRED" ${ARGN})
  get_target_property(sources ${target} SOURCES)
  set(suites)
  foreach(src ${sources})
    get_filename_component(path ${src} ABSOLUTE BASE_DIR ${CMAKE_CURRENT_SOURCE_DIR})
    if(NOT path MATCHES "\\.cpp$")
      continue()
    endif()
    set_property(DIRECTORY APPEND PROPERTY CMAKE_CONFIGURE_DEPENDS ${path})
    file(STRINGS ${path} lines REGEX "^TEST(_F|_P)?\\([A-Za-z0-9_]+,")
    foreach(line ${lines})
      string(REGEX REPLACE "^TEST(_F|_P)?\\(([A-Za-z0-9_]+),.*" "\\2" suite "${line}")
      list(APPEND suites ${suite})
    endforeach()
  endforeach()
  list(REMOVE_DUPLICATES suites)
  foreach(suite ${suites})
    # Parameterized suites run as <Instantiation>/<Suite>.<Test>/<n>.
    add_test(NAME ${prefix}${suite} COMMAND ${target} --gtest_filter=${suite}.*:*/${suite}.*)
    set_tests_properties(${prefix}${suite} PROPERTIES LABELS "${ARG_LABELS}"
      TIMEOUT "${ARG_TIMEOUT}" ENVIRONMENT "${ARG_ENVIRONMENT}"
      FIXTURES_REQUIRED "${ARG_FIXTURES_REQUIRED}")
  endforeach()
endfunction()
