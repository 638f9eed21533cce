"""Brain-shift registration with a nonlinear biomechanical model, from Python.

The binding of the BiomechanicalRegistration ITK module (docs/python.md):
images are :class:`Image` objects (NumPy arrays indexed [z, y, x] with ITK's
spacing, origin and direction), meshes and results are NumPy arrays (mm, N,
Pa), every filter takes its parameters as keyword arguments, long calls
release the GIL and report progress to an optional callable
``progress(stage, fraction, info)``, and errors from C++ arrive as
:class:`Error` (a RuntimeError) with the command-line tool's messages.

Quick start::

    import biomechanical_registration as bmr
    image = bmr.imread("/usr/share/mricron/templates/ch2.nii.gz")
    mask = bmr.imread("/usr/share/mricron/templates/ch2bet.nii.gz")
    mask = bmr.image_from_array(bmr.array_from_image(mask) > 0, mask.spacing, mask.origin, mask.direction)
    result = bmr.register(image, brain_mask=mask, intraoperative_surface=surface,
                          craniotomy_centre=(-11, 43, 84), craniotomy_radius=30)
"""

import json as _json
import os as _os
import sys as _sys

# The extension is loaded with RTLD_LOCAL whatever the caller set (sys.setdlopenflags):
# under RTLD_GLOBAL the binding's Debian ITK 5.2 libraries, and the ITK template
# instantiations the extension exports, would enter the process's global scope, where
# ITK's own 5.4 wheels (`import itk`) bind their symbols to them: wrong filter results,
# then heap corruption (wrapping/tests/test_itk_interop.py).
_dlopen_flags = _sys.getdlopenflags()
_sys.setdlopenflags(_dlopen_flags & ~_os.RTLD_GLOBAL)
try:
    from . import _bmr
finally:
    _sys.setdlopenflags(_dlopen_flags)

from ._bmr import (
    BrainModel,
    BSplineRegistration,
    EdgeEvaluation,
    Error,
    ImageGrid,
    Material,
    Model,
    ModelBundle,
    OgdenMaterial,
    PrescribedDisplacement,
    RegistrationResult,
    Scene,
    SolveError,
    SolveResult,
    SolverSettings,
    Surface,
    SyntheticBrainShift,
    TissueClassification,
    Tool,
    ToolHistory,
    Transform,
    atlas_brain_mask,
    brain_surfaces,
    bspline_registration,
    classify_tissue,
    displacements_between_surfaces,
    displacements_from_points,
    displacements_from_surface,
    evaluate_edges,
    fit_transform,
    format_report,
    identity_transform,
    imread,
    imwrite,
    make_block_mesh,
    make_ellipsoid_surface,
    make_grid,
    make_synthetic_brain_shift,
    make_synthetic_electrode_ct,
    material_laws,
    material_parameters,
    map_materials,
    locate_electrodes,
    measure_displacement_error,
    model_regions,
    parse_scene,
    read_mesh,
    read_model_bundle,
    read_scene,
    read_sparse_displacements,
    read_surface,
    read_transform,
    report_json,
    skull_base_nodes,
    surface_nodes_in_mask,
    surface_distance_p95,
    surface_nodes_in_sphere,
    ventricle_mask,
    warp_image,
    write_mesh,
    write_result,
    write_surface,
)
from .image import Image, array_from_image, array_view_from_image, image_from_array, image_view_from_array

__version__ = "0.1.0"


def write_transform(transform, path):
    """Writes a transform (.h5, .tfm, .txt), as `biomech register` writes transform.h5."""
    transform.write(_os.fspath(path))


def solve(scene, settings=None, progress=None, **overrides):
    """Solves a model to steady state (dynamic relaxation) or over time (explicit dynamics).

    ``scene`` is a scene file path (as ``biomech solve`` takes), a dict with
    the scene file's content (docs/scene-format.md; relative paths are
    relative to the current folder), a :class:`Scene`, or a :class:`Model`
    (then ``settings`` is a :class:`SolverSettings`, default the solver's
    defaults). Keyword arguments override single solver settings, e.g.
    ``tolerance=0.01``, ``max_steps=20000``, ``threads=1``.

    A solve that stops without converging is not an exception: the result
    says so (``converged``, ``message``). A failed solve (an inverted element)
    raises :class:`SolveError` with ``step`` and ``element``.
    """
    model, chosen = _model_and_settings("solve", scene, settings, overrides)
    return _bmr._solve(model, chosen, progress)


