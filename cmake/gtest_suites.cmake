# phys_add_gtest_suites(TARGET PREFIX [TIMEOUT s] [LABELS ...] [ENVIRONMENT ...]
#                       [FIXTURES_REQUIRED ...]): one ctest test per GoogleTest suite of
# TARGET (named PREFIX<Suite>, running --gtest_filter=<Suite>.*), instead of
# gtest_discover_tests' one process per test. For suites whose tests share something costly
# to make in a process: the GPU tests' Vulkan device and kernels (seconds on lavapipe).
# The suites are read from the target's sources (lines starting TEST(Suite, / TEST_F /
# TEST_P), and CMake configures again when a source changes, so a new suite gets its test.
# A suite whose every test skipped (GTEST_SKIP: no Vulkan device) is reported as skipped.
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
    foreach(line IN LISTS lines)
      if(line MATCHES "^TEST(_F|_P)?\\(([A-Za-z0-9_]+),")
        list(APPEND suites ${CMAKE_MATCH_2})
      endif()
    endforeach()
  endforeach()
  list(REMOVE_DUPLICATES suites)
  foreach(suite ${suites})
    set(name ${prefix}${suite})
    # Parameterized suites run as <Instantiation>/<Suite>.<Test>/<n>.
    add_test(NAME ${name} COMMAND ${target} --gtest_filter=${suite}.*:*/${suite}.*)
    # GoogleTest's summary when every test skipped and none failed (a failure's block would
    # follow the skipped ones).
    set_tests_properties(${name} PROPERTIES LABELS "${ARG_LABELS}" SKIP_REGULAR_EXPRESSION
      "\\[  PASSED  \\] 0 tests\\.\n\\[  SKIPPED \\] [0-9]+ tests?, listed below:\n(\\[  SKIPPED \\] [^\n]*\n)*$")
    if(ARG_TIMEOUT)
      set_tests_properties(${name} PROPERTIES TIMEOUT ${ARG_TIMEOUT})
    endif()
    if(ARG_ENVIRONMENT)
      set_tests_properties(${name} PROPERTIES ENVIRONMENT "${ARG_ENVIRONMENT}")
    endif()
    if(ARG_FIXTURES_REQUIRED)
      set_tests_properties(${name} PROPERTIES FIXTURES_REQUIRED "${ARG_FIXTURES_REQUIRED}")
    endif()
  endforeach()
endfunction()
