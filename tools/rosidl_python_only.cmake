# Included by tools/build_msgs.py (CMAKE_PROJECT_INCLUDE) when it builds an interface package into the venv: only
# the rosidl generators and type supports a Python node loads are registered, not the C++ ones.
#
# What rclpy loads for `<pkg>.msg`: the Python module (rosidl_generator_py), its C extension
# `<pkg>_s__rosidl_typesupport_c.so`, which links lib<pkg>__rosidl_generator_c (rosidl_generator_c, with the type
# hashes of rosidl_generator_type_description) and lib<pkg>__rosidl_typesupport_c, the dispatcher that dlopens at run
# time the C type support the RMW asks for: rmw_fastrtps_cpp asks for rosidl_typesupport_fastrtps_c
# (lib<pkg>__rosidl_typesupport_fastrtps_c), introspection-based tools for rosidl_typesupport_introspection_c.
# The C++ side (rosidl_generator_cpp, rosidl_typesupport_cpp, rosidl_typesupport_fastrtps_cpp,
# rosidl_typesupport_introspection_cpp: headers and libraries for rclcpp nodes) is not loaded by a Python process;
# compiling its templates was most of the build time.
#
# A real ROS 2 install never includes this file: `colcon build` of msgs_config/cgp_sim_msgs builds every generator.

find_package(ament_cmake_core QUIET REQUIRED)  # defines ament_register_extension (its config is included once)

set(CGP_SIM_SKIPPED_ROSIDL_EXTENSIONS
  rosidl_generator_cpp
  rosidl_typesupport_cpp
  rosidl_typesupport_fastrtps_cpp
  rosidl_typesupport_introspection_cpp)

# The generators register themselves with ament_register_extension("rosidl_generate_idl_interfaces" ...) when
# rosidl_default_generators finds them; rosidl_generate_interfaces() runs what is registered.  This wrapper leaves the
# C++ ones out (CMake keeps the original command as _ament_register_extension).
macro(ament_register_extension extension_point package_name cmake_filename)
  set(_cgp_sim_package "${package_name}")
  if("${extension_point}" STREQUAL "rosidl_generate_idl_interfaces"
      AND _cgp_sim_package IN_LIST CGP_SIM_SKIPPED_ROSIDL_EXTENSIONS)
    message(STATUS "cgp_sim: not generating ${package_name} (a Python node does not load it)")
  else()
    _ament_register_extension("${extension_point}" "${package_name}" "${cmake_filename}")
  endif()
endmacro()

# Found here, before the package's CMakeLists.txt finds it (a second find_package of an ament package is a no-op),
# so that the generators register through the wrapper above and rosidl_generator_py's macro can be replaced below.
find_package(rosidl_default_generators REQUIRED)

# rosidl_generator_py builds one extension module per C type support (`<pkg>_s__<type support>.so`), but rclpy
# imports only `<pkg>_s__rosidl_typesupport_c` (the dispatcher, rosidl_generator_py.import_type_support): the
# fastrtps and introspection ones are never loaded.
macro(rosidl_generator_py_get_typesupports TYPESUPPORT_IMPLS)
  find_package(rosidl_typesupport_c QUIET)
  if(rosidl_typesupport_c_FOUND)
    set(${TYPESUPPORT_IMPLS} "rosidl_typesupport_c")
  else()
    set(${TYPESUPPORT_IMPLS} "")
  endif()
endmacro()

# The fastrtps C type support is generated as C++ (one file per interface, each parsing Fast CDR's headers anew):
# compiled as a unity build (a few files that include several each) it takes a fraction of the time.  Set at the
# end of the package's CMakeLists.txt, when rosidl_generate_interfaces() has made the target.
if(NOT CMAKE_VERSION VERSION_LESS 3.19)
  function(_cgp_sim_unity_type_support)
    foreach(_target "${PROJECT_NAME}__rosidl_typesupport_fastrtps_c")
      if(TARGET "${_target}")
        set_target_properties("${_target}" PROPERTIES UNITY_BUILD ON UNITY_BUILD_BATCH_SIZE 0)
      endif()
    endforeach()
  endfunction()
  cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _cgp_sim_unity_type_support)
endif()
