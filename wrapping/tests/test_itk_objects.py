"""ITK objects in, ITK objects out (issue 61): the module's functions given ITK Python's
own images and transforms (`import itk`, the 5.4 wheels) answer with them, geometry exact,
results equal to those of the package's own Image objects.

Needs `itk` (skipped without it): run with scripts/install-python-environment.sh's venv,
    PYTHONPATH=build/python build/venv/bin/python -m pytest wrapping/tests/test_itk_objects.py
"""

import importlib.util
import sys

import numpy as np
import pytest

if importlib.util.find_spec("itk") is None:
    pytest.skip("itk (ITK's 5.4 wheels) is not importable by %s: run with build/venv/bin/python "
                "(scripts/install-python-environment.sh)" % sys.executable, allow_module_level=True)

import itk
from itk.support.helpers import camel_to_snake_case

import biomechanical_registration as bmr
from conftest import COLIN27, SOURCE_DIR, ball_mask

# An oblique grid 1 m off the origin: a rotation about (1, 2, 2)/3 by 0.4 rad.
AXIS = np.array([1.0, 2.0, 2.0]) / 3.0
CROSS = np.array([[0, -AXIS[2], AXIS[1]], [AXIS[2], 0, -AXIS[0]], [-AXIS[1], AXIS[0], 0]])
OBLIQUE = np.eye(3) + np.sin(0.4) * CROSS + (1 - np.cos(0.4)) * CROSS @ CROSS
ORIGIN = (1000.25, -512.5, 33.125)
SPACING = (0.9, 1.1, 1.7)


def itk_image(array, spacing=SPACING, origin=ORIGIN, direction=OBLIQUE):
    image = itk.image_from_array(np.ascontiguousarray(array))
    image.SetSpacing(spacing)
    image.SetOrigin(origin)
    image.SetDirection(itk.matrix_from_array(np.asarray(direction, dtype=np.float64)))
    return image


def geometry(image):
    return (tuple(image.GetSpacing()), tuple(image.GetOrigin()), itk.array_from_matrix(image.GetDirection()).tolist(),
            tuple(image.GetLargestPossibleRegion().GetSize()))


@pytest.mark.parametrize("pixel", ["uint8", "int16", "uint16", "float32", "float64"])
def test_an_itk_image_comes_back_an_itk_image_with_its_geometry(pixel):
    values = (np.arange(7 * 6 * 5).reshape(7, 6, 5) % 97).astype(pixel)
    image = itk_image(values)
    warped = bmr.warp_image(image, bmr.identity_transform())
    # uint8 images are label maps to the module (warped by nearest neighbour, kept uint8); the rest float.
    kept = np.uint8 if pixel == "uint8" else np.float32
    assert isinstance(warped, itk.Image[itk.UC if pixel == "uint8" else itk.F, 3])
    assert geometry(warped) == geometry(image)
    # The identity at the voxel centres: every value (to the rounding of the oblique index -> point -> index).
    np.testing.assert_allclose(itk.array_from_image(warped), values.astype(kept), rtol=0, atol=1e-9)
    # The package's own image objects are untouched by the bridge.
    own = bmr.warp_image(bmr.image_from_itk(image), bmr.identity_transform())
    assert isinstance(own, bmr.Image)
    np.testing.assert_array_equal(own.array, itk.array_from_image(warped))


def test_the_bridge_shares_memory_both_ways():
    image = itk_image(np.zeros((4, 5, 6), dtype=np.float32))
    view = bmr.image_from_itk(image)
    itk.array_view_from_image(image)[1, 2, 3] = 7.5
    assert view.array[1, 2, 3] == 7.5
    own = bmr.image_from_array(np.zeros((4, 5, 6), dtype=np.uint8), SPACING, ORIGIN, OBLIQUE)
    back = bmr.itk_image_from_image(own)
    own.array[3, 2, 1] = 9
    assert itk.array_view_from_image(back)[3, 2, 1] == 9
    assert isinstance(back, itk.Image[itk.UC, 3]) and geometry(back) == geometry(image)[:3] + ((6, 5, 4),)


def test_a_temporary_itk_image_lives_as_long_as_the_call_needs_it():
    # map_materials(model, classification.memberships): the itk image exists only in the call. Before the
    # bridge kept it, its voxels were freed (and overwritten) before the C++ side read them.
    def temporary():
        return bmr.itk_image_from_image(bmr.image_from_array(np.full((20, 20, 20), 3.0, dtype=np.float32)))

    view = bmr.image_from_itk(temporary())
    import gc

    gc.collect()
    clutter = [np.zeros(24000) for _ in range(50)]  # reuses freed memory
    assert float(view.array.sum()) == 3.0 * 20**3 and len(clutter) == 50
    warped = bmr.warp_image(temporary(), bmr.identity_transform())
    assert float(itk.array_view_from_image(warped).sum()) == 3.0 * 20**3


