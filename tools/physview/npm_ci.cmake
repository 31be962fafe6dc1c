# `npm ci` for physview's page (CMakeLists.txt: cmake -DNPM=... -DDIR=... -P npm_ci.cmake), so
# that a failure says what failed and how to build without the viewer.
execute_process(COMMAND ${NPM} ci --no-audit --no-fund --loglevel=error
                WORKING_DIRECTORY ${DIR} RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR
    "physview: `npm ci` in ${DIR} failed (${rc}). It installs the viewer page's packages "
    "(three, esbuild, playwright-core; tools/physview/web/package-lock.json) from the npm "
    "registry or npm's cache, so it needs registry access once. To build without the viewer, "
    "configure with -DPHYS_BUILD_VIEWER=OFF (docs/VIEWER.md).")
endif()
