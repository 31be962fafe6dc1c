# Warnings and sanitizers for every target of the project.
add_compile_options(-Wall -Wextra)
if(PHYS_SANITIZE)
  string(REPLACE ";" "," _phys_san "${PHYS_SANITIZE}")
  add_compile_options(-fsanitize=${_phys_san} -fno-omit-frame-pointer)
  add_link_options(-fsanitize=${_phys_san})
  # No ifunc multiversioning (physics/dynamics/solver_wide.cpp): its resolver runs in the
  # dynamic loader before the sanitizer runtime is up.
  add_compile_definitions(PHYS_NO_MULTIVERSION)
endif()
# The step's float math must be reproducible: no fast-math, no FMA contraction differences.
add_compile_options(-ffp-contract=off)
