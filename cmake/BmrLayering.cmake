# The dependency direction of src/'s layers, checked when CMake configures:
#
#   pipeline -> modelbuilding -> formats -> mechanics
#
# Each layer is a static library linking only the layer below, but every
# public header sits in include/ and every executable links all layers, so a
# wrong #include would still compile and link. bmr_check_layer() fails the
# configuration when a layer's sources include a header of a layer above it
# or a library the layer must not use. It runs at every configuration (a
# fresh build, CI, a new source file), not at every edit.

get_filename_component(BMR_LAYERING_ROOT ${CMAKE_CURRENT_LIST_DIR}/.. ABSOLUTE)

# Public headers (include/) by the layer that implements them.
set(BMR_MECHANICS_HEADERS bmrModel.h bmrMaterialLaw.h bmrSolver.h bmrBinaryStream.h bmrMeshless.h bmrOgden.h bmrUnits.h bmrAtomicWrite.h
                          bmrSettingsTable.h bmrSolverSettingsTable.h)
set(BMR_FORMATS_HEADERS bmrMeshIO.h bmrScene.h bmrMeshGenerators.h)
set(BMR_MODELBUILDING_HEADERS bmrFuzzyCMeans.h bmrMaterialMapping.h bmrImageGrids.h bmrBrainSurfaces.h
                              bmrSurfaceLoads.h bmrImageVolume.h bmrBSplineField.h)

# bmr_check_layer(FOLDER FORBIDDEN_HEADERS... FORBIDDEN_PREFIXES prefixes...)
# FORBIDDEN_PREFIXES match the start of an included name (e.g. "vtk", "itk").
function(bmr_check_layer folder)
  cmake_parse_arguments(CHECK "" "" "HEADERS;PREFIXES" ${ARGN})
  file(GLOB_RECURSE sources ${folder}/*.cxx ${folder}/*.h)
  foreach(source IN LISTS sources)
    file(STRINGS ${source} includes REGEX "^[ \t]*#[ \t]*include")
    foreach(line IN LISTS includes)
      string(REGEX REPLACE "^[ \t]*#[ \t]*include[ \t]*[<\"]([^>\"]*)[>\"].*$" "\\1" included "${line}")
      get_filename_component(name "${included}" NAME)
      set(wrong "")
      if(name IN_LIST CHECK_HEADERS)
        set(wrong "a header of a higher layer")
      endif()
      foreach(prefix IN LISTS CHECK_PREFIXES)
        if(included MATCHES "^${prefix}")
          set(wrong "a library this layer must not use")
        endif()
      endforeach()
      if(wrong)
        file(RELATIVE_PATH shown ${BMR_LAYERING_ROOT} ${source})
        message(FATAL_ERROR "${shown} includes ${included}, ${wrong} (cmake/BmrLayering.cmake: "
                            "pipeline -> modelbuilding -> formats -> mechanics). Move the code to the layer "
                            "that may use it.")
      endif()
    endforeach()
  endforeach()
endfunction()
