"""The ITK layer from Python: surfaces, transform fitting, warping, evaluation,
the B-spline baseline, the patient model and the one-call registration
(identical to `biomech register`), and the install command."""

import json
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

import biomechanical_registration as bmr
from conftest import COLIN27, SOURCE_DIR, ball_mask


def blob(size=40, centre_shift=(0.0, 0.0, 0.0), spacing=1.0):
    """A smooth float image with structure everywhere (for warps and registrations)."""
    z, y, x = (np.indices((size, size, size)) - (size - 1) / 2.0) * spacing
    x, y, z = x - centre_shift[0], y - centre_shift[1], z - centre_shift[2]
    values = 100 * np.exp(-(x**2 + y**2 + z**2) / (2 * (0.25 * size * spacing) ** 2))
    values += 30 * np.exp(-((x - 5) ** 2 + (y + 4) ** 2 + z**2) / 18.0)
    return bmr.image_from_array(values.astype(np.float32), (spacing,) * 3, origin=(-(size - 1) / 2.0 * spacing,) * 3)


def grid_points(low, high, count):
    axis = np.linspace(low, high, count)
    return np.array(np.meshgrid(axis, axis, axis, indexing="ij")).reshape(3, -1).T


def translation(reference, vector):
    """The backward map of a uniform forward displacement `vector`, fitted from points over
    the whole reference grid (the fitted field is then within a few hundredths of a mm of the constant)."""
    corner = reference.index_to_point((0, 0, 0))
    points = grid_points(corner[0], -corner[0], 8)
    transform, report = bmr.fit_transform(points, np.tile(vector, (len(points), 1)), reference, tolerance=0.01)
    return transform, report


def test_fit_transform_inverts_the_displacements_at_the_points():
    reference = blob(32)
    points = grid_points(-12, 12, 7)
    displacements = np.column_stack([0.05 * points[:, 1], -0.03 * points[:, 0], 1.0 + 0.02 * points[:, 2]])
    transform, report = bmr.fit_transform(points, displacements, reference, tolerance=0.01)
    assert report["tolerance_reached"] and report["max_residual_mm"] <= 0.01
    # Backward map: T(x + u(x)) = x.
    np.testing.assert_allclose(transform.transform_points(points + displacements), points, atol=0.011)
    field = transform.displacement_field(reference)
    assert field.array.shape == (32, 32, 32, 3)
    centre = field.array[16, 16, 16]
    np.testing.assert_allclose(centre, transform.transform_points([reference.index_to_point((16, 16, 16))])[0] -
                               reference.index_to_point((16, 16, 16)), atol=1e-5)
    with pytest.raises(ValueError, match="differ in length"):
        bmr.fit_transform(points, displacements[:-1], reference)
    with pytest.raises(bmr.Error, match="points"):
        bmr.fit_transform(points[:3], displacements[:3], reference)
    with pytest.raises(bmr.Error, match="olerance"):
        bmr.fit_transform(points, displacements, reference, tolerance=0)


def test_warp_by_a_translation_shifts_the_image():
    image = blob(40)
    transform, _ = translation(image, [2.0, 0.0, 0.0])
    warped = bmr.warp_image(image, transform)
    assert warped.same_grid(image) and warped.array.dtype == np.float32
    # Forward motion +2 mm in x: the warped image at x holds the original at x - 2 (2 voxels).
    # The fitted translation is within about 0.03 mm of 2 mm; the gradient reaches about 6 per mm.
    np.testing.assert_allclose(warped.array[8:32, 8:32, 10:30], image.array[8:32, 8:32, 8:28], atol=0.2)
    assert np.max(np.abs(warped.array[8:32, 8:32, 10:30] - image.array[8:32, 8:32, 12:32])) > 10
    labels = bmr.image_from_array((image.array > 50).astype(np.uint8), image.spacing, image.origin)
    warped_labels = bmr.warp_image(labels, transform)
    assert warped_labels.array.dtype == np.uint8 and set(np.unique(warped_labels.array)) <= {0, 1}
    linear = bmr.warp_image(labels, transform, interpolation="linear")
    assert linear.array.dtype == np.float32
    coarse = bmr.image_from_array(np.zeros((10, 10, 10), np.float32), (4.0,) * 3, image.origin)
    assert bmr.warp_image(image, transform, reference=coarse).same_grid(coarse)
    with pytest.raises(ValueError, match="interpolation"):
        bmr.warp_image(image, transform, interpolation="cubic")
    with pytest.raises(TypeError):
        bmr.warp_image(image, "not a transform")


