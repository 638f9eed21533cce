"""The mechanics core from Python: models, the solver, loads, files, errors, progress."""

import json
import threading
import time

import numpy as np
import pytest

import biomechanical_registration as bmr
from conftest import SOURCE_DIR, ball_mask

E, NU = 3000.0, 0.45
SHEAR, BULK = E / (2 * (1 + NU)), E / (3 * (1 - 2 * NU))


def uniaxial_block(stretch, divisions=(2, 2, 2), cells="hexahedra", material=None):
    """A 10 mm cube on rollers (xmin, ymin, zmin) pulled along x to `stretch`."""
    material = material or bmr.Material("brain", E, NU, 1000)
    model = bmr.make_block_mesh((10, 10, 10), divisions, cells=cells, material=material)
    model.fix("xmin", (True, False, False))
    model.fix("ymin", (False, True, False))
    model.fix("zmin", (False, False, True))
    pulled = model.node_sets["xmax"]
    displacement = np.tile([10 * (stretch - 1), 0, 0], (len(pulled), 1))
    model.add_prescribed_displacement(bmr.PrescribedDisplacement(pulled, displacement, components=(True, False, False)))
    return model


def uniaxial_neo_hookean(stretch, share=0.0):
    """Lateral stretch and axial Cauchy stress (Pa) in uniaxial stress of
    W = C10 (I1bar - 3) + C01 (I2bar - 3) + kappa/2 (J - 1)^2, C01 = share * mu/2
    (share 0: the neo-Hookean law): sigma = 2/J dev[(C10 + C01 I1bar) bbar - C01 bbar^2] + kappa (J - 1)."""
    c10, c01 = (1.0 - share) * SHEAR / 2.0, share * SHEAR / 2.0

    def cauchy(lateral):
        j = stretch * lateral**2
        bbar = j ** (-2.0 / 3.0) * np.array([stretch**2, lateral**2, lateral**2])
        a = (c10 + c01 * bbar.sum()) * bbar - c01 * bbar**2
        return 2.0 / j * (a - a.sum() / 3.0) + BULK * (j - 1.0)

    low, high = 0.5, 1.5
    for _ in range(200):  # bisection on sigma_yy(lateral) = 0, increasing in lateral
        middle = 0.5 * (low + high)
        low, high = (middle, high) if cauchy(middle)[1] < 0 else (low, middle)
    lateral = 0.5 * (low + high)
    return lateral, cauchy(lateral)[0]


def test_a_mooney_rivlin_material_solves_its_own_law_and_bad_laws_are_named():
    assert bmr.material_laws() == ["neo-hookean", "mooney-rivlin"]
    material = bmr.Material("brain", E, NU, 1000, law="mooney-rivlin", second_invariant_share=0.5)
    assert material.law == "mooney-rivlin" and "second_invariant_share=0.5" in repr(material)
    stretch = 1.2
    result = bmr.solve(uniaxial_block(stretch, material=material), tolerance=1e-6, max_steps=200000)
    assert result.converged, result.message
    lateral, sigma_xx = uniaxial_neo_hookean(stretch, share=0.5)
    force = result.reaction_forces[uniaxial_block(stretch).node_sets["xmax"], 0].sum()
    np.testing.assert_allclose(force, sigma_xx * (10 * lateral) ** 2 * 1e-6, rtol=2e-3)
    _, neo_hookean_sigma = uniaxial_neo_hookean(stretch)
    assert abs(neo_hookean_sigma - sigma_xx) > 0.02 * abs(sigma_xx)  # the law shows in the answer
    with pytest.raises(Exception, match="the laws are neo-hookean, mooney-rivlin"):
        bmr.Material("brain", E, NU, 1000, law="ogden")
    with pytest.raises(Exception, match="must lie in"):
        bmr.Material("brain", E, NU, 1000, law="mooney-rivlin", second_invariant_share=2.0)
    # The laws' parameters are keywords and attributes, named by one list.
    assert bmr.material_parameters() == ["second_invariant_share"]
    material.second_invariant_share = 0.25
    assert material.second_invariant_share == 0.25
    with pytest.raises(TypeError, match="unexpected keyword 'share'; the laws' parameters are: second_invariant_share"):
        bmr.Material("brain", E, NU, 1000, law="mooney-rivlin", share=0.5)


