# tactus_add_fclib_hdf5(<target>): compiles FCLIB's HDF5 reader (tools/common/fclib_hdf5.cpp) into
# a tool when Debian's libhdf5 is present, and defines TACTUS_HAVE_HDF5=1 for it. HDF5 is optional
# and only ever linked into tools, never into tactus_shared or the daemons. Sets
# TACTUS_FCLIB_HDF5_FOUND in the caller's scope.
function(tactus_add_fclib_hdf5 target)
  # FindHDF5's C component test-compiles a C file, so C must be enabled (when a C compiler exists).
  include(CheckLanguage)
  check_language(C)
  if(CMAKE_C_COMPILER)
    enable_language(C)
    find_package(HDF5 COMPONENTS C QUIET)
  endif()
  set(TACTUS_FCLIB_HDF5_FOUND ${HDF5_FOUND} PARENT_SCOPE)
  if(NOT HDF5_FOUND)
    return()
  endif()
  target_sources(${target} PRIVATE ${PROJECT_SOURCE_DIR}/tools/common/fclib_hdf5.cpp)
  target_include_directories(${target} PRIVATE ${PROJECT_SOURCE_DIR}/tools/common)
  target_include_directories(${target} SYSTEM PRIVATE ${HDF5_C_INCLUDE_DIRS} ${HDF5_INCLUDE_DIRS})
  target_link_libraries(${target} PRIVATE ${HDF5_C_LIBRARIES})
  target_compile_definitions(${target} PRIVATE TACTUS_HAVE_HDF5=1 ${HDF5_C_DEFINITIONS}
                             ${HDF5_DEFINITIONS})
endfunction()