def test_edge_evaluation_measures_a_known_shift():
    image = blob(48)
    same = bmr.evaluate_edges(image, image, slice_axis=-1)
    assert same.valid and same.percentile(100) == 0 and same.fraction_within_threshold == 1.0
    transform, _ = translation(image, [3.0, 0.0, 0.0])
    shifted = bmr.warp_image(image, transform)
    region = bmr.image_from_array(ball_mask(48, 18).array, image.spacing, image.origin)
    moved = bmr.evaluate_edges(image, shifted, region, slice_axis=-1)
    assert moved.valid and len(moved.percentiles) == 100
    assert 1.0 <= moved.percentile(95) <= 3.5
    assert moved.fixed_edge_image.array.dtype == np.uint8 and moved.fixed_edge_image.same_grid(image)
    # Canny settings reach the filter: thresholds above every gradient leave no edge to measure.
    none = bmr.evaluate_edges(image, shifted, upper_threshold=1e9, lower_threshold=1e9, slice_axis=-1)
    assert not none.valid and none.message and none.fixed_edges == 0
    with pytest.raises(bmr.Error, match="grid"):
        bmr.evaluate_edges(image, blob(32))
    with pytest.raises(bmr.Error, match="both the upper and the lower"):
        bmr.evaluate_edges(image, image, upper_threshold=3.0)


def test_bspline_baseline_recovers_a_shift():
    fixed = blob(40)
    transform, _ = translation(fixed, [2.0, -1.0, 0.0])
    moving_truth = bmr.warp_image(fixed, transform)  # fixed moved by (2, -1, 0)
    result = bmr.bspline_registration(moving_truth, fixed, shrink_factors=[2, 1], smoothing_sigmas=[1.0, 0.0], iterations=30)
    before = bmr.evaluate_edges(moving_truth, bmr.warp_image(fixed, bmr.identity_transform()), slice_axis=-1)
    after = bmr.evaluate_edges(moving_truth, result.warped, slice_axis=-1)
    assert after.percentile(95) < 0.5 * before.percentile(95)
    centre = np.array([[0.0, 0.0, 0.0]])
    np.testing.assert_allclose(result.transform.transform_points(centre + [2, -1, 0]), centre, atol=0.3)
    with pytest.raises(ValueError, match="levels"):
        bmr.bspline_registration(moving_truth, fixed, shrink_factors=[2, 1], smoothing_sigmas=[1.0])
    for setting, message in [({"control_point_spacing": -1}, "ControlPointSpacing"),
                             ({"histogram_bins": 1}, "NumberOfHistogramBins"),
                             ({"metric_sampling_percentage": 2.0}, "MetricSamplingPercentage")]:
        with pytest.raises(bmr.Error, match=message):
            bmr.bspline_registration(moving_truth, fixed, shrink_factors=[1], smoothing_sigmas=[0.0], iterations=2, **setting)


def test_brain_surfaces_of_a_ball():
    mask = ball_mask(48, 15, spacing=(1.0, 1.0, 1.0))
    brain, skull = bmr.brain_surfaces(mask, skull_gap=3.0)
    assert brain.is_closed() and skull.is_closed()
    np.testing.assert_allclose(brain.enclosed_volume(), 4 / 3 * np.pi * 15**3, rtol=0.03)
    np.testing.assert_allclose(skull.enclosed_volume(), 4 / 3 * np.pi * 18**3, rtol=0.05)
    with pytest.raises(bmr.Error):
        bmr.brain_surfaces(bmr.image_from_array(np.zeros((8, 8, 8), np.uint8)))
    # A ball is convex: closing it changes nothing beyond the smoothing's tolerance.
    _, closed = bmr.brain_surfaces(mask, skull_gap=3.0, skull_closing=2.0)
    np.testing.assert_allclose(closed.enclosed_volume(), skull.enclosed_volume(), rtol=0.01)
    with pytest.raises(bmr.Error, match="SkullClosing"):
        bmr.brain_surfaces(mask, skull_closing=-1.0)


def test_transform_files_round_trip(tmp_path):
    image = blob(24)
    transform, _ = translation(image, [1.5, 0.5, -0.5])
    bmr.write_transform(transform, tmp_path / "transform.h5")
    back = bmr.read_transform(tmp_path / "transform.h5")
    points = grid_points(-8, 8, 4)
    np.testing.assert_array_equal(back.transform_points(points), transform.transform_points(points))
    assert back.name == "BSplineTransform"
    with pytest.raises(bmr.Error, match="extension"):
        transform.write(tmp_path / "transform.xyz")
    with pytest.raises(bmr.Error):
        bmr.read_transform(tmp_path / "missing.h5")


