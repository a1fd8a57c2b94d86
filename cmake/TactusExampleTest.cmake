# The ctest example_cpp_installed (cmake -P): installs the library into a fresh prefix, checks that
# no header of the simulation's inside is there, then configures, builds and runs examples/cpp
# out of tree against that prefix alone, as a user's program would be built.
# -D BUILD (this build), SOURCE (the source tree), WORK (a scratch folder), GENERATOR, CXX,
# LAUNCHER (a compiler launcher such as ccache, or empty).
file(REMOVE_RECURSE ${WORK})
execute_process(COMMAND ${CMAKE_COMMAND} --install ${BUILD} --prefix ${WORK}/prefix
                        --component library
                RESULT_VARIABLE rc OUTPUT_QUIET)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "cmake --install ${BUILD} failed (${rc})")
endif()
foreach(inside fem.h compliance.h step_scratch.h simulation_state.h simulation_model.h
        pipeline.h collision.h instrument.h segment.h)
  file(GLOB_RECURSE found ${WORK}/prefix/include/*${inside})
  if(found)
    message(FATAL_ERROR "the install holds ${found}, a header of the library's inside")
  endif()
endforeach()
set(launcher "")
if(LAUNCHER)
  set(launcher -DCMAKE_CXX_COMPILER_LAUNCHER=${LAUNCHER})
endif()
execute_process(COMMAND ${CMAKE_COMMAND} -S ${SOURCE}/examples/cpp -B ${WORK}/build
                        -G ${GENERATOR} -DCMAKE_BUILD_TYPE=Release
                        -DCMAKE_PREFIX_PATH=${WORK}/prefix -DCMAKE_CXX_COMPILER=${CXX} ${launcher}
                RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "configuring examples/cpp against ${WORK}/prefix failed (${rc})")
endif()
execute_process(COMMAND ${CMAKE_COMMAND} --build ${WORK}/build RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "building examples/cpp failed (${rc})")
endif()
execute_process(COMMAND ${WORK}/build/tactus_example RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "tactus_example failed (${rc})")
endif()
