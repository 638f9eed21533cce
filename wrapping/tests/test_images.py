"""Images: NumPy arrays with geometry, ITK Python's axis order, file round trips."""

import gzip
import struct

import numpy as np
import pytest

import biomechanical_registration as bmr
from conftest import ball_mask

# An oblique grid: anisotropic spacing, an origin, a rotation about z by 30 degrees.
ANGLE = np.radians(30.0)
DIRECTION = np.array([[np.cos(ANGLE), -np.sin(ANGLE), 0.0], [np.sin(ANGLE), np.cos(ANGLE), 0.0], [0.0, 0.0, 1.0]])
SPACING = (0.8, 1.25, 2.5)
ORIGIN = (-12.0, 40.5, 7.25)


def ramp(shape=(5, 6, 7), dtype=np.float32):
    """Values that name their voxel: 100 z + 10 y + x."""
    z, y, x = np.indices(shape)
    return (100 * z + 10 * y + x).astype(dtype)


def test_image_from_array_copies_and_view_shares():
    array = ramp()
    image = bmr.image_from_array(array, SPACING, ORIGIN, DIRECTION)
    view = bmr.image_view_from_array(array, SPACING, ORIGIN, DIRECTION)
    array[0, 0, 0] = -1
    assert image.array[0, 0, 0] == 0
    assert view.array[0, 0, 0] == -1
    assert bmr.array_view_from_image(view) is view.array
    copy = bmr.array_from_image(view)
    copy[0, 0, 0] = 5
    assert view.array[0, 0, 0] == -1


def test_size_is_x_y_z_of_a_z_y_x_array():
    image = bmr.image_from_array(ramp((5, 6, 7)))
    assert image.size == (7, 6, 5)
    assert image.array.shape == (5, 6, 7)


@pytest.mark.parametrize("dtype", [np.float32, np.uint8])
def test_nifti_round_trip_keeps_values_and_geometry(tmp_path, dtype):
    image = bmr.image_from_array(ramp(dtype=dtype) % 251 if dtype == np.uint8 else ramp(dtype=dtype), SPACING, ORIGIN, DIRECTION)
    bmr.imwrite(image, tmp_path / "image.nii.gz")
    back = bmr.imread(tmp_path / "image.nii.gz")
    assert back.array.dtype == dtype
    np.testing.assert_array_equal(back.array, image.array)
    np.testing.assert_allclose(back.spacing, SPACING, rtol=1e-6)
    np.testing.assert_allclose(back.origin, ORIGIN, atol=1e-5)
    np.testing.assert_allclose(back.direction, DIRECTION, atol=1e-6)


def test_multicomponent_round_trip(tmp_path):
    values = np.random.default_rng(1).random((4, 5, 6, 3)).astype(np.float32)
    image = bmr.image_from_array(values, SPACING, ORIGIN, is_vector=True)
    bmr.imwrite(image, tmp_path / "memberships.nii.gz")
    back = bmr.imread(tmp_path / "memberships.nii.gz")
    assert back.components == 3
    np.testing.assert_array_equal(back.array, values)


def test_array_order_is_that_of_the_nifti_file(tmp_path):
    """Independent of ITK: the NIfTI header's dim[1..3] is (x, y, z) and x varies fastest in its data."""
    image = bmr.image_from_array(ramp((5, 6, 7)), SPACING, ORIGIN)
    bmr.imwrite(image, tmp_path / "image.nii.gz")
    raw = gzip.decompress((tmp_path / "image.nii.gz").read_bytes())
    dims = struct.unpack("<8h", raw[40:56])
    assert dims[:4] == (3, 7, 6, 5)
    assert struct.unpack("<h", raw[70:72])[0] == 16  # NIFTI_TYPE_FLOAT32
    pixdim = struct.unpack("<8f", raw[76:108])
    np.testing.assert_allclose(pixdim[1:4], SPACING, rtol=1e-6)
    offset = int(struct.unpack("<f", raw[108:112])[0])
    data = np.frombuffer(raw[offset : offset + 7 * 6 * 5 * 4], dtype="<f4")
    np.testing.assert_array_equal(data, image.array.ravel())
    assert data[1] == 1.0 and data[7] == 10.0 and data[42] == 100.0  # x, then y, then z