def test_measure_displacement_error_of_a_known_offset():
    image = blob(24)
    truth, _ = translation(image, [2.0, 0.0, 0.0])
    region = ball_mask(24, 6)
    region = bmr.image_from_array(region.array, image.spacing, image.origin)
    none = bmr.measure_displacement_error(None, truth, region, stride=1)
    np.testing.assert_allclose([none["mean_mm"], none["max_mm"]], 2.0, atol=0.05)  # the fitted translation's error
    exact = bmr.measure_displacement_error(truth, truth, region)
    assert exact["max_mm"] == 0.0
    with pytest.raises(ValueError, match="stride"):
        bmr.measure_displacement_error(None, truth, region, stride=0)


def test_surface_distance_and_ventricles_from_python():
    # A 6 mm ball moved 2 mm: a sphere's point at cos theta = u is 2 |u| mm from the moved sphere (to first order),
    # uniform in u, so the 95th percentile is 1.9 mm (the ball's 1 mm voxels allow 0.6 mm).
    image = blob(24)
    truth, _ = translation(image, [2.0, 0.0, 0.0])
    ball = ball_mask(24, 6)
    ball = bmr.image_from_array(ball.array, image.spacing, image.origin)
    assert bmr.surface_distance_p95(truth, truth, ball) == 0.0
    assert abs(bmr.surface_distance_p95(None, truth, ball) - 1.9) < 0.6
    # A T1-like ball brain (white 100, grey shell 70, CSF 20) with a central ventricle and a sulcus near the surface.
    z, y, x = np.indices((64, 64, 64)) - 31.5
    radius = np.sqrt(x**2 + y**2 + z**2)
    ventricle = (x / 10.0) ** 2 + (y / 5.0) ** 2 + (z / 6.0) ** 2 <= 1.0
    sulcus = (radius > 22) & (np.abs(x) <= 1) & (z > 0)
    values = np.where(radius > 23, 70.0, 100.0)
    values[ventricle | sulcus] = 20.0
    brain = (radius <= 28).astype(np.uint8)
    values[brain == 0] = 0.0
    found = bmr.ventricle_mask(bmr.image_from_array(values.astype(np.float32)), bmr.image_from_array(brain)).array > 0
    assert not found[sulcus].any()
    assert (found != ventricle).sum() < 0.05 * ventricle.sum()  # 3.1 % measured: the opening's staircase
    with pytest.raises(bmr.Error, match="deeper"):
        bmr.ventricle_mask(bmr.image_from_array(values.astype(np.float32)), bmr.image_from_array(brain), depth=40.0)


def test_synthetic_brain_shift_needs_a_mask():
    with pytest.raises(TypeError):
        bmr.make_synthetic_brain_shift(blob(16))
    with pytest.raises(ValueError, match="brain_mask"):
        bmr.make_synthetic_brain_shift(blob(16), None)


def test_synthetic_brain_shift_names_bad_intraoperative_options():
    """The realistic intraoperative image's options are checked before the ground truth's solve."""
    image = blob(16)
    mask = bmr.image_from_array((image.array > 50).astype(np.uint8), image.spacing, image.origin, image.direction)
    with pytest.raises(ValueError, match="noise_model"):
        bmr.make_synthetic_brain_shift(image, mask, noise_model="poisson")
    with pytest.raises(bmr.Error, match="low-field-t1"):
        bmr.make_synthetic_brain_shift(image, mask, intraoperative_contrast="flair")
    with pytest.raises(bmr.Error, match="tumour"):
        bmr.make_synthetic_brain_shift(image, mask, resection_margin=3.0)
    with pytest.raises(bmr.Error, match="bias field"):
        bmr.make_synthetic_brain_shift(image, mask, bias_field=1.5)


def test_electrodes_from_a_synthetic_ct(colin27):
    """The epilepsy workflow from Python: a CT with an 8 x 8 grid after a 10 mm sag, its contacts found,
    carried into the MRI (within 0.3 mm of the truth; the C++ test measures 0.07 mm) and projected along
    gravity as loads for register()."""
    image, mask = colin27
    truth = bmr.make_synthetic_brain_shift(image, mask, element_size=6.0)
    ct = bmr.make_synthetic_electrode_ct(image, mask, truth)
    assert ct.contacts.shape == (64, 3)
    located = bmr.locate_electrodes(ct.image, image, mask, contacts=64, project_along=truth.down)
    distances = np.linalg.norm(located["contacts"][:, None, :] - ct.contacts[None, :, :], axis=2)
    assert sorted(distances.argmin(axis=1)) == list(range(64))  # each true contact found once
    assert distances.min(axis=1).max() < 0.3
    assert located["sparse_points"].shape == located["sparse_displacements"].shape == (64, 3)
    with pytest.raises(bmr.Error, match="expected 63"):
        bmr.locate_electrodes(ct.image, image, mask, contacts=63)


