# viewer_test.cpp starts the real tactus-viewer binary.
add_dependencies(security_tests tactus-viewer)
