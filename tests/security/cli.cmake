# cli_test.cpp starts tactus-monitor too (sim_server and haptic_server are dependencies of every
# security test).
add_dependencies(security_tests tactus-monitor)