def test_atlas_brain_mask_follows_a_moved_colin27(colin27):
    """Colin27 at half resolution, moved by 6 mm: the atlas (Colin27 itself) must be registered to find its brain."""
    image, mask = colin27
    moved_origin = image.origin + [6.0, -4.0, 5.0]
    small = bmr.image_from_array(image.array[::2, ::2, ::2], image.spacing * 2, moved_origin, image.direction)
    found = bmr.atlas_brain_mask(small, bspline_stage=False)
    assert found.same_grid(small) and found.array.dtype == np.uint8
    expected = mask.array[::2, ::2, ::2] > 0
    dice = 2 * np.count_nonzero(expected & (found.array > 0)) / (np.count_nonzero(expected) + np.count_nonzero(found.array))
    assert dice > 0.95, dice


def test_atlas_brain_mask_names_a_missing_atlas(tmp_path):
    with pytest.raises(bmr.Error, match="missing-atlas"):
        bmr.atlas_brain_mask(blob(16), atlas_image=str(tmp_path / "missing-atlas.nii.gz"))


def sparse_csv():
    return SOURCE_DIR / "examples" / "data" / "colin27-superior-craniotomy.csv"


def test_surface_correspondence_and_mask_regions():
    """A flat top moved down 1 mm everywhere: the surface-to-surface load is -1 mm at every exposed node."""
    model = bmr.make_block_mesh((20, 20, 10), (4, 4, 2))
    exposed = model.node_sets["zmax"]

    def top(z, count=31):  # a plane over x, y in -5..25 mm with 1 mm triangles, normals up
        axis = np.linspace(-5, 25, count)
        x, y = np.meshgrid(axis, axis, indexing="ij")
        vertices = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])
        corner = (np.arange(count - 1)[:, None] * count + np.arange(count - 1)[None, :]).ravel()
        triangles = np.concatenate([np.column_stack([corner, corner + count, corner + count + 1]),
                                    np.column_stack([corner, corner + count + 1, corner + 1])])
        return bmr.Surface(vertices, triangles)

    load, report = bmr.displacements_between_surfaces(model, exposed, top(10.0), top(9.0), reach=5.0, spacing=5.0)
    np.testing.assert_array_equal(np.sort(load.nodes), np.sort(exposed))
    np.testing.assert_allclose(load.displacements, np.tile([0, 0, -1.0], (len(exposed), 1)), atol=1e-9)
    with pytest.raises(TypeError):
        bmr.displacements_between_surfaces(model, exposed, top(10.0), top(9.0))  # reach is required (it depends on the grid)
    # A mask over the block's top layer selects the top nodes.
    region = np.zeros((12, 22, 22), np.uint8)  # 1 mm voxels from (-1, -1, -1): z 8..11 mm
    region[9:, :, :] = 1
    mask = bmr.image_from_array(region, origin=(-1.0, -1.0, -1.0))
    selected = bmr.surface_nodes_in_mask(model, mask)
    np.testing.assert_array_equal(np.sort(selected), np.sort(exposed))


CRANIOTOMY = dict(craniotomy_centre=(-11, 43, 84), craniotomy_radius=30, element_size=8)


def test_register_gives_what_biomech_register_writes(tmp_path, biomech, colin27):
    image, mask = colin27
    output = tmp_path / "registration"
    run = biomech("register", COLIN27 / "ch2.nii.gz", "--mask", COLIN27 / "ch2bet.nii.gz", "--craniotomy-centre",
                  -11, 43, 84, "--craniotomy-radius", 30, "--sparse-displacements", sparse_csv(), "--element-size", 8,
                  "--labels", COLIN27 / "ch2bet.nii.gz", "-o", output, "-q")
    assert run.returncode == 0, run.stderr
    points, displacements = bmr.read_sparse_displacements(sparse_csv())
    stages = []
    result = bmr.register(image, brain_mask=mask, label_maps=[bmr.imread(COLIN27 / "ch2bet.nii.gz")],
                          sparse_points=points, sparse_displacements=displacements,
                          progress=lambda stage, fraction, info: stages.append((stage, fraction)), **CRANIOTOMY)
    report = json.loads((output / "registration-report.json").read_text())
    for section, key in [("solve", "converged"), ("solve", "steps"), ("solve", "max_displacement_mm"),
                         ("solve", "estimated_error_mm"), ("fit", "max_residual_mm"), ("loads", "used")]:
        assert result.report[section][key] == report[section][key], (section, key)
    cli = bmr.read_transform(output / "transform.h5")
    samples = grid_points(-60, 60, 9)
    np.testing.assert_array_equal(result.transform.transform_points(samples), cli.transform_points(samples))
    np.testing.assert_array_equal(result.warped_image.array, bmr.imread(output / "warped.nii.gz").array)
    np.testing.assert_array_equal(result.warped_label_maps[0].array, bmr.imread(output / "ch2bet-warped.nii.gz").array)
    assert ("solve", 1.0) in stages and ("fit", 0.0) in stages
    assert "NOT CONVERGED" not in result.table()


