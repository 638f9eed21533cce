// A mechanics source that reaches up into the formats layer: compiled with the
// mechanics layer's include directories it must fail to find the header
// (test/CMakeLists.txt, LowerLayerCannotSeeAHigherLayersHeaders).
#include "bmrScene.h"
