// Not compiled: a mechanics source that reaches up into the formats layer,
// which the layering check must refuse.
#include "bmrScene.h"