@pytest.mark.parametrize("cells", ["hexahedra", "tetrahedra"])
def test_uniaxial_stretch_matches_the_analytic_neo_hookean_solution(cells):
    stretch = 1.2
    model = uniaxial_block(stretch, cells=cells)
    result = bmr.solve(model, tolerance=1e-6, max_steps=200000)
    assert result.converged, result.message
    lateral, sigma_xx = uniaxial_neo_hookean(stretch)
    nodes, u = model.nodes, result.displacements
    ymax = model.node_sets["ymax"]
    np.testing.assert_allclose(u[ymax, 1], 10 * (lateral - 1), rtol=1e-3)
    # Reaction on the pulled face = sigma_xx times the deformed area (Pa * mm^2 * 1e-6 = N).
    force = result.reaction_forces[model.node_sets["xmax"], 0].sum()
    np.testing.assert_allclose(force, sigma_xx * (10 * lateral) ** 2 * 1e-6, rtol=2e-3)
    assert result.displacements.shape == nodes.shape


def test_model_from_arrays_round_trips_and_validates():
    block = bmr.make_block_mesh((2, 1, 1), (2, 1, 1))
    model = bmr.Model(block.nodes, block.cells, materials=[bmr.Material("a", 1000), bmr.Material("b", 2000)],
                      cell_materials=[0, 1], node_sets={"left": [0, 3]})
    np.testing.assert_array_equal(model.nodes, block.nodes)
    np.testing.assert_array_equal(model.cells, block.cells)
    np.testing.assert_array_equal(model.cell_types, [12, 12])
    np.testing.assert_array_equal(model.cell_materials, [0, 1])
    assert model.materials[1].youngs_modulus == 2000
    np.testing.assert_array_equal(model.node_sets["left"], [0, 3])
    tetrahedra = bmr.make_block_mesh((1, 1, 1), (1, 1, 1), cells="tetrahedra")
    assert tetrahedra.cells.shape == (6, 4) and set(tetrahedra.cell_types) == {10}
    mixed = bmr.make_block_mesh((2, 1, 1), (2, 1, 1), cells="mixed")
    assert mixed.cells.shape[1] == 8 and np.all(mixed.cells[mixed.cell_types == 10, 4:] == -1)
    again = bmr.Model(mixed.nodes, mixed.cells)
    np.testing.assert_array_equal(again.cells, mixed.cells)


def test_bad_models_are_named():
    block = bmr.make_block_mesh((1, 1, 1), (1, 1, 1))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        bmr.Model(block.nodes[:, :2], block.cells)
    with pytest.raises(ValueError, match="cells must be"):
        bmr.Model(block.nodes, block.cells[:, :5])
    with pytest.raises(bmr.Error, match="node"):
        bmr.Model(block.nodes, block.cells + 100)
    with pytest.raises(ValueError, match="cell_materials"):
        bmr.Model(block.nodes, block.cells, cell_materials=[0, 0])
    with pytest.raises(bmr.Error, match="nope"):
        block.fix("nope")
    with pytest.raises(ValueError, match="differ in length"):
        bmr.PrescribedDisplacement([0, 1], [[0, 0, 1]])
    with pytest.raises(ValueError, match="curve"):
        bmr.PrescribedDisplacement([0], [[0, 0, 1]], curve="cubic")
    with pytest.raises(TypeError, match="no setting 'tolerence'"):
        bmr.SolverSettings(tolerence=1)
    with pytest.raises(ValueError, match="integrator"):
        bmr.SolverSettings(integrator="implicit")
    with pytest.raises(TypeError, match="scene must be"):
        bmr.solve(42)


def test_failed_solve_raises_solve_error_with_step_and_element():
    model = bmr.make_block_mesh((10, 10, 10), (1, 1, 1))
    model.fix("zmin")
    corner = [int(i) for i in model.node_sets["zmax"][:1]]
    model.add_prescribed_displacement(bmr.PrescribedDisplacement(corner, [[0, 0, -25.0]]))
    with pytest.raises(bmr.SolveError) as raised:
        bmr.solve(model, load_steps=10)
    assert raised.value.element == 0 and raised.value.step > 0
    message = str(raised.value)
    assert "cell 0 is folded" in message and "step %d" % raised.value.step in message
    assert isinstance(raised.value, bmr.Error)


