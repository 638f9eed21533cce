# ITK remote module description: read by ITK's module system when this folder
# sits in ITK's Modules/Remote.
get_filename_component(MY_CURRENT_DIR "${CMAKE_CURRENT_LIST_FILE}" PATH)
file(READ "${MY_CURRENT_DIR}/README.md" DOCUMENTATION)

itk_module(BiomechanicalRegistration
  DEPENDS
    ITKCommon
    ITKIOImageBase
    ITKIOGDCM
    ITKMesh
    ITKStatistics
    ITKImageFilterBase
    ITKImageFunction
    ITKImageGrid
    ITKImageIntensity
    ITKThresholding
    ITKSmoothing
    ITKDistanceMap
    ITKTransform
    ITKDisplacementField
    ITKRegistrationMethodsv4
    ITKOptimizersv4
    ITKMetricsv4
    ITKImageFeature
    ITKImageCompose
    ITKIOTransformBase
    ITKZLIB
  TEST_DEPENDS
    ITKTestKernel
    ITKIONIFTI
    ITKIONRRD
    ITKIOMeta
    ITKIOPNG
    ITKIOTransformHDF5
    ITKIOTransformInsightLegacy
  DESCRIPTION
    "${DOCUMENTATION}"
  EXCLUDE_FROM_DEFAULT
  ENABLE_SHARED
)