def test_resection_mask_from_python_and_the_command_line(tmp_path, biomech, colin27):
    """The planned resection (a 20 mm ball of brain under the craniotomy) given to register() and to
    `biomech register --resection-mask`: the same model and transform; a mask outside the brain is named."""
    image, mask = colin27
    brain = bmr.array_from_image(mask) > 0
    index = np.round(mask.point_to_index((-11, 40, 55))).astype(int)  # (x, y, z); arrays are [z, y, x]
    z, y, x = np.indices(brain.shape)
    ball = (x - index[0]) ** 2 + (y - index[1]) ** 2 + (z - index[2]) ** 2 <= 10 ** 2
    resection = bmr.image_from_array((ball & brain).astype(np.uint8), mask.spacing, mask.origin, mask.direction)
    bmr.imwrite(resection, tmp_path / "resection.nii.gz")
    output = tmp_path / "registration"
    run = biomech("register", COLIN27 / "ch2.nii.gz", "--mask", COLIN27 / "ch2bet.nii.gz", "--craniotomy-centre",
                  -11, 43, 84, "--craniotomy-radius", 30, "--sparse-displacements", sparse_csv(), "--element-size", 8,
                  "--resection-mask", tmp_path / "resection.nii.gz", "-o", output, "-q")
    assert run.returncode == 0, run.stderr
    report = json.loads((output / "registration-report.json").read_text())
    model = biomech("model", COLIN27 / "ch2.nii.gz", "--mask", COLIN27 / "ch2bet.nii.gz", "--element-size", 8,
                    "--resection-mask", tmp_path / "resection.nii.gz", "-o", tmp_path / "model", "-q")
    assert model.returncode == 0, model.stderr
    model_report = json.loads((tmp_path / "model" / "model-report.json").read_text())
    assert model_report["resected_volume_mm3"] == report["model"]["resected_volume_mm3"]
    points, displacements = bmr.read_sparse_displacements(sparse_csv())
    result = bmr.register(image, brain_mask=mask, sparse_points=points, sparse_displacements=displacements,
                          resection_mask=resection, **CRANIOTOMY)
    volume = float((ball & brain).sum()) * float(np.prod(mask.spacing))
    assert result.report["model"]["resected_volume_mm3"] == pytest.approx(volume, rel=1e-12)
    assert report["model"]["resected_volume_mm3"] == result.report["model"]["resected_volume_mm3"]
    samples = grid_points(-60, 60, 9)
    np.testing.assert_array_equal(result.transform.transform_points(samples),
                                  bmr.read_transform(output / "transform.h5").transform_points(samples))
    # The fluid's cells are CSF-soft: more of the model's materials are the CSF class's than without.
    plain = bmr.register(image, brain_mask=mask, sparse_points=points, sparse_displacements=displacements, **CRANIOTOMY)
    assert "resected_volume_mm3" not in plain.report["model"]
    softest = lambda model: sum(1 for cell in model.cell_materials if model.materials[cell].youngs_modulus <= 10.0)
    assert softest(result.brain_model.model) > softest(plain.brain_model.model)
    assert result.brain_model.resected_volume == result.report["model"]["resected_volume_mm3"]
    assert plain.brain_model.resected_volume == 0.0
    # Without gravity nothing makes the walls sag: a warning says to give it.
    assert any("without gravity nothing makes them sag" in warning for warning in result.warnings)
    assert not any("resection" in warning for warning in plain.warnings)
    corner = np.zeros(brain.shape, dtype=np.uint8)
    corner[:5, :5, :5] = 1  # the image's corner, outside the head
    outside = bmr.image_from_array(corner, mask.spacing, mask.origin, mask.direction)
    with pytest.raises(bmr.Error, match="resection mask has no voxel inside the brain"):
        bmr.register(image, brain_mask=mask, sparse_points=points, sparse_displacements=displacements,
                     resection_mask=outside, **CRANIOTOMY)


def test_build_brain_model_then_solve_reproduces_register(colin27):
    image, mask = colin27
    points, displacements = bmr.read_sparse_displacements(sparse_csv())
    brain = bmr.build_brain_model(image, mask, sparse_points=points, sparse_displacements=displacements, **CRANIOTOMY)
    assert len(brain.exposed_nodes) > 0 and brain.load_report["used"] == 61
    solved = bmr.solve(brain.model, tolerance=0.01)
    assert solved.converged
    result = bmr.register(image, brain_mask=mask, sparse_points=points, sparse_displacements=displacements, **CRANIOTOMY)
    np.testing.assert_array_equal(solved.displacements, result.solve.displacements)
    transform, report = bmr.fit_transform(brain.model.nodes, solved.displacements, image, tolerance=0.1)
    samples = grid_points(-50, 50, 5)
    np.testing.assert_array_equal(transform.transform_points(samples), result.transform.transform_points(samples))


