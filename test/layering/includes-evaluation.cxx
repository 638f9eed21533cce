// A product source that includes a header of the evaluation library (the
// fixtures that judge the product): compiled with the pipeline's include
// directories it must fail to find it (test/CMakeLists.txt,
// EvaluationHeadersAreNotVisibleToTheProduct).
#include "bmrSyntheticBrainShift.h"
