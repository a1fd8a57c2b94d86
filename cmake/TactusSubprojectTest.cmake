# The ctest add_subdirectory_library_only (cmake -P): configures tests/subproject, a program that
# adds Tactus with add_subdirectory; its CMakeLists fails unless only the library came in. Checks
# too that configuring it ran nothing of npm. -D SOURCE, WORK, GENERATOR.
file(REMOVE_RECURSE ${WORK})
execute_process(COMMAND ${CMAKE_COMMAND} -S ${SOURCE}/tests/subproject -B ${WORK} -G ${GENERATOR}
                        -DTACTUS_SOURCE=${SOURCE} -DCMAKE_BUILD_TYPE=Release
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "configuring tests/subproject failed:\n${out}\n${err}")
endif()
if(out MATCHES "npm" OR err MATCHES "npm")
  message(FATAL_ERROR "configuring the library mentions npm:\n${out}\n${err}")
endif()
message(STATUS "${out}")