def test_step_functions_compose_into_build_brain_model(colin27):
    """The filters' Python faces, one step at a time, give build_brain_model's model."""
    image, mask = colin27
    points, displacements = bmr.read_sparse_displacements(sparse_csv())
    brain = bmr.build_brain_model(image, mask, sparse_points=points, sparse_displacements=displacements, **CRANIOTOMY)
    classes = bmr.classify_tissue(image, mask, classes=3)
    grid = bmr.make_grid(mask, element_size=CRANIOTOMY["element_size"])
    model = bmr.map_materials(grid.model, classes.memberships)
    model = bmr.model_regions(model, craniotomy_centre=CRANIOTOMY["craniotomy_centre"],
                              craniotomy_radius=CRANIOTOMY["craniotomy_radius"])
    load, report = bmr.displacements_from_points(model, model.node_sets["exposed"], points, displacements)
    np.testing.assert_array_equal(model.nodes, brain.model.nodes)
    np.testing.assert_array_equal(model.cell_materials, brain.model.cell_materials)
    assert [m.youngs_modulus for m in model.materials] == [m.youngs_modulus for m in brain.model.materials]
    for name in ("skull_base", "exposed", "contact"):
        np.testing.assert_array_equal(model.node_sets[name], brain.model.node_sets[name], err_msg=name)
    np.testing.assert_array_equal(load.nodes, brain.load.nodes)
    np.testing.assert_array_equal(load.displacements, brain.load.displacements)
    assert report["used"] == brain.load_report["used"] == 61
    # The surfaces of the grid's cells (not of the mask): the skull must enclose the staircase.
    brain_surface, skull = bmr.brain_surfaces(mask, body=grid.model)
    np.testing.assert_array_equal(brain_surface.vertices, brain.brain_surface.vertices)
    np.testing.assert_array_equal(skull.vertices, brain.skull_surface.vertices)
    cortex, no_skull = bmr.brain_surfaces(mask, skull=False)  # what a surface scan images: the mask's smooth surface
    assert no_skull is None and cortex.vertices.shape != brain_surface.vertices.shape
    np.testing.assert_array_equal(cortex.vertices, bmr.brain_surfaces(mask)[0].vertices)
    # From a displaced surface (the cortex sunk 4 mm), matched to the cortex.
    displaced = bmr.Surface(cortex.vertices - [0.0, 0.0, 4.0], cortex.triangles)
    from_surface = bmr.build_brain_model(image, mask, intraoperative_surface=displaced, **CRANIOTOMY)
    reach = max(grid.quality["mean_edge_length_mm"], CRANIOTOMY["element_size"])
    load, report = bmr.displacements_between_surfaces(model, model.node_sets["exposed"], cortex, displaced, reach=reach)
    np.testing.assert_array_equal(load.nodes, from_surface.load.nodes)
    np.testing.assert_array_equal(load.displacements, from_surface.load.displacements)
    assert report["used"] == from_surface.load_report["used"] > 20
    assert report["rejected"] == from_surface.load_report["rejected"] == 0  # a rigid sinking: every match agrees
    # The surface sank 4 mm. Closest points see only the motion along the surface's normal where it slopes
    # (docs/registration.md), so the nodes move down by 4 mm on the crown and less on the flanks.
    sinking = -load.displacements[:, 2]
    assert np.median(sinking) == pytest.approx(4.0, abs=0.5) and sinking.min() > 1.5 and sinking.max() < 4.5, sinking
    # One craniotomy check for every face: a sphere and a mask together are refused.
    with pytest.raises(bmr.Error, match="not both"):
        bmr.model_regions(model, craniotomy_centre=(0, 0, 0), craniotomy_radius=5, craniotomy_mask=mask)


