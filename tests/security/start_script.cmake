# scripts/start.sh exit status and run dir (a shell test; ~6 s, starts the real daemons).
add_test(NAME security_start_script
  COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/start_script_test.sh ${PROJECT_SOURCE_DIR}
          ${PROJECT_BINARY_DIR})
set_tests_properties(security_start_script PROPERTIES LABELS security RUN_SERIAL TRUE TIMEOUT 300)