def test_step_limit_is_reported_not_raised():
    result = bmr.solve(uniaxial_block(1.1), max_steps=5, load_steps=2)
    assert not result.converged
    assert result.steps == 5 and result.message


def test_progress_reaches_python_and_an_exception_stops_the_solve():
    reports = []
    result = bmr.solve(uniaxial_block(1.1), tolerance=1e-5, progress=lambda *report: reports.append(report))
    assert reports and reports[0][0] == "solve" and "estimated_error" in reports[0][2]
    assert reports[-1][2]["step"] <= result.steps

    class Stop(Exception):
        pass

    def stop(stage, fraction, info):
        if info["step"] > 40:
            raise Stop("enough")

    with pytest.raises(Stop, match="enough"):
        bmr.solve(uniaxial_block(1.1), tolerance=1e-9, max_steps=10**6, progress=stop)


def test_long_solves_release_the_gil():
    model = bmr.make_block_mesh((40, 40, 40), (16, 16, 16), material=bmr.Material("brain", E, NU, 1000))
    model.fix("zmin")
    top = model.node_sets["zmax"]
    model.add_prescribed_displacement(bmr.PrescribedDisplacement(top, np.tile([0, 0, -4.0], (len(top), 1))))
    done, ticks = threading.Event(), [0]
    worker = threading.Thread(target=lambda: (bmr.solve(model, tolerance=1e-6, threads=1), done.set()))
    start = time.perf_counter()
    worker.start()
    while not done.is_set():
        ticks[0] += 1
        time.sleep(0.001)
    worker.join()
    seconds = time.perf_counter() - start
    # With the GIL held for the whole solve this thread could not run at all.
    assert ticks[0] >= 20 and ticks[0] > 0.2 * seconds / 0.0011


def scene_path():
    return SOURCE_DIR / "examples" / "scenes" / "block-indentation.json"


def test_solve_gives_what_the_command_line_tool_writes(tmp_path, biomech):
    run = biomech("solve", scene_path(), "-d", tmp_path)
    assert run.returncode == 0, run.stderr
    written = bmr.read_mesh(tmp_path / "block-indentation-result.vtu")
    result = bmr.solve(scene_path())
    np.testing.assert_array_equal(result.displacements, written["point_data"]["displacement"])
    np.testing.assert_array_equal(result.reaction_forces, written["point_data"]["reaction_force"])
    report = json.loads((tmp_path / "block-indentation-report.json").read_text())
    scene = bmr.read_scene(scene_path())
    ours = bmr.report_json(scene, result)
    for key in ("converged", "steps", "max_displacement_mm", "estimated_error_mm", "strain_energy_J", "nodes"):
        assert ours[key] == report[key], key
    # The summary table is the one biomech prints, but for the wall time (and the output files it names).
    printed = run.stdout.splitlines()
    table = [line for line in bmr.format_report(scene, result).splitlines() if "wall time" not in line]
    assert len(table) > 5 and all(line in printed for line in table)
    # The same scene as a dict, with the mesh generated from its description.
    as_dict = json.loads(scene_path().read_text())
    np.testing.assert_array_equal(bmr.solve(as_dict).displacements, result.displacements)


