"""Images as NumPy arrays with their physical geometry.

Debian's ITK 5.2 has no Python wrapping, so the package carries its own small
image type. It follows ITK Python's conventions so that code reads the same:

* ``image.array`` is indexed ``[z, y, x]`` (``[z, y, x, component]`` for
  multi-component images such as tissue memberships), the view
  ``itk.array_view_from_image`` gives of an ITK image: x varies fastest in
  memory, as in ITK's buffer.
* ``spacing``, ``origin`` and ``size`` are in ITK's ``(x, y, z)`` order;
  ``direction`` is ITK's direction matrix (column ``j`` is the physical
  direction of index axis ``j``).
* Physical space is ITK's: mm, LPS.
"""

import numpy as np

__all__ = [
    "Image",
    "image_from_array",
    "image_view_from_array",
    "array_from_image",
    "array_view_from_image",
]


class Image:
    """A 3-D image: voxel values and where they are (mm, ITK physical space)."""

    def __init__(self, array, spacing=(1.0, 1.0, 1.0), origin=(0.0, 0.0, 0.0), direction=None):
        array = np.asarray(array)
        if array.ndim not in (3, 4):
            raise ValueError(
                "an image array must have shape (z, y, x) or (z, y, x, components); got shape %s" % (array.shape,)
            )
        self.array = array
        self.spacing = _three("spacing", spacing)
        if np.any(self.spacing <= 0):
            raise ValueError("spacing must be positive (mm); got %s" % (tuple(self.spacing),))
        self.origin = _three("origin", origin)
        direction = np.eye(3) if direction is None else np.asarray(direction, dtype=np.float64)
        if direction.shape != (3, 3) or not np.all(np.isfinite(direction)):
            raise ValueError("direction must be a finite 3 x 3 matrix; got shape %s" % (direction.shape,))
        if not np.allclose(direction.T @ direction, np.eye(3), atol=1e-3):
            raise ValueError("direction must have orthonormal columns (a rotation or reflection)")
        self.direction = direction

    @property
    def size(self):
        """Voxels along x, y, z (ITK's order)."""
        shape = self.array.shape
        return (shape[2], shape[1], shape[0])

    @property
    def components(self):
        return self.array.shape[3] if self.array.ndim == 4 else 1

    @property
    def dtype(self):
        return self.array.dtype

    def index_to_point(self, index):
        """Physical point (mm) of an (x, y, z) voxel index (continuous indices allowed)."""
        return self.origin + self.direction @ (self.spacing * np.asarray(index, dtype=np.float64))

    def point_to_index(self, point):
        """Continuous (x, y, z) index of a physical point (mm)."""
        return (self.direction.T @ (np.asarray(point, dtype=np.float64) - self.origin)) / self.spacing

    def same_grid(self, other, tolerance=1e-6):
        """True when both images have the same voxel grid (size, spacing, origin, direction)."""
        return (
            self.size == other.size
            and np.allclose(self.spacing, other.spacing, rtol=tolerance)
            and np.allclose(self.origin, other.origin, atol=tolerance * np.max(np.abs(self.spacing)))
            and np.allclose(self.direction, other.direction, atol=tolerance)
        )

    def copy(self):
        return Image(self.array.copy(), self.spacing, self.origin, self.direction)

    def __repr__(self):
        return "Image(size=%s, spacing=%s, dtype=%s%s)" % (
            self.size,
            tuple(float(s) for s in self.spacing),
            self.array.dtype,
            "" if self.components == 1 else ", components=%d" % self.components,
        )


def _three(name, values):
    values = np.asarray(values, dtype=np.float64).reshape(-1)
    if values.shape != (3,) or not np.all(np.isfinite(values)):
        raise ValueError("%s must be three finite numbers (x, y, z); got %r" % (name, values))
    return values


def image_from_array(array, spacing=(1.0, 1.0, 1.0), origin=(0.0, 0.0, 0.0), direction=None, is_vector=False):
    """An Image holding a copy of ``array`` ([z, y, x], or [z, y, x, component] with is_vector)."""
    return image_view_from_array(np.array(array, copy=True), spacing, origin, direction, is_vector)


def image_view_from_array(array, spacing=(1.0, 1.0, 1.0), origin=(0.0, 0.0, 0.0), direction=None, is_vector=False):
    """An Image that shares ``array``'s memory (changes show in both)."""
    array = np.asarray(array)
    expected = 4 if is_vector else 3
    if array.ndim != expected:
        raise ValueError(
            "image_from_array needs a %s array%s; got shape %s"
            % (
                "4-D [z, y, x, component]" if is_vector else "3-D [z, y, x]",
                "" if is_vector else " (pass is_vector=True for [z, y, x, component])",
                array.shape,
            )
        )
    return Image(array, spacing, origin, direction)


def array_from_image(image):
    """A copy of the image's voxels, indexed [z, y, x] (ITK Python's order)."""
    return np.array(_check(image).array, copy=True)


def array_view_from_image(image):
    """The image's voxels without a copy, indexed [z, y, x]."""
    return _check(image).array


def _check(image):
    if not isinstance(image, Image):
        raise TypeError("expected a biomechanical_registration.Image, got %s" % type(image).__name__)
    return image
