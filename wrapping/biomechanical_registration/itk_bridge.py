"""ITK Python's own objects in and out of the module's functions (issue 61).

The binding links Debian's ITK 5.2; ``import itk`` brings ITK's 5.4 wheels.
The two ITKs share no C++ object, so the bridge goes through what both
understand (docs/python.md, "ITK objects in, ITK objects out"):

* an ``itk.Image`` (any scalar pixel type of the wheels) enters as a NumPy
  view of its buffer (``itk.array_view_from_image``, no copy) with its
  spacing, origin and direction; the C++ side then takes one copy into its
  own float or uint8 image, as for any NumPy input;
* an image coming out becomes an ``itk.Image`` viewing the NumPy array the
  binding made (``itk.image_view_from_array``, no copy), with spacing, origin
  and direction set exactly; multi-component images (tissue memberships)
  become ``itk.VectorImage[itk.F, 3]``;
* a transform goes through ITK's HDF5 transform file, which both ITKs read
  and write with every parameter as a double: an ``itk`` transform object
  comes out (``itk.BSplineTransform[itk.D, 3, 3]`` for the registrations),
  usable by ``itk.resample_image_filter`` and ``itk.transformwrite``;
* result objects (:class:`RegistrationResult`, :class:`BrainModel`, ...) come
  out as views whose image and transform attributes are ``itk`` objects.

Only a call given an ``itk`` object (or such a view) answers with ``itk``
objects; a call with the package's own :class:`Image` objects is unchanged.
Nothing here imports ``itk``: it is used only when the caller has imported it.
"""

import functools
import inspect
import os
import re
import sys
import tempfile

import numpy as np

from .image import Image

__all__ = [
    "image_from_itk",
    "itk_image_from_image",
    "transform_from_itk",
    "itk_transform_from_transform",
    "is_itk_image",
    "is_itk_transform",
]

# Parameters that take a multi-component image (tissue memberships); every other image
# parameter needs a scalar one.
_VECTOR_PARAMETERS = {"memberships"}

# The binding's classes whose attributes hold images or transforms: given itk input, they
# come back as _ItkView.
_VIEWED_CLASSES = {
    "BrainModel",
    "BSplineRegistration",
    "EdgeEvaluation",
    "ModelBundle",
    "RegistrationResult",
    "SyntheticBrainShift",
    "SyntheticElectrodeCt",
    "TissueClassification",
}


def _itk():
    itk = sys.modules.get("itk")
    if itk is None:
        raise RuntimeError("itk is not imported: `import itk` (ITK's Python wheels) first")
    return itk


def _from_itk_module(value):
    return type(value).__module__.startswith("itk.")


def is_itk_image(value):
    """True for an image of ITK's Python wheels (itk.Image, itk.VectorImage, ...)."""
    return _from_itk_module(value) and hasattr(value, "GetLargestPossibleRegion") and hasattr(value, "GetSpacing")


def is_itk_transform(value):
    """True for a transform of ITK's Python wheels (any itk.Transform)."""
    return _from_itk_module(value) and hasattr(value, "GetInputSpaceDimension") and hasattr(value, "TransformPoint")


def image_from_itk(image, argument="image", allow_components=False):
    """An :class:`Image` viewing an ``itk.Image``'s buffer (no copy), with its geometry.

    ``argument`` names the parameter in errors: the module's images are 3-D, and scalar
    unless ``allow_components``.
    """
    itk = _itk()
    if not is_itk_image(image):
        raise TypeError("%s must be an itk.Image; got %s" % (argument, type(image).__name__))
    dimension = image.GetImageDimension()
    scalar = _has_scalar_pixels(itk, image)
    kind = "%d-D image of %s pixels (%s%s)" % (
        dimension, "scalar" if scalar else "vector", type(image).__name__,
        "" if scalar else ", %d components" % image.GetNumberOfComponentsPerPixel())
    if dimension != 3 or not (scalar or allow_components):
        raise TypeError(
            "%s: an itk %s; a 3-D %simage is needed, e.g. itk.Image[itk.F, 3]%s"
            % (argument, kind, "" if allow_components else "scalar ",
               "" if scalar or allow_components else
               ": pick one component (itk.vector_index_selection_cast_image_filter) or convert it")
        )
    size = tuple(image.GetLargestPossibleRegion().GetSize())
    if min(size) == 0:
        raise ValueError("%s: the itk image is empty (size %s); give it voxels (itk.imread, or Allocate())"
                         % (argument, size))
    result = Image(
        itk.array_view_from_image(image),
        spacing=np.array(image.GetSpacing(), dtype=np.float64),
        origin=np.array(image.GetOrigin(), dtype=np.float64),
        direction=np.array(itk.array_from_matrix(image.GetDirection()), dtype=np.float64),
    )
    # Image() keeps a plain ndarray view, and NumPy points a view's base at the memory's owner, skipping
    # the NDArrayITKBase whose itk_base keeps the itk image (and, for an itk.image_view_from_array image,
    # the NumPy array it views) alive: a temporary itk image's voxels were freed before the C++ call read
    # them. So the Image holds the itk image itself.
    result._itk_image = image
    return result


