// Not compiled: a mechanics source that uses VTK, which the layering check must refuse.
#include <vtkPoints.h>
