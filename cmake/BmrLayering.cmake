# The libraries src/'s layers must not use, checked when CMake configures.
#
#   pipeline -> modelbuilding -> formats -> mechanics -> common
#
# The direction between the layers' own headers needs no list: each layer's
# public headers sit in its own include/ folder, which only the layers above
# it see, so the compiler refuses a lower layer's include of a higher layer's
# header (test/CMakeLists.txt: LowerLayerCannotSeeAHigherLayersHeaders). A
# library's headers, though, are on the system's include path, so
# bmr_check_layer() fails the configuration when a layer's sources include a
# library the layer must not use (VTK, JSON or ITK in mechanics, ...). It runs
# at every configuration (a fresh build, CI, a new source file).

get_filename_component(BMR_LAYERING_ROOT ${CMAKE_CURRENT_LIST_DIR}/.. ABSOLUTE)

# bmr_check_layer(FOLDER PREFIXES prefixes...)
# PREFIXES match the start of an included name (e.g. "vtk", "itk").
function(bmr_check_layer folder)
  cmake_parse_arguments(CHECK "" "" "PREFIXES" ${ARGN})
  file(GLOB_RECURSE sources ${folder}/*.cxx ${folder}/*.h)
  foreach(source IN LISTS sources)
    file(STRINGS ${source} includes REGEX "^[ \t]*#[ \t]*include")
    foreach(line IN LISTS includes)
      string(REGEX REPLACE "^[ \t]*#[ \t]*include[ \t]*[<\"]([^>\"]*)[>\"].*$" "\\1" included "${line}")
      set(wrong "")
      foreach(prefix IN LISTS CHECK_PREFIXES)
        if(included MATCHES "^${prefix}")
          set(wrong "a library this layer must not use")
        endif()
      endforeach()
      if(wrong)
        file(RELATIVE_PATH shown ${BMR_LAYERING_ROOT} ${source})
        message(FATAL_ERROR "${shown} includes ${included}, ${wrong} (cmake/BmrLayering.cmake: "
                            "pipeline -> modelbuilding -> formats -> mechanics -> common). Move the code to the layer "
                            "that may use it.")
      endif()
    endforeach()
  endforeach()
endfunction()
