# scripts/start.sh exit status and run dir (a shell test; ~14 s, starts the real daemons). It
# checks exit statuses and logs, not times, and mostly waits on the daemons: no core slot, one
# haptic loop at a time (tests/CMakeLists.txt, WAITS).
add_test(NAME security_start_script
  COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/start_script_test.sh ${PROJECT_SOURCE_DIR}
          ${PROJECT_BINARY_DIR})
set_tests_properties(security_start_script PROPERTIES LABELS security RESOURCE_LOCK haptic_loop
                     TIMEOUT 300)
