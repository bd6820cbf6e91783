# Building a rosidl package with `pip install <folder>` (scikit-build-core, pyproject.toml)
# against the ROS 2 Jazzy wheels from PyPI, with no ROS install and nothing sourced
# (docs/howto/building.md). Both interface packages of this folder include it, only when
# SKBUILD is defined: colcon on a ROS install builds them without it.

# The build environment's prefix holds the ROS wheels' share/ and lib/ (ament, rosidl): put it
# where find_package and ament look. Call before the first find_package.
macro(ros_wheels_prefix)
  execute_process(COMMAND "${Python3_EXECUTABLE}" -c "import sys; print(sys.prefix)"
                  OUTPUT_VARIABLE _ros_wheels_prefix OUTPUT_STRIP_TRAILING_WHITESPACE)
  list(PREPEND CMAKE_PREFIX_PATH "${_ros_wheels_prefix}")
  set(ENV{AMENT_PREFIX_PATH} "${_ros_wheels_prefix}")
endmacro()

# The PyPI wheels' exported CMake targets name the include directories of the machine that
# built them (/opt/python/...): drop those from the generator targets of the packages named,
# and give this package's Python generator this Python's and numpy's. Call after
# rosidl_generate_interfaces.
function(ros_wheels_python_includes)
  find_package(Python3 REQUIRED COMPONENTS Interpreter Development.Module NumPy)
  foreach(_pkg ${ARGN})
    set(_target "${_pkg}::${_pkg}__rosidl_generator_py")
    if(TARGET ${_target})
      get_target_property(_dirs ${_target} INTERFACE_INCLUDE_DIRECTORIES)
      if(_dirs)
        list(FILTER _dirs EXCLUDE REGEX "^/opt/python/")
        set_target_properties(${_target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_dirs}")
      endif()
    endif()
  endforeach()
  set(_py_target "${PROJECT_NAME}__rosidl_generator_py")
  if(TARGET ${_py_target})
    target_include_directories(${_py_target} PRIVATE ${Python3_INCLUDE_DIRS}
                               ${Python3_NumPy_INCLUDE_DIRS})
  endif()
endfunction()
