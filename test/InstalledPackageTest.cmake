# CTest case: install the build tree into a fresh prefix, build the C++
# example against it with find_package(BiomechanicalRegistration) alone, and
# run it. Variables: BINARY_DIR (this build), SOURCE_DIR, WORK_DIR (scratch).
file(REMOVE_RECURSE "${WORK_DIR}")
function(run_step what)
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE status OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT status EQUAL 0)
    message(FATAL_ERROR "${what} failed (${status}):\n${out}\n${err}")
  endif()
  set(STEP_OUTPUT "${out}${err}" PARENT_SCOPE)
endfunction()

run_step("cmake --install" ${CMAKE_COMMAND} --install "${BINARY_DIR}" --prefix "${WORK_DIR}/prefix")
foreach(installed include/BiomechanicalRegistration/itkBiomechanicalDeformationFilter.h
                  lib/cmake/BiomechanicalRegistration/BiomechanicalRegistrationConfig.cmake bin/biomech)
  if(NOT EXISTS "${WORK_DIR}/prefix/${installed}")
    message(FATAL_ERROR "not installed: ${installed}")
  endif()
endforeach()
run_step("configuring the consumer" ${CMAKE_COMMAND} -S "${SOURCE_DIR}/test/install-consumer" -B "${WORK_DIR}/build"
         -DCMAKE_BUILD_TYPE=Release "-DCMAKE_PREFIX_PATH=${WORK_DIR}/prefix"
         "-DEXAMPLE_SOURCE=${SOURCE_DIR}/examples/BrainShiftRegistrationExample.cxx")
run_step("building the consumer" ${CMAKE_COMMAND} --build "${WORK_DIR}/build")

# It runs: on Colin27 when it is installed (the example's own check), else up to a named error.
set(colin27 /usr/share/mricron/templates)
if(EXISTS "${colin27}/ch2.nii.gz")
  run_step("running the consumer" "${WORK_DIR}/build/ConsumerExample" "${colin27}/ch2.nii.gz" "${colin27}/ch2bet.nii.gz"
           "${SOURCE_DIR}/examples/data/colin27-superior-craniotomy.csv" -11 43 84 30 "${WORK_DIR}/out" 8)
  if(NOT STEP_OUTPUT MATCHES "solve      converged" OR NOT EXISTS "${WORK_DIR}/out/warped.nii.gz")
    message(FATAL_ERROR "the consumer ran but did not register:\n${STEP_OUTPUT}")
  endif()
else()
  execute_process(COMMAND "${WORK_DIR}/build/ConsumerExample" "${WORK_DIR}/none.nii.gz" a b 0 0 0 1 "${WORK_DIR}/out"
                  RESULT_VARIABLE status ERROR_VARIABLE err)
  if(NOT status EQUAL 1 OR NOT err MATCHES "none.nii.gz")
    message(FATAL_ERROR "the consumer did not name the missing image (${status}): ${err}")
  endif()
endif()
file(REMOVE_RECURSE "${WORK_DIR}")
