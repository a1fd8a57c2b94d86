# files_test runs tactus-fc3d-solve too (its --output must not replace a file unasked).
add_dependencies(files_test tactus-fc3d-solve)