def simulate(scene, settings=None, progress=None, frames=None, **overrides):
    """Time-accurate explicit dynamics with moving tools, as ``biomech simulate``.

    ``scene`` and the settings as for :func:`solve`; the integrator must be
    ``explicit_dynamics``. ``frames``: a callable ``frames(time, step,
    displacements, strain_energy, kinetic_energy)`` called at t = 0, at every
    ``output_interval`` and at the end; None collects the frames. Returns
    ``(result, frames)``: ``result.tools`` holds each tool's force, moment,
    position (and, with a stress region, corrected force and Ogden stresses)
    at every step; ``frames`` is the list of collected frames (dicts with
    ``time``, ``step``, ``displacements``, ``strain_energy``,
    ``kinetic_energy``), empty when a callable was given.
    """
    model, chosen = _model_and_settings("simulate", scene, settings, overrides)
    if chosen.integrator != "explicit_dynamics":
        raise ValueError("simulate runs time-accurate explicit dynamics; set integrator='explicit_dynamics' "
                         "(and end_time, output_interval), or use solve() for a steady state")
    collected = []
    if frames is None:
        if chosen.output_interval <= 0:
            raise ValueError("give output_interval (s), the time between the frames collected")

        def frames(time, step, displacements, strain_energy, kinetic_energy):
            collected.append(dict(time=time, step=step, displacements=displacements, strain_energy=strain_energy,
                                  kinetic_energy=kinetic_energy))

    return _bmr._solve(model, chosen, progress, frames), collected


def _model_and_settings(function, scene, settings, overrides):
    if isinstance(scene, Model):
        model = scene
        base = SolverSettings() if settings is None else settings
    else:
        if settings is not None:
            raise TypeError("settings is for a Model; a scene carries its own (override single ones with keywords)")
        scene = _as_scene(scene)
        model, base = scene.model, scene.settings
    if not isinstance(base, SolverSettings):
        raise TypeError("settings must be a SolverSettings, got %s" % type(base).__name__)
    chosen = base.copy()
    for name, value in overrides.items():
        if name.startswith("_") or not hasattr(chosen, name) or callable(getattr(chosen, name)):
            raise TypeError("%s() got an unknown solver setting '%s'" % (function, name))
        setattr(chosen, name, value)
    return model, chosen


def _as_scene(scene):
    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, dict):
        return parse_scene(_json.dumps(scene), _os.path.join(_os.getcwd(), "scene.json"))
    if isinstance(scene, (str, _os.PathLike)):
        return read_scene(_os.fspath(scene))
    raise TypeError("scene must be a path, a dict, a Scene or a Model; got %s" % type(scene).__name__)


def default_registration_settings():
    """The keyword settings of :func:`register` and :func:`build_brain_model` with their defaults.

    They are the rows of the registration's settings table (the options of
    ``biomech register`` with underscores for dashes; ``--no-contact`` is
    ``contact=False``; docs/registration.md lists them), and the craniotomy,
    gravity, CSF drainage and ``max_distance``.
    """
    return _bmr._default_registration_settings()


def _checked_settings(function, settings):
    known = _bmr._default_registration_settings()
    unknown = sorted(set(settings) - set(known))
    if unknown:
        raise TypeError(
            "%s() got unknown setting%s %s; the settings are: %s"
            % (function, "s" if len(unknown) > 1 else "", ", ".join(unknown), ", ".join(sorted(known)))
        )
    return dict(settings)


def build_brain_model(
    image,
    brain_mask=None,
    *,
    tumour_mask=None,
    skull_surface=None,
    intraoperative_surface=None,
    sparse_points=None,
    sparse_displacements=None,
    progress=None,
    **settings
):
    """The patient-specific model of ``biomech model``: classification, grid, materials,
    surfaces, fixed skull base, exposed surface loaded from the measurements, skull contact.

    ``brain_mask`` None: atlas skull stripping (Colin27 from mricron-data).
    Settings: see :func:`default_registration_settings`. Returns a :class:`BrainModel`;
    ``solve(brain_model.model)`` solves it.
    """
    values = _checked_settings("build_brain_model", settings)
    return _bmr._build_brain_model(
        image, brain_mask, tumour_mask, skull_surface, intraoperative_surface, sparse_points, sparse_displacements,
        values, progress,
    )


_UNCERTAINTY_KEYWORDS = {  # keyword: (UncertaintySettings field(s), conversion)
    "uncertainty_noise": (("noise_sigma",), float),
    "uncertainty_gravity": (("gravity_low", "gravity_high"), float),
    "uncertainty_modulus_spread": (("youngs_modulus_spread",), float),
    "uncertainty_tissue_modulus_spread": (("tissue_modulus_spread",), float),
    "uncertainty_poisson": (("poisson_low", "poisson_high"), float),
    "uncertainty_skull_gap": (("skull_gap_spread",), float),
    "uncertainty_exposed_radius": (("exposed_radius_spread",), float),
    "uncertainty_tolerance": (("member_tolerance",), float),
    "uncertainty_seed": (("seed",), int),
}