_SCALAR_PIXEL_TYPES = ("UC", "SC", "US", "SS", "UI", "SI", "UL", "SL", "ULL", "SLL", "F", "D", "B")


def _has_scalar_pixels(itk, image):
    """itk.Image of a scalar pixel type (not itk.VectorImage, nor vector, RGB or tensor pixels)."""
    try:
        image_class, (pixel, _) = itk.template(image)
    except (KeyError, TypeError, ValueError):
        return False
    scalars = [getattr(itk, name) for name in _SCALAR_PIXEL_TYPES if hasattr(itk, name)]
    return image_class is itk.Image and any(pixel is scalar for scalar in scalars)


def itk_image_from_image(image):
    """An ``itk.Image`` viewing an :class:`Image`'s array (no copy when it is C-contiguous), geometry exact."""
    itk = _itk()
    if not isinstance(image, Image):
        raise TypeError("expected a biomechanical_registration.Image, got %s" % type(image).__name__)
    array = image.array
    if array.dtype == np.bool_:
        array = array.astype(np.uint8)
    array = np.ascontiguousarray(array)
    if array.ndim == 4:
        result = itk.image_view_from_array(np.ascontiguousarray(array, dtype=np.float32), ttype=itk.VectorImage[itk.F, 3])
    else:
        result = itk.image_view_from_array(array)
    result.SetSpacing([float(value) for value in image.spacing])
    result.SetOrigin([float(value) for value in image.origin])
    result.SetDirection(itk.matrix_from_array(np.array(image.direction, dtype=np.float64)))
    return result


def transform_from_itk(transform, argument="transform"):
    """The binding's :class:`Transform` of an ``itk`` transform of 3-D points (through an HDF5 file)."""
    itk = _itk()
    from . import _bmr

    if not is_itk_transform(transform):
        raise TypeError("%s must be an itk transform; got %s" % (argument, type(transform).__name__))
    dimensions = (transform.GetInputSpaceDimension(), transform.GetOutputSpaceDimension())
    if dimensions != (3, 3):
        raise TypeError(
            "%s: an itk transform of %d-D points to %d-D (%s); a 3-D transform is needed, e.g. "
            "itk.BSplineTransform[itk.D, 3, 3]" % (argument, dimensions[0], dimensions[1], type(transform).__name__)
        )
    with tempfile.TemporaryDirectory(prefix="bmr-transform-") as folder:
        path = os.path.join(folder, "transform.h5")
        itk.transformwrite([transform], path)
        return _bmr.read_transform(path)


def itk_transform_from_transform(transform):
    """An ``itk`` transform object equal to the binding's :class:`Transform` (through an HDF5 file)."""
    itk = _itk()
    with tempfile.TemporaryDirectory(prefix="bmr-transform-") as folder:
        path = os.path.join(folder, "transform.h5")
        transform.write(path)
        transforms = itk.transformread(path)
    if len(transforms) != 1:
        raise RuntimeError("the transform file held %d transforms; expected one" % len(transforms))
    return transforms[0]


class _ItkView:
    """One of the binding's result objects, whose images and transforms read as ``itk`` objects.

    ``isinstance`` sees the wrapped class; the module's functions take the view where they
    take the object.
    """

    __slots__ = ("_wrapped",)

    def __init__(self, wrapped):
        object.__setattr__(self, "_wrapped", wrapped)

    @property
    def __class__(self):
        return type(self._wrapped)

    def __getattr__(self, name):
        value = getattr(self._wrapped, name)
        if callable(value) and not isinstance(value, type):
            return _calling_with_itk(value, always_itk=True)
        return _to_itk(value)

    def __setattr__(self, name, value):
        setattr(self._wrapped, name, value)

    def __dir__(self):
        return dir(self._wrapped)

    def __repr__(self):
        return repr(self._wrapped)


