cmake_minimum_required(VERSION 3.16)
# The library check of cmake/BmrLayering.cmake must stop a configuration: run
# it on a folder whose source uses a forbidden library (it should fail with
# its reason), and on src/'s own mechanics layer (should pass). A higher
# layer's header is the compiler's to refuse (test/CMakeLists.txt).
include(${SOURCE_DIR}/cmake/BmrLayering.cmake)
bmr_check_layer(${SOURCE_DIR}/src/mechanics PREFIXES vtk itk)
if(CASE STREQUAL "library")
  bmr_check_layer(${SOURCE_DIR}/test/layering/includes-forbidden-library PREFIXES vtk)
endif()
message(STATUS "layering respected")
