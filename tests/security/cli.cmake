# cli_test starts tactus-monitor too (sim_server and haptic_server are dependencies of every
# security test).
add_dependencies(cli_test tactus-monitor)