def test_csf_material_settings_reach_the_model(colin27):
    image, mask = colin27
    points, displacements = bmr.read_sparse_displacements(sparse_csv())
    defaults = bmr.default_registration_settings()
    assert defaults["csf_modulus"] == 10.0 and defaults["csf_poisson_ratio"] == 0.1
    ratios = {}
    for ratio in (0.1, 0.49):
        brain = bmr.build_brain_model(image, mask, sparse_points=points, sparse_displacements=displacements,
                                      csf_poisson_ratio=ratio, **CRANIOTOMY)
        ratios[ratio] = [material.poisson_ratio for material in brain.model.materials]
    # Cells mix the classes' values by membership: with CSF at nu 0.1 the ventricles' cells are
    # compressible (0.155 measured at 8 mm); with CSF at 0.49, as parenchyma, every cell has 0.49.
    assert min(ratios[0.1]) < 0.3
    assert ratios[0.49] == pytest.approx([0.49] * len(ratios[0.49]))
    with pytest.raises(ValueError, match="csf_poisson_ratio"):
        bmr.build_brain_model(image, mask, sparse_points=points, sparse_displacements=displacements,
                              csf_poisson_ratio=0.5, **CRANIOTOMY)


def test_csf_drainage_places_the_fluid_surface_below_the_top(colin27):
    image, mask = colin27
    points, displacements = bmr.read_sparse_displacements(sparse_csv())
    assert bmr.default_registration_settings()["csf_drained_depth"] is None
    brain = bmr.build_brain_model(image, mask, sparse_points=points, sparse_displacements=displacements,
                                  gravity=(0, 0, -9810), csf_drained_depth=40.0, **CRANIOTOMY)
    top = max(node[2] for node in brain.model.nodes)
    assert brain.model.fluid_surface[2] == pytest.approx(top - 40.0)
    assert bmr.build_brain_model(image, mask, sparse_points=points, sparse_displacements=displacements,
                                 gravity=(0, 0, -9810), **CRANIOTOMY).model.fluid_surface is None
    with pytest.raises(bmr.Error, match="without gravity"):
        bmr.build_brain_model(image, mask, sparse_points=points, sparse_displacements=displacements,
                              csf_drained_depth=40.0, **CRANIOTOMY)


def test_register_bad_arguments_are_named(colin27):
    image, mask = colin27
    points, displacements = bmr.read_sparse_displacements(sparse_csv())
    with pytest.raises(TypeError, match="element_sise"):
        bmr.register(image, brain_mask=mask, sparse_points=points, sparse_displacements=displacements, element_sise=8)
    with pytest.raises(TypeError, match="'element_size' must be a number, got 'eight'"):
        bmr.register(image, brain_mask=mask, sparse_points=points, sparse_displacements=displacements, element_size="eight")
    with pytest.raises(ValueError, match="grid.*hexahedra"):
        bmr.register(image, brain_mask=mask, sparse_points=points, sparse_displacements=displacements, grid="bricks")
    with pytest.raises(ValueError, match="both sparse_points and sparse_displacements"):
        bmr.register(image, brain_mask=mask, sparse_points=points, **CRANIOTOMY)
    with pytest.raises(ValueError, match="craniotomy_radius"):
        bmr.register(image, brain_mask=mask, sparse_points=points, sparse_displacements=displacements,
                     craniotomy_centre=(0, 0, 0))
    with pytest.raises(bmr.Error, match="grid"):
        bmr.register(image, brain_mask=ball_mask(16, 5), sparse_points=points, sparse_displacements=displacements,
                     **CRANIOTOMY)
    with pytest.raises(bmr.Error):
        bmr.register(image, brain_mask=mask, **CRANIOTOMY)
    # The gravity fit's settings are checked before the model is built.
    assert bmr.default_registration_settings()["gravity_fit_candidates"] == 0
    with pytest.raises(bmr.Error, match="3 or more sizes"):
        bmr.register(image, brain_mask=mask, sparse_points=points, sparse_displacements=displacements,
                     gravity=(0, 0, -9810), gravity_fit_candidates=2, **CRANIOTOMY)
    with pytest.raises(bmr.Error, match="give the intraoperative image"):
        bmr.register(image, brain_mask=mask, sparse_points=points, sparse_displacements=displacements,
                     gravity=(0, 0, -9810), gravity_fit_candidates=5, **CRANIOTOMY)