def test_geometry_maps_voxels_as_itk_does():
    """A box of voxels meshed by the C++ grid generator lands where index_to_point puts it."""
    labels = np.zeros((12, 14, 16), np.uint8)
    labels[2:10, 3:11, 4:12] = 1  # z 2..9, y 3..10, x 4..11
    image = bmr.image_from_array(labels, (1.0, 1.0, 1.0), ORIGIN, DIRECTION)
    grid = bmr.make_grid(image, kind="hexahedra", element_size=2.0)
    nodes = grid.model.nodes
    # The box's corners (voxel faces) in index space are x 3.5..11.5, y 2.5..10.5, z 1.5..9.5.
    corners = np.array([[x, y, z] for x in (3.5, 11.5) for y in (2.5, 10.5) for z in (1.5, 9.5)])
    expected = np.array([image.index_to_point(c) for c in corners])
    for corner in expected:
        assert np.min(np.linalg.norm(nodes - corner, axis=1)) < 1e-9
    assert len(nodes) == 5 * 5 * 5
    np.testing.assert_allclose(grid.quality["mesh_volume_mm3"], 8 * 8 * 8, rtol=1e-12)


def test_point_to_index_inverts_index_to_point():
    image = bmr.image_from_array(ramp(), SPACING, ORIGIN, DIRECTION)
    index = np.array([1.5, -2.0, 3.25])
    np.testing.assert_allclose(image.point_to_index(image.index_to_point(index)), index, atol=1e-12)


def test_bad_images_are_named():
    with pytest.raises(ValueError, match="shape"):
        bmr.image_from_array(np.zeros((4, 4)))
    with pytest.raises(ValueError, match="spacing must be positive"):
        bmr.image_from_array(np.zeros((2, 2, 2)), spacing=(1, 0, 1))
    with pytest.raises(ValueError, match="orthonormal"):
        bmr.image_from_array(np.zeros((2, 2, 2)), direction=np.ones((3, 3)))
    with pytest.raises(TypeError, match="biomechanical_registration.Image"):
        bmr.classify_tissue(np.zeros((4, 4, 4)))
    with pytest.raises(TypeError, match="uint8"):
        bmr.make_grid(bmr.image_from_array(np.ones((4, 4, 4), np.float32)))
    with pytest.raises(ValueError, match="labels 0..255"):
        bmr.make_grid(bmr.image_from_array(np.full((4, 4, 4), 300, np.int32)))
    with pytest.raises(TypeError, match="biomechanical_registration.Image"):
        bmr.imwrite(np.zeros((2, 2, 2)), "never.nii.gz")
    with pytest.raises(TypeError, match="biomechanical_registration.Image"):
        bmr.warp_image(np.zeros((2, 2, 2)), bmr.identity_transform())
    with pytest.raises(TypeError, match="numbers"):
        bmr.imwrite(bmr.image_from_array(np.zeros((2, 2, 2), np.complex64)), "never.nii.gz")


def test_missing_and_unwritable_files_raise_error(tmp_path):
    with pytest.raises(bmr.Error, match="missing.nii.gz"):
        bmr.imread(tmp_path / "missing.nii.gz")
    with pytest.raises(ValueError, match="pixel_type"):
        bmr.imread(tmp_path / "missing.nii.gz", pixel_type="int16")
    with pytest.raises(bmr.Error):
        bmr.imwrite(ball_mask(8, 2), tmp_path / "no-such-folder" / "mask.nii.gz")
    assert not (tmp_path / "no-such-folder").exists()
    assert issubclass(bmr.Error, RuntimeError)