def _uncertainty_settings(function, uncertainty, settings):
    """The ensemble's settings of register() and update() (None without `uncertainty`), taking its keywords out of
    `settings`."""
    given = {name: settings.pop(name) for name in list(settings) if name in _UNCERTAINTY_KEYWORDS}
    given = {name: value for name, value in given.items() if value is not None}
    if uncertainty is None:
        if given:
            raise TypeError("%s() got %s without uncertainty=N (the ensemble's members)" % (
                function, ", ".join(sorted(given))))
        return None
    ensemble = _bmr.UncertaintySettings()
    ensemble.members = int(uncertainty)
    for name, value in given.items():
        fields, convert = _UNCERTAINTY_KEYWORDS[name]
        values = (value,) if len(fields) == 1 else tuple(value)
        if len(values) != len(fields):
            raise TypeError("%s() takes %s as (low, high)" % (function, name))
        for field, item in zip(fields, values):
            setattr(ensemble, field, convert(item))
    return ensemble


def register(
    preoperative_image,
    *,
    brain_mask=None,
    tumour_mask=None,
    skull_surface=None,
    label_maps=(),
    intraoperative_surface=None,
    sparse_points=None,
    sparse_displacements=None,
    intraoperative_image=None,
    intraoperative_mask=None,
    uncertainty=None,
    progress=None,
    **settings
):
    """The whole registration in one call, as ``biomech register``: model, solve,
    B-spline transform, warped image and label maps, edge-based evaluation.

    Intraoperative data: a displaced surface (:class:`Surface`), sparse
    points with their displacements ((N, 3) arrays, mm), or an intraoperative
    image (and its brain mask), which is also the evaluation's fixed image.
    Settings: the options of ``biomech register`` as keywords (see
    :func:`default_registration_settings`), e.g. ``grid="tetrahedra"``,
    ``element_size=7``, ``craniotomy_centre=(x, y, z)``, ``craniotomy_radius=30``.

    Returns a :class:`RegistrationResult` with ``report``, the dict
    ``biomech register`` writes as registration-report.json. A solve that did
    not converge is reported there (``report["solve"]["converged"]``) and in
    ``warnings``; bad input and a failed solve raise :class:`Error`.

    ``uncertainty=N`` and the ``uncertainty_*`` keywords: the ensemble, as
    :func:`update` runs it, on the model this call prepares.
    """
    ensemble = _uncertainty_settings("register", uncertainty, settings)
    values = _checked_settings("register", settings)
    result, report, spread = _bmr._register(
        preoperative_image, brain_mask, tumour_mask, skull_surface, list(label_maps), intraoperative_surface,
        sparse_points, sparse_displacements, intraoperative_image, intraoperative_mask, values, ensemble, progress,
    )
    return _with_report(result, report, spread)


def _with_report(result, report, spread):
    """The result of register() or update() with its report and, after an ensemble, its uncertainty."""
    result.report = report
    if spread is not None:
        result.uncertainty_map, result.mean_transform, result.nodal_uncertainty = spread
    return result


def prepare(
    image,
    *,
    brain_mask=None,
    tumour_mask=None,
    skull_surface=None,
    label_maps=(),
    output=None,
    progress=None,
    **settings
):
    """Before surgery, as ``biomech prepare``: skull stripping (without ``brain_mask``),
    classification, grid, materials, surfaces and regions of the preoperative image, for
    the planned craniotomy (``craniotomy_centre`` and ``craniotomy_radius``, or
    ``craniotomy_mask``). Returns a :class:`ModelBundle`; with ``output`` it is also
    written there (a folder that :func:`update` and ``biomech update`` read).
    Settings: those of :func:`register` (the solve's, fit's and evaluation's are kept as
    the updates' defaults); gravity belongs to :func:`update`.
    """
    values = _checked_settings("prepare", settings)
    for name in ("gravity", "csf_drained_depth", "max_distance"):
        if name in values:
            raise TypeError("prepare() takes no %s: give it to update()" % name)
    bundle = _bmr._prepare(image, brain_mask, tumour_mask, skull_surface, list(label_maps), values, progress)
    if output is not None:
        bundle.write(output)
    return bundle


