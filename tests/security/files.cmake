# files_test.cpp runs tactus-fc3d-solve too (its --output must not replace a file unasked).
add_dependencies(security_tests tactus-fc3d-solve)
