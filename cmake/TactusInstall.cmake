# `cmake --install`: the libraries, the public headers and the CMake package (TactusConfig.cmake,
# TactusConfigVersion.cmake, TactusTargets.cmake) that find_package(Tactus) reads (docs/api.md).
# The headers installed are the public API's (api/include/tactus) and the few project headers it
# includes; the simulation's inside (FEM bodies, compliance models, scratch) is not among them.
# The libraries are static: the module libraries the public ones link are installed beside them.
include(GNUInstallDirs)
include(CMakePackageConfigHelpers)

set(_tactus_libraries tactus_api tactus_contact_solver tactus_haptic_model tactus_local_model
    tactus_shared tactus_sim tactus_sim_mesh tactus_sim_scene tactus_sim_fem tactus_sim_contact
    tactus_warnings)
install(TARGETS ${_tactus_libraries} EXPORT TactusTargets
        ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR} COMPONENT library
        INCLUDES DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})

install(DIRECTORY ${PROJECT_SOURCE_DIR}/api/include/tactus
        DESTINATION ${CMAKE_INSTALL_INCLUDEDIR} COMPONENT library
        FILES_MATCHING PATTERN "*.h")
install(FILES ${PROJECT_BINARY_DIR}/api/include/tactus/version.h
        DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/tactus COMPONENT library)
# the project headers the public ones include
foreach(h nsgs.h pose.h error.h messages.h triple_buffer.h delassus_blocks.h warm_start.h
          grow_only_matrix.h)
  install(FILES ${PROJECT_SOURCE_DIR}/shared/include/tactus/shared/${h}
          DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/tactus/shared COMPONENT library)
endforeach()
install(FILES ${PROJECT_SOURCE_DIR}/haptic_server/include/tactus/haptic/local_model.h
        DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/tactus/haptic COMPONENT library)

set(_tactus_cmake_dir ${CMAKE_INSTALL_LIBDIR}/cmake/Tactus)
install(EXPORT TactusTargets NAMESPACE Tactus:: DESTINATION ${_tactus_cmake_dir}
        COMPONENT library)
configure_package_config_file(${PROJECT_SOURCE_DIR}/cmake/TactusConfig.cmake.in
                              ${PROJECT_BINARY_DIR}/TactusConfig.cmake
                              INSTALL_DESTINATION ${_tactus_cmake_dir})
# 0.x: a minor version may change the API
write_basic_package_version_file(${PROJECT_BINARY_DIR}/TactusConfigVersion.cmake
                                 VERSION ${PROJECT_VERSION} COMPATIBILITY SameMinorVersion)
install(FILES ${PROJECT_BINARY_DIR}/TactusConfig.cmake
              ${PROJECT_BINARY_DIR}/TactusConfigVersion.cmake
              ${PROJECT_SOURCE_DIR}/cmake/TactusCholmod.cmake
        DESTINATION ${_tactus_cmake_dir} COMPONENT library)

# The example consumer, built against a fresh install inside the test command (its output is
# checked: contacts, forces, the local model's answer).
if(TACTUS_BUILD_TESTS)
  add_test(NAME example_cpp_installed
           COMMAND ${CMAKE_COMMAND} -DBUILD=${PROJECT_BINARY_DIR} -DSOURCE=${PROJECT_SOURCE_DIR}
                   -DWORK=${PROJECT_BINARY_DIR}/example_cpp -DGENERATOR=${CMAKE_GENERATOR}
                   -DCXX=${CMAKE_CXX_COMPILER} -DLAUNCHER=${CMAKE_CXX_COMPILER_LAUNCHER}
                   -P ${PROJECT_SOURCE_DIR}/cmake/TactusExampleTest.cmake)
  set(_num "-?[0-9.]+")
  string(CONCAT _expect "after 100 steps.* [1-9][0-9]* contacts, NSGS converged"
                        ".*contact force on the tissue \\(sum over [1-9][0-9]* contacts\\)"
                        ".*reactions: fixed nodes \\[${_num} ${_num} ${_num}\\] N"
                        ".*haptic local model \\(ready\\): force on the tool")
  set_tests_properties(example_cpp_installed PROPERTIES LABELS "unit;install" TIMEOUT 600
                       PASS_REGULAR_EXPRESSION "${_expect}"
                       FAIL_REGULAR_EXPRESSION "(^|[^a-z])(nan|inf)([^a-z]|$)"
                       ${TACTUS_TEST_ON_A_CORE})
endif()