def _to_itk(value):
    from . import _bmr

    if isinstance(value, Image):
        return itk_image_from_image(value)
    if isinstance(value, _bmr.Transform):
        return itk_transform_from_transform(value)
    if isinstance(value, (list, tuple)):
        return type(value)(_to_itk(item) for item in value)
    if isinstance(value, dict):
        return {key: _to_itk(item) for key, item in value.items()}
    if type(value).__name__ in _VIEWED_CLASSES and type(value).__module__ == _bmr.__name__:
        return _ItkView(value)
    return value


def _from_itk(value, argument, found):
    """The argument as the binding takes it; found[0] becomes True where an itk object (or view) was given."""
    if type(value) is _ItkView:
        found[0] = True
        return object.__getattribute__(value, "_wrapped")
    if _from_itk_module(value):
        if is_itk_image(value):
            found[0] = True
            return image_from_itk(value, argument, allow_components=argument in _VECTOR_PARAMETERS)
        if is_itk_transform(value):
            found[0] = True
            return transform_from_itk(value, argument)
    if isinstance(value, (list, tuple)):
        return type(value)(_from_itk(item, "%s[%d]" % (argument, k), found) for k, item in enumerate(value))
    return value


_SIGNATURE = re.compile(r"^\w+\((.*?)\)\s*->", re.MULTILINE)


def parameter_names(function):
    """The parameter names, in order, of a Python function or of a pybind11 function (from its signature line)."""
    function = inspect.unwrap(function)
    code = getattr(function, "__code__", None)
    if code is not None:
        return list(code.co_varnames[: code.co_argcount + code.co_kwonlyargcount])
    match = _SIGNATURE.search(function.__doc__ or "")
    return re.findall(r"(\w+)\s*:", match.group(1)) if match else []


def _calling_with_itk(function, always_itk=False):
    names = parameter_names(function)

    @functools.wraps(function)
    def call(*args, **kwargs):
        if "itk" not in sys.modules and not always_itk:
            return function(*args, **kwargs)
        found = [always_itk]
        args = [
            _from_itk(value, names[k] if k < len(names) else "argument %d" % (k + 1), found)
            for k, value in enumerate(args)
        ]
        kwargs = {name: _from_itk(value, name, found) for name, value in kwargs.items()}
        result = function(*args, **kwargs)
        return _to_itk(result) if found[0] else result

    return call


def accepting_itk(function):
    """``function`` taking ``itk`` images and transforms wherever it takes the package's, and answering
    with ``itk`` objects when it was given one (a no-op while ``itk`` is not imported)."""
    return _calling_with_itk(function)


def camel_to_snake_case(name):
    """ITK Python's functional name of a class name: BSplineTransform -> b_spline_transform."""
    snake = re.sub("(.)([A-Z][a-z]+)", r"\1_\2", name)
    snake = re.sub("([a-z0-9])([A-Z])", r"\1_\2", snake)
    return snake.replace("__", "_").lower()


def functional_alias(itk_class, function, inputs, keywords):
    """ITK Python's functional form of one of the module's ITK filters, calling ``function``.

    ``inputs``: ``function``'s keyword for each positional input of the filter (its primary
    input first, as ``itk.<filter>(input, ...)`` takes it); ``keywords``: the filter's Set
    methods in snake_case mapped to ``function``'s keywords. Keywords of ``function`` itself
    are accepted as well.
    """
    name = camel_to_snake_case(itk_class)
    accepted = set(keywords) | set(parameter_names(function))

    def alias(*args, **kwargs):
        if len(args) > len(inputs):
            raise TypeError("%s() takes %d positional input%s (%s); give the rest as keywords"
                            % (name, len(inputs), "" if len(inputs) == 1 else "s", ", ".join(inputs)))
        unknown = sorted(set(kwargs) - accepted)
        if unknown:
            raise TypeError("%s() got unknown keyword%s %s; it takes %s"
                            % (name, "s" if len(unknown) > 1 else "", ", ".join(unknown), ", ".join(sorted(accepted))))
        call = {keywords.get(key, key): value for key, value in kwargs.items()}
        for key, value in zip(inputs, args):
            if key in call:
                raise TypeError("%s() got %s both as an input and as a keyword" % (name, key))
            call[key] = value
        return function(**call)

    alias.__name__ = alias.__qualname__ = name
    renames = ", ".join("%s=%s" % (key, value) for key, value in sorted(keywords.items()))
    alias.__doc__ = (
        "ITK Python's functional form of itk::%s: %s(%s, ...) is %s(...)%s.\n\n%s"
        % (itk_class, name, ", ".join(inputs), function.__name__,
           "; the filter's Set methods as keywords: " + renames if renames else "", function.__doc__ or "")
    )
    return alias