def test_multicomponent_images_come_out_as_itk_vector_images():
    field = bmr.image_from_array(np.arange(2 * 3 * 4 * 3, dtype=np.float32).reshape(2, 3, 4, 3), SPACING, ORIGIN,
                                 OBLIQUE, is_vector=True)
    converted = bmr.itk_image_from_image(field)
    assert isinstance(converted, itk.VectorImage[itk.F, 3]) and converted.GetNumberOfComponentsPerPixel() == 3
    assert geometry(converted) == (SPACING, ORIGIN, OBLIQUE.tolist(), (4, 3, 2))
    np.testing.assert_array_equal(itk.array_view_from_image(converted), field.array)
    # and back, where a multi-component image is taken (map_materials' memberships)
    assert bmr.itk_bridge.image_from_itk(converted, "memberships", allow_components=True).array.shape == (2, 3, 4, 3)


def test_wrong_itk_images_and_transforms_are_named():
    image = itk_image(np.zeros((6, 6, 6), dtype=np.float32))
    with pytest.raises(TypeError, match=r"^image: an itk 2-D image of scalar pixels \(itkImageF2\); a 3-D scalar"):
        bmr.warp_image(itk.image_from_array(np.zeros((5, 5), dtype=np.float32)), bmr.identity_transform())
    with pytest.raises(TypeError, match=r"^image: an itk 3-D image of vector pixels \(itkImageVF33, 3 components\)"):
        bmr.warp_image(itk.Image[itk.Vector[itk.F, 3], 3].New(), bmr.identity_transform())
    with pytest.raises(TypeError, match=r"^brain_mask: an itk 3-D image of vector pixels \(itkVectorImageF3"):
        bmr.register(image, brain_mask=itk.VectorImage[itk.F, 3].New())
    with pytest.raises(TypeError, match=r"^label_maps\[1\]: an itk 2-D image"):
        bmr.register(image, brain_mask=image, label_maps=[image, itk.Image[itk.UC, 2].New()])
    with pytest.raises(TypeError, match=r"^transform: an itk transform of 2-D points to 2-D \(itkEuler2DTransformD\)"):
        bmr.warp_image(image, itk.Euler2DTransform[itk.D].New())
    with pytest.raises(ValueError, match=r"^image: the itk image is empty"):
        bmr.warp_image(itk.Image[itk.F, 3].New(), bmr.identity_transform())


def test_itk_transforms_go_both_ways_exactly():
    points = np.random.default_rng(5).uniform(-40, 40, (200, 3))
    displacements = np.stack([np.sin(points[:, 1] / 20), np.cos(points[:, 0] / 25), points[:, 2] / 40], axis=1)
    reference = itk_image(np.zeros((30, 30, 30), dtype=np.float32), (3.0, 3.0, 3.0), (-45.0, -45.0, -45.0), np.eye(3))
    transform, _ = bmr.fit_transform(points, displacements, reference)
    assert isinstance(transform, itk.BSplineTransform[itk.D, 3, 3])
    own, _ = bmr.fit_transform(points, displacements, bmr.image_from_itk(reference))
    np.testing.assert_array_equal(np.array([transform.TransformPoint(p) for p in points]), own.transform_points(points))
    back = bmr.transform_from_itk(transform)
    np.testing.assert_array_equal(back.transform_points(points), own.transform_points(points))
    # ITK's functional resampling with it is the module's warp, voxel for voxel.
    moving = itk_image(np.random.default_rng(2).uniform(0, 100, (30, 30, 30)).astype(np.float32), (3.0, 3.0, 3.0),
                       (-45.0, -45.0, -45.0), np.eye(3))
    resampled = itk.resample_image_filter(moving, transform=transform, use_reference_image=True, reference_image=moving)
    warped = bmr.warp_image(moving, transform)
    np.testing.assert_allclose(itk.array_from_image(resampled), itk.array_from_image(warped), rtol=0, atol=1e-4)


def test_functional_names_are_itks_of_the_filters():
    classes = {"AtlasBrainMaskImageFilter", "FuzzyCMeansClassifierImageFilter", "BiomechanicalGridImageFilter",
               "BiomechanicalMaterialMappingFilter", "BiomechanicalRegionsFilter", "BrainSurfaceMeshSource",
               "DisplacementPointSetToBSplineTransformFilter", "EdgeHausdorffDistanceImageFilter",
               "TransformWarpImageFilter", "BSplineIntensityRegistrationFilter"}
    for name in classes:
        assert callable(getattr(bmr, camel_to_snake_case(name))), name