def test_solver_settings_are_the_one_table(tmp_path, biomech):
    """SolverSettings' attributes, solve() keywords, biomech solve --set and the scene keys are one vocabulary."""
    listed = [line.split(" = ")[0] for line in biomech("settings").stdout.splitlines() if not line.startswith(" ")]
    assert "safety_factor" in listed and "damping" in listed and len(listed) >= 15
    settings = bmr.SolverSettings()
    for name in listed:
        assert hasattr(settings, name), name
    with pytest.raises(TypeError, match="damping_coefficient"):
        bmr.SolverSettings(damping_coefficient=1.0)
    settings.safety_factor = 0.5
    with pytest.raises(ValueError, match=r"safety_factor.*\(0, 1\]"):
        settings.safety_factor = 1.5
    with pytest.raises(TypeError, match="max_steps"):
        settings.max_steps = 2.5
    with pytest.raises(ValueError, match="tetrahedron"):
        settings.tetrahedron = "quadratic"
    # The same override from Python and from the command line gives the same solve.
    run = biomech("solve", scene_path(), "-d", tmp_path, "--set", "tolerance=0.05", "--set", "load_steps=50")
    assert run.returncode == 0, run.stderr
    written = bmr.read_mesh(tmp_path / "block-indentation-result.vtu")
    result = bmr.solve(scene_path(), tolerance=0.05, load_steps=50)
    np.testing.assert_array_equal(result.displacements, written["point_data"]["displacement"])
    assert result.steps != bmr.solve(scene_path()).steps
    bad = biomech("solve", scene_path(), "-d", tmp_path / "bad", "--set", "tolerance=-1")
    assert bad.returncode == 1 and "tolerance" in bad.stderr and "> 0" in bad.stderr


def test_errors_carry_the_command_line_tool_messages(tmp_path, biomech):
    scene = json.loads(scene_path().read_text())
    scene["fixed"][0]["node_set"] = "floor"
    (tmp_path / "bad.json").write_text(json.dumps(scene))
    run = biomech("solve", tmp_path / "bad.json", "-d", tmp_path)
    assert run.returncode == 1
    with pytest.raises(bmr.Error) as raised:
        bmr.read_scene(tmp_path / "bad.json")
    assert str(raised.value) in run.stderr
    assert "floor" in str(raised.value)


def test_mesh_surface_and_result_files_round_trip(tmp_path):
    model = uniaxial_block(1.1, cells="mixed")
    bmr.write_mesh(tmp_path / "model.vtu", model)
    read = bmr.read_mesh(tmp_path / "model.vtu")
    np.testing.assert_array_equal(read["model"].nodes, model.nodes)
    np.testing.assert_array_equal(read["model"].cells, model.cells)
    np.testing.assert_array_equal(read["point_data"]["xmax"], np.isin(np.arange(len(model.nodes)), model.node_sets["xmax"]))
    assert read["cell_data"]["youngs_modulus"][0] == E
    result = bmr.solve(model, tolerance=1e-3)
    bmr.write_result(tmp_path / "result.vtu", model, result)
    np.testing.assert_array_equal(bmr.read_mesh(tmp_path / "result.vtu")["point_data"]["displacement"], result.displacements)
    with pytest.raises(ValueError, match="displacements"):
        bmr.write_result(tmp_path / "other.vtu", bmr.make_block_mesh((1, 1, 1), (1, 1, 1)), result)
    assert not (tmp_path / "other.vtu").exists()

    skull = bmr.make_ellipsoid_surface((70, 85, 60), 2)
    bmr.write_surface(tmp_path / "skull.vtp", skull)
    back = bmr.read_surface(tmp_path / "skull.vtp")
    # The reader merges coincident points, which may renumber them: compare the geometry.
    assert back.triangles.shape == skull.triangles.shape
    np.testing.assert_allclose(np.sort(back.vertices, axis=0), np.sort(skull.vertices, axis=0), rtol=1e-6)
    np.testing.assert_allclose(back.enclosed_volume(), skull.enclosed_volume(), rtol=1e-6)
    assert back.is_closed()
    with pytest.raises(bmr.Error, match="missing.stl"):
        bmr.read_surface(tmp_path / "missing.stl")
    with pytest.raises(ValueError, match="vertex"):
        bmr.Surface([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3]])


def test_sparse_points_reproduce_an_affine_displacement():
    """The thin-plate spline with its affine part interpolates a linear field exactly."""
    model = bmr.make_block_mesh((20, 20, 10), (4, 4, 2))
    exposed = model.node_sets["zmax"]
    points = model.nodes[exposed][::3]
    field = lambda x: np.column_stack([0.01 * x[:, 0], -0.02 * x[:, 1], -1.0 + 0.03 * x[:, 0]])
    load, report = bmr.displacements_from_points(model, exposed, points, field(points))
    np.testing.assert_array_equal(load.nodes, exposed)
    np.testing.assert_allclose(load.displacements, field(model.nodes[exposed]), atol=1e-9)
    assert report["used"] == len(points) and report["rejected"] == 0
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        bmr.displacements_from_points(model, exposed, points[:, :2], field(points))
    with pytest.raises(bmr.Error):
        bmr.displacements_from_points(model, exposed, points, field(points)[:-1])


