cmake_minimum_required(VERSION 3.16)
# The layering check of cmake/BmrLayering.cmake must stop a configuration: run
# it on a folder whose source includes a higher layer's header and on one that
# uses a forbidden library (each should fail with its reason), and on src/'s
# own mechanics layer (should pass).
include(${SOURCE_DIR}/cmake/BmrLayering.cmake)
bmr_check_layer(${SOURCE_DIR}/src/mechanics HEADERS ${BMR_FORMATS_HEADERS} ${BMR_MODELBUILDING_HEADERS} PREFIXES vtk itk)
if(CASE STREQUAL "header")
  bmr_check_layer(${SOURCE_DIR}/test/layering/includes-higher-layer HEADERS ${BMR_FORMATS_HEADERS})
elseif(CASE STREQUAL "library")
  bmr_check_layer(${SOURCE_DIR}/test/layering/includes-forbidden-library PREFIXES vtk)
endif()
message(STATUS "layering respected")