def test_install_command_installs_an_importable_package(tmp_path):
    build = os.environ.get("BMR_BUILD_DIR")
    if not build:
        pytest.skip("BMR_BUILD_DIR is not set")
    run = subprocess.run(["cmake", "--install", build, "--component", "python", "--prefix", str(tmp_path)],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    version = "python%d.%d" % sys.version_info[:2]
    site = tmp_path / "lib" / version / "dist-packages"
    assert (site / "biomechanical_registration" / "__init__.py").exists()
    probe = subprocess.run([sys.executable, "-c", "import biomechanical_registration as b; print(b.__file__); "
                            "print(b.make_block_mesh((1, 1, 1), (1, 1, 1)))"],
                           env={**os.environ, "PYTHONPATH": str(site)}, capture_output=True, text=True, cwd=tmp_path)
    assert probe.returncode == 0, probe.stderr
    assert probe.stdout.startswith(str(site)) and "8 nodes" in probe.stdout


def test_prepare_then_update_gives_the_one_call_registration(tmp_path, colin27):
    """bmr.prepare (written as a bundle) and bmr.update (from the folder, or the object): the same transform and
    warped image as bmr.register, bit for bit; the update runs only the intraoperative stages; the CSF class is named."""
    image, mask = colin27
    points, displacements = bmr.read_sparse_displacements(sparse_csv())
    bundle = bmr.prepare(image, brain_mask=mask, output=tmp_path / "plan", **CRANIOTOMY)
    assert (tmp_path / "plan" / "manifest.json").exists()
    assert bundle.brain_model.csf_class["contrast"] == "t1" and bundle.brain_model.csf_class["class"] == 1
    assert bundle.manifest["version"] == 4  # 2: with the solver's precomputation; 3: the materials' laws; 4: the tissue mixture
    assert "precomputation.bin" in [entry["name"] for entry in bundle.manifest["files"]]
    assert "precompute" in bundle.manifest["prepare"]["seconds"]
    from_folder = bmr.update(tmp_path / "plan", sparse_points=points, sparse_displacements=displacements)
    from_object = bmr.update(bundle, sparse_points=points, sparse_displacements=displacements)
    one_call = bmr.register(image, brain_mask=mask, sparse_points=points, sparse_displacements=displacements,
                            **CRANIOTOMY)
    assert [stage for stage, _ in from_folder.stage_seconds.items() if stage != "total"] == ["loads", "solve", "fit",
                                                                                              "warp"]
    samples = grid_points(-60, 60, 9)
    for result in (from_folder, from_object):
        assert result.report["solve"]["steps"] == one_call.report["solve"]["steps"]
        np.testing.assert_array_equal(result.transform.transform_points(samples),
                                      one_call.transform.transform_points(samples))
        np.testing.assert_array_equal(result.warped_image.array, one_call.warped_image.array)
    # A later update of the surgery from this one (its result in memory): a warm start, fewer steps.
    second = bmr.update(bundle, sparse_points=points, sparse_displacements=1.5 * displacements, previous=from_object)
    assert second.solve.warm_started and not from_object.solve.warm_started
    assert second.report["solve"]["warm_started"]
    assert second.solve.converged and second.solve.steps < from_object.solve.steps
    with pytest.raises(bmr.Error, match="no such file"):
        bmr.update(bundle, sparse_points=points, sparse_displacements=displacements, previous=tmp_path / "none")
    with pytest.raises(TypeError, match="give it to update"):
        bmr.prepare(image, brain_mask=mask, gravity=(0, 0, -9810), **CRANIOTOMY)
    with pytest.raises(bmr.Error, match="no manifest.json|no such folder"):
        bmr.update(tmp_path / "nothing-here", sparse_points=points, sparse_displacements=displacements)
    # The uncertainty map: an ensemble of 3 with the defaults' draws, as `biomech update --uncertainty 3`.
    ensemble = bmr.update(bundle, sparse_points=points, sparse_displacements=displacements, uncertainty=3,
                          uncertainty_seed=5)
    assert ensemble.report["uncertainty"]["used_members"] == 3 and ensemble.report["uncertainty"]["seed"] == 5
    spread = ensemble.uncertainty_map.array
    assert spread.shape == from_object.warped_image.array.shape
    assert spread.min() >= 0.0 and spread.max() > 0.0
    assert len(ensemble.nodal_uncertainty) == len(ensemble.brain_model.model.nodes)
    np.testing.assert_allclose(ensemble.mean_transform.transform_points(samples),
                               from_object.transform.transform_points(samples), atol=2.0)
    # register() runs the same ensemble on the model it prepares: the same draws give the same map, bit for bit.
    registered = bmr.register(image, brain_mask=mask, sparse_points=points, sparse_displacements=displacements,
                              uncertainty=3, uncertainty_seed=5, **CRANIOTOMY)
    np.testing.assert_array_equal(registered.uncertainty_map.array, spread)
    assert registered.report["uncertainty"]["member_results"] == ensemble.report["uncertainty"]["member_results"]
    with pytest.raises(TypeError, match="without uncertainty=N"):
        bmr.register(image, brain_mask=mask, sparse_points=points, sparse_displacements=displacements,
                     uncertainty_poisson=(0.45, 0.49), **CRANIOTOMY)
    with pytest.raises(TypeError, match="without uncertainty=N"):
        bmr.update(bundle, sparse_points=points, sparse_displacements=displacements, uncertainty_seed=3)
    with pytest.raises(bmr.Error, match="at least 2"):
        bmr.update(bundle, sparse_points=points, sparse_displacements=displacements, uncertainty=1)