def test_surface_load_and_regions():
    model = bmr.make_block_mesh((20, 20, 10), (4, 4, 2))
    exposed = bmr.surface_nodes_in_sphere(model, (10, 10, 10), 6.0)
    assert len(exposed) > 0 and np.all(np.linalg.norm(model.nodes[exposed] - [10, 10, 10], axis=1) <= 6.0)
    plane = bmr.Surface([[-50, -50, 9], [50, -50, 9], [50, 50, 9], [-50, 50, 9]], [[0, 1, 2], [0, 2, 3]])
    load, report = bmr.displacements_from_surface(model, exposed, plane)
    np.testing.assert_allclose(load.displacements, np.tile([0, 0, -1.0], (len(exposed), 1)), atol=1e-12)
    base = bmr.skull_base_nodes(model, height=1.0)
    np.testing.assert_array_equal(np.sort(base), np.sort(model.node_sets["zmin"]))
    with pytest.raises(bmr.Error):
        bmr.displacements_from_surface(model, [], plane)


def test_tissue_classification_finds_three_intensity_classes():
    rng = np.random.default_rng(3)
    levels = np.array([20.0, 60.0, 110.0])
    labels = rng.integers(0, 3, size=(16, 16, 16))
    image = bmr.image_from_array((levels[labels] + rng.normal(0, 2, labels.shape)).astype(np.float32))
    mask = ball_mask(16, 7)
    stages = []
    classes = bmr.classify_tissue(image, mask, classes=3, progress=lambda *report: stages.append(report[1]))
    assert classes.converged and stages[-1] == 1.0
    np.testing.assert_allclose(classes.centroids, levels, atol=1.0)
    memberships = classes.memberships.array
    assert memberships.shape == (16, 16, 16, 3)
    inside = mask.array > 0
    np.testing.assert_allclose(memberships[inside].sum(axis=1), 1.0, atol=1e-5)
    assert np.all(memberships[~inside] == 0)
    np.testing.assert_array_equal(classes.labels.array[inside], labels[inside] + 1)
    with pytest.raises(bmr.Error, match="classes"):
        bmr.classify_tissue(image, mask, classes=1)
    with pytest.raises(bmr.Error, match="grid"):
        bmr.classify_tissue(image, ball_mask(12, 4))


def test_grid_kinds_and_bad_settings():
    mask = ball_mask(32, 12)
    hexahedra = bmr.make_grid(mask, element_size=2.0)
    volume = np.count_nonzero(mask.array)
    assert hexahedra.quality["mask_volume_mm3"] == volume
    # Cubes at least half inside are kept, then non-manifold contacts filled: a 2 mm grid on a 12 mm ball measured 7.4 % more.
    assert 0 <= hexahedra.quality["mesh_volume_mm3"] - volume < 0.1 * volume
    assert hexahedra.quality["hexahedra"] == len(hexahedra.model.cells)
    tetrahedra = bmr.make_grid(mask, kind="tetrahedra", element_size=4.0)
    assert tetrahedra.quality["min_scaled_jacobian"] > 0 and set(tetrahedra.model.cell_types) == {10}
    assert len(tetrahedra.cell_labels) == len(tetrahedra.model.cells)
    with pytest.raises(bmr.Error, match="hexahedra"):
        bmr.make_grid(mask, kind="bricks")
    with pytest.raises(bmr.Error, match="spacing"):
        bmr.make_grid(mask, element_size=0.1)
    with pytest.raises(bmr.Error):
        bmr.make_grid(bmr.image_from_array(np.zeros((8, 8, 8), np.uint8)))


def probe_scene():
    return SOURCE_DIR / "examples" / "scenes" / "probe-indentation.json"