def test_the_functional_form_takes_the_filters_set_methods():
    mask = ball_mask(24, 9.0)
    values = np.where(bmr.array_from_image(mask) > 0, 40.0, 0.0).astype(np.float32)
    z, y, x = np.indices(values.shape)
    values[(x > 12) & (values > 0)] = 80.0
    values[(y > 14) & (x <= 12) & (values > 0)] = 120.0
    image, itk_mask = itk_image(values, (1.0, 1.0, 1.0), (0.0, 0.0, 0.0), np.eye(3)), bmr.itk_image_from_image(mask)
    functional = bmr.fuzzy_c_means_classifier_image_filter(image, mask_image=itk_mask, number_of_classes=3,
                                                             maximum_number_of_iterations=50)
    short = bmr.classify_tissue(bmr.image_from_itk(image), mask=mask, classes=3, max_iterations=50)
    assert isinstance(functional, bmr.TissueClassification)
    assert isinstance(functional.memberships, itk.VectorImage[itk.F, 3])
    np.testing.assert_array_equal(itk.array_from_image(functional.labels), short.labels.array)
    np.testing.assert_array_equal(itk.array_from_image(functional.memberships), short.memberships.array)
    with pytest.raises(TypeError, match=r"fuzzy_c_means_classifier_image_filter\(\) got unknown keyword number_of_clases"):
        bmr.fuzzy_c_means_classifier_image_filter(image, number_of_clases=3)


@pytest.fixture(scope="module")
def colin27_itk():
    if not (COLIN27 / "ch2.nii.gz").exists():
        pytest.skip("Colin27 (mricron-data) is not installed")
    image = itk.imread(str(COLIN27 / "ch2.nii.gz"), itk.F)
    bet = itk.imread(str(COLIN27 / "ch2bet.nii.gz"))
    mask = itk.binary_threshold_image_filter(bet, lower_threshold=1, upper_threshold=255, inside_value=1,
                                             outside_value=0)
    points, displacements = bmr.read_sparse_displacements(SOURCE_DIR / "examples" / "data" /
                                                          "colin27-superior-craniotomy.csv")
    return image, mask, points, displacements


COARSE = dict(craniotomy_centre=(-11, 43, 84), craniotomy_radius=30, element_size=10, threads=1)


def test_registration_from_itk_images_is_that_of_the_packages_images(colin27_itk, tmp_path):
    image, mask, points, displacements = colin27_itk
    result = bmr.register(image, brain_mask=mask, sparse_points=points, sparse_displacements=displacements, **COARSE)
    own = bmr.register(bmr.image_from_itk(image), brain_mask=bmr.image_from_itk(mask), sparse_points=points,
                       sparse_displacements=displacements, **COARSE)
    assert isinstance(result, bmr.RegistrationResult) and result.report["solve"]["converged"]
    assert result.report["solve"]["steps"] == own.report["solve"]["steps"]
    warped = result.warped_image
    assert isinstance(warped, itk.Image[itk.F, 3]) and geometry(warped) == geometry(image)
    np.testing.assert_array_equal(itk.array_from_image(warped), own.warped_image.array)
    assert isinstance(result.brain_model.brain_mask, itk.Image[itk.UC, 3])
    transform = result.transform
    assert isinstance(transform, itk.BSplineTransform[itk.D, 3, 3])
    samples = np.random.default_rng(1).uniform(-60, 60, (200, 3))
    np.testing.assert_array_equal(np.array([transform.TransformPoint(p) for p in samples]),
                                  own.transform.transform_points(samples))
    # Written by ITK 5.4, read by the module (what 3D Slicer reads too).
    itk.transformwrite([transform], str(tmp_path / "transform.h5"))
    np.testing.assert_array_equal(bmr.read_transform(tmp_path / "transform.h5").transform_points(samples),
                                  own.transform.transform_points(samples))

    # The two phases with itk images: the bundle and the update read as itk objects; the
    # update's previous= takes the view.
    bundle = bmr.prepare(image, brain_mask=mask, **COARSE)
    assert isinstance(bundle, bmr.ModelBundle) and isinstance(bundle.preoperative_image, itk.Image[itk.F, 3])
    update = bmr.update(bundle, sparse_points=points, sparse_displacements=displacements)
    np.testing.assert_array_equal(itk.array_from_image(update.warped_image), own.warped_image.array)
    again = bmr.update(bundle, sparse_points=points, sparse_displacements=displacements, previous=update)
    assert again.report["solve"]["warm_started"] and isinstance(again.transform, itk.BSplineTransform[itk.D, 3, 3])
