# The link guard that keeps haptic_server off the simulation (cmake/TactusLinkGuard.cmake):
# configures the tiny project in link_guard/ once per case and checks the outcome. Bad cases
# must fail configuration naming the forbidden library; clean cases must configure.
set(_lg_dir ${CMAKE_CURRENT_SOURCE_DIR}/link_guard)
foreach(_case direct_alias alias_interface static_private by_file clean unrelated)
  set(_bin ${CMAKE_CURRENT_BINARY_DIR}/link_guard_${_case})
  add_test(NAME security.link_guard.${_case}
           COMMAND ${CMAKE_COMMAND} -S ${_lg_dir} -B ${_bin} -G ${CMAKE_GENERATOR}
                   -DCMAKE_CXX_COMPILER=${CMAKE_CXX_COMPILER}
                   -DCASE=${_case} -DGUARD_FILE=${PROJECT_SOURCE_DIR}/cmake/TactusLinkGuard.cmake
                   --fresh)
  if(_case STREQUAL "clean" OR _case STREQUAL "unrelated")
    set_tests_properties(security.link_guard.${_case} PROPERTIES
      PASS_REGULAR_EXPRESSION "link guard passed"
      FAIL_REGULAR_EXPRESSION "must not link|CMake Error")
  elseif(_case STREQUAL "by_file")
    set_tests_properties(security.link_guard.${_case} PROPERTIES
      PASS_REGULAR_EXPRESSION "rt_lib must not link /usr/lib/libcholmod[.]so[.]3"
      FAIL_REGULAR_EXPRESSION "link guard passed")
  else()
    set_tests_properties(security.link_guard.${_case} PROPERTIES
      PASS_REGULAR_EXPRESSION "rt_lib must not link forbidden_core"
      FAIL_REGULAR_EXPRESSION "link guard passed")
  endif()
  set_tests_properties(security.link_guard.${_case} PROPERTIES
    LABELS security TIMEOUT 120)
endforeach()