def test_simulate_gives_what_biomech_simulate_writes(tmp_path, biomech):
    run = biomech("simulate", probe_scene(), "-d", tmp_path)
    assert run.returncode == 0, run.stderr
    result, frames = bmr.simulate(probe_scene())
    assert [round(frame["time"], 9) for frame in frames][:3] == pytest.approx([0.0, 0.05, 0.1], abs=result.time_step)
    collection = (tmp_path / "probe-indentation.pvd").read_text()
    files = [line.split('file="')[1].split('"')[0] for line in collection.splitlines() if "file=" in line]
    assert len(files) == len(frames)
    for frame, name in zip(frames, files):
        written = bmr.read_mesh(tmp_path / name)["point_data"]["displacement"]
        np.testing.assert_array_equal(frame["displacements"], written)
    probe = result.tools[0]
    rows = np.genfromtxt(tmp_path / "probe-indentation-tool-forces.csv", delimiter=",", names=True, dtype=None,
                         encoding="utf-8")
    assert len(rows) == len(probe.time) == result.steps
    np.testing.assert_allclose(rows["fz_N"], probe.force[:, 2], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(rows["z_mm"], probe.position[:, 2], rtol=1e-9)
    # The tissue pushes the probe back while it is in, and lets go once it is out.
    assert probe.force[:, 2].max() > 0 and probe.contact_nodes[-1] == 0
    assert len(probe.corrected_force) == result.steps and len(probe.stress_cells) > 0
    report = json.loads((tmp_path / "probe-indentation-report.json").read_text())
    assert report["tools"][0]["max_force_N"] == pytest.approx(np.linalg.norm(probe.force, axis=1).max(), rel=1e-12)
    assert "ogden-stress-region" in report["active_components"]


def test_tools_from_python():
    model = bmr.make_block_mesh((10, 10, 10), (5, 5, 5), material=bmr.Material("brain", E, NU, 1000))
    model.fix("zmin")
    probe = bmr.Tool("probe", "probe", radius=2.0, times=[0.0, 1.0], positions=[[5, 5, 12], [5, 5, 11]],
                     slave_node_set="zmax")
    model.add_tool(probe)
    assert model.tools[0].shape == "probe"
    np.testing.assert_allclose(probe.pose(0.5)[0], [5, 5, 11.5])
    steady = bmr.solve(model, tolerance=1e-5)
    assert steady.converged and steady.tools[0].force[-1, 2] > 0
    frames = []
    result, collected = bmr.simulate(model, integrator="explicit_dynamics", end_time=0.02, output_interval=0.01,
                                     frames=lambda *frame: frames.append(frame[0]))
    assert collected == [] and len(frames) == 3 and len(result.tools[0].time) == result.steps
    with pytest.raises(ValueError, match="explicit dynamics"):
        bmr.simulate(model)
    with pytest.raises(ValueError, match="shape"):
        bmr.Tool("knife", "scalpel", times=[0], positions=[[0, 0, 0]])
    with pytest.raises(ValueError, match="one entry per pose"):
        bmr.Tool("probe", times=[0, 1], positions=[[0, 0, 0]])

    class Stop(Exception):
        pass

    def stop(*frame):
        raise Stop("frame")

    with pytest.raises(Stop):
        bmr.simulate(model, integrator="explicit_dynamics", end_time=0.02, output_interval=0.01, frames=stop)
    inside = bmr.Tool("inside", times=[0.0], positions=[[5, 5, 9]], slave_node_set="zmax")
    model.add_tool(inside)
    with pytest.raises(bmr.Error, match="starts"):
        bmr.solve(model)


def test_simulate_command_refuses_a_steady_state_scene_and_writes_nothing(tmp_path, biomech):
    run = biomech("simulate", scene_path(), "-d", tmp_path)
    assert run.returncode == 1
    assert "explicit_dynamics" in run.stderr and "biomech solve" in run.stderr
    assert list(tmp_path.iterdir()) == []
    scene = json.loads(probe_scene().read_text())
    scene["tools"][0]["trajectory"][0]["position"] = [15, 15, 14]  # starts inside the block
    (tmp_path / "inside.json").write_text(json.dumps(scene))
    run = biomech("simulate", tmp_path / "inside.json", "-d", tmp_path / "out")
    assert run.returncode == 1 and "starts" in run.stderr and "'probe'" in run.stderr
    assert not (tmp_path / "out" / "inside.pvd").exists() and not (tmp_path / "out" / "inside-frames").exists()