def update(
    bundle,
    *,
    intraoperative_surface=None,
    sparse_points=None,
    sparse_displacements=None,
    intraoperative_image=None,
    intraoperative_mask=None,
    previous=None,
    uncertainty=None,
    progress=None,
    **settings
):
    """During surgery, as ``biomech update``: loads from the intraoperative data, solve,
    transform, warped image and label maps, evaluation, on a prepared model
    (a :class:`ModelBundle`, or the path of a bundle folder). Settings: the bundle's,
    with these keywords (the solve's, fit's and evaluation's, and ``gravity``,
    ``csf_drained_depth``, ``max_distance``) over them. ``previous``: an earlier
    update of the same surgery (its :class:`RegistrationResult`, or the output folder
    of ``biomech update``) to start the solve from (``result.solve.warm_started``);
    the result is the cold solve's within the solver tolerance. Returns a
    :class:`RegistrationResult` with ``report``, as :func:`register`.

    ``uncertainty=N``, as ``biomech update --uncertainty N``: an ensemble of N solves with
    the uncertain inputs drawn (``uncertainty_noise`` mm, ``uncertainty_gravity`` (low,
    high) fractions, ``uncertainty_modulus_spread``, ``uncertainty_tissue_modulus_spread``,
    ``uncertainty_poisson`` (low, high),
    ``uncertainty_skull_gap`` mm, ``uncertainty_exposed_radius`` mm, ``uncertainty_tolerance`` mm,
    ``uncertainty_seed``;
    defaults and meaning in docs/registration.md, Uncertainty).
    The result then has ``uncertainty_map`` (an :class:`Image` on the preoperative grid:
    per voxel the 95th percentile of |u_i - u_mean| in mm), ``mean_transform``,
    ``nodal_uncertainty`` (mm per node) and the report's ``uncertainty``.
    """
    if not isinstance(bundle, _bmr.ModelBundle):
        bundle = _bmr.read_model_bundle(bundle)
    ensemble = _uncertainty_settings("update", uncertainty, settings)
    values = _checked_settings("update", settings)
    result, report, spread = _bmr._update(
        bundle, intraoperative_surface, sparse_points, sparse_displacements, intraoperative_image,
        intraoperative_mask, previous, values, ensemble, progress,
    )
    return _with_report(result, report, spread)


# ITK Python's objects (`import itk`) wherever the package's are taken, and back when given
# (itk_bridge.py, docs/python.md).
from . import itk_bridge as _itk_bridge
from .itk_bridge import image_from_itk, itk_image_from_image, itk_transform_from_transform, transform_from_itk

for _name, _value in list(globals().items()):
    if not _name.startswith("_") and callable(_value) and not isinstance(_value, type) \
            and _name not in _itk_bridge.__all__:
        globals()[_name] = _itk_bridge.accepting_itk(_value)

# ITK Python's functional names of the module's ITK filters (snake_case of the class, keywords
# of its Set methods), beside the short names: (class, function, its primary inputs, Set
# method -> keyword).
for _itk_class, _function, _inputs, _keywords in [
    ("AtlasBrainMaskImageFilter", atlas_brain_mask, ("image",),
     dict(atlas_mask_image="atlas_mask", use_b_spline_stage="bspline_stage")),
    ("FuzzyCMeansClassifierImageFilter", classify_tissue, ("image",),
     dict(mask_image="mask", number_of_classes="classes", maximum_number_of_iterations="max_iterations",
          number_of_work_units="threads")),
    ("BiomechanicalGridImageFilter", make_grid, ("labels",), dict(grid_kind="kind", number_of_work_units="threads")),
    ("BiomechanicalMaterialMappingFilter", map_materials, ("model",),
     dict(model_input="model", number_of_work_units="threads")),
    ("BiomechanicalRegionsFilter", model_regions, ("model",), dict(model_input="model")),
    ("BrainSurfaceMeshSource", brain_surfaces, ("mask",), dict(compute_skull="skull")),
    ("DisplacementPointSetToBSplineTransformFilter", fit_transform, ("points", "displacements"),
     dict(reference_image="reference")),
    ("EdgeHausdorffDistanceImageFilter", evaluate_edges, ("fixed",), dict(moving_image="moving", mask_image="mask")),
    ("TransformWarpImageFilter", warp_image, ("image",), dict(reference_image="reference")),
    ("BSplineIntensityRegistrationFilter", bspline_registration, ("moving",),
     dict(moving_image="moving", fixed_image="fixed", translation_number_of_iterations="translation_iterations",
          number_of_histogram_bins="histogram_bins")),
]:
    _alias = _itk_bridge.functional_alias(_itk_class, _function, _inputs, _keywords)
    globals()[_alias.__name__] = _alias

__all__ = [name for name in dir() if not name.startswith("_")]
