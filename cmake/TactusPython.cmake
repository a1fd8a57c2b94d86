# The interpreter, its headers and pybind11 for the Python module (api/python; docs/api.md).
# Debian's /usr/bin/python3 is preferred when it has numpy: a python3 earlier on PATH (a pyenv
# build, a virtualenv) may lack numpy, and the module must be imported by the interpreter it was
# built for. Give -DPython_EXECUTABLE=... to choose another. Sets TACTUS_PYTHON_READY, and
# TACTUS_PYTEST_READY when pytest is there too; otherwise says what is missing and goes on
# without the module (scripts/install_deps.sh installs python3-dev, python3-numpy, pybind11-dev,
# python3-pytest).
set(TACTUS_PYTHON_READY FALSE)
set(TACTUS_PYTEST_READY FALSE)
if(NOT Python_EXECUTABLE AND EXISTS /usr/bin/python3)
  execute_process(COMMAND /usr/bin/python3 -c "import numpy" RESULT_VARIABLE _tactus_numpy
                  OUTPUT_QUIET ERROR_QUIET)
  if(_tactus_numpy EQUAL 0)
    set(Python_EXECUTABLE /usr/bin/python3 CACHE FILEPATH "Python interpreter of the tactus module")
  endif()
endif()
find_package(Python 3.8 COMPONENTS Interpreter Development.Module)
if(NOT Python_FOUND)
  message(STATUS "tactus: Python module not built: no Python interpreter with its headers "
                 "(python3-dev)")
  return()
endif()
execute_process(COMMAND ${Python_EXECUTABLE} -c "import numpy" RESULT_VARIABLE _tactus_numpy
                OUTPUT_QUIET ERROR_QUIET)
if(NOT _tactus_numpy EQUAL 0)
  message(STATUS "tactus: Python module not built: ${Python_EXECUTABLE} has no numpy "
                 "(python3-numpy, or -DPython_EXECUTABLE=an interpreter with numpy)")
  return()
endif()
set(PYBIND11_FINDPYTHON ON)
find_package(pybind11 2.6 CONFIG QUIET)
if(NOT pybind11_FOUND)
  message(STATUS "tactus: Python module not built: pybind11 not found (pybind11-dev)")
  return()
endif()
set(TACTUS_PYTHON_READY TRUE)
execute_process(COMMAND ${Python_EXECUTABLE} -c "import pytest" RESULT_VARIABLE _tactus_pytest
                OUTPUT_QUIET ERROR_QUIET)
if(_tactus_pytest EQUAL 0)
  set(TACTUS_PYTEST_READY TRUE)
else()
  message(STATUS "tactus: ${Python_EXECUTABLE} has no pytest: the Python tests are skipped "
                 "(python3-pytest)")
endif()
message(STATUS "tactus: Python module for ${Python_EXECUTABLE} (${Python_VERSION}), pybind11 "
               "${pybind11_VERSION}")
