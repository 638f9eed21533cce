#!/usr/bin/env python3
"""The validation study's intensity peers from Python: ANTs SyN (antspyx) and elastix (itk-elastix).

One registration of a study scene's cached ground truth (a `biomech demo --truth-only` folder): the
intraoperative image fixed, the preoperative image moving, the intraoperative brain mask. Writes into
FOLDER what `biomech demo --truth-from TRUTH --peer-field ... --peer-warped ... --peer-details ...` scores
like every other method: the peer's displacement field over the preoperative grid (field.nii.gz, the
backward map minus the point, LPS mm, so that errors are measured over the whole brain, also outside a
partial field of view), its own warped image on the intraoperative grid (warped.nii.gz) and peer.json
(tool, version, parameters, seconds). The itk-elastix run is also compared with the Debian elastix
binary's run of the same scene (its folder, with the same parameter files): both transforms' fields are
made by the same transformix, and their difference over the brain goes into peer.json.

Runs in the project's venv (scripts/install-python-environment.sh: itk 5.4, itk-elastix, antspyx):

    build/venv/bin/python examples/validation_peers.py ants-syn TRUTH FOLDER [--threads N] [--reduced]
    build/venv/bin/python examples/validation_peers.py itk-elastix TRUTH FOLDER --debian-elastix ELASTIX_FOLDER
"""
import argparse
import glob
import importlib.metadata
import json
import os
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ELASTIX_PARAMETERS = [os.path.join(ROOT, "examples", "elastix", name) for name in ("affine.txt", "bspline.txt")]
ELASTIX_QUICK_PARAMETERS = [os.path.join(ROOT, "test", "elastix-quick.txt")]
# ANTs SyN as antspyx documents it (an affine stage, then SyN with mutual information), not tuned on the truth; the
# seed makes reruns repeat. The reduced study (CI) shortens SyN's iterations, as the notebook's coarse settings.
ANTS_SETTINGS = {"type_of_transform": "SyN", "random_seed": 121212}
ANTS_REDUCED_SETTINGS = dict(ANTS_SETTINGS, reg_iterations=(20, 10, 0))
PEERS = {"ants-syn": "ANTs SyN", "itk-elastix": "itk-elastix B-spline"}


def fail(message):
    print("validation_peers: error: " + message, file=sys.stderr)
    sys.exit(1)


def scene_images(truth):
    """The scene's intraoperative image, its brain mask, the preoperative image and the brain mask on its grid."""
    import itk
    with open(os.path.join(truth, "run.json")) as handle:
        solved = json.load(handle)
    if solved["status"] != 0 or not solved.get("report"):
        fail("the ground truth in %s failed: %s" % (truth, solved.get("error", "")))
    return (itk.imread(os.path.join(truth, "intraoperative.nii.gz"), itk.F),
            itk.imread(os.path.join(truth, "intraoperative-brain-mask.nii.gz"), itk.UC),
            itk.imread(solved["report"]["preoperative_image"], itk.F),
            itk.imread(os.path.join(truth, "intraoperative-brain-on-preoperative-grid.nii.gz"), itk.UC))


def itk_image_on(array, grid, is_vector=False):
    """`array` as an itk image with `grid`'s spacing, origin and direction (CopyInformation would also reset a
    vector image's length to the grid's one component)."""
    import itk
    image = itk.image_view_from_array(array, is_vector=is_vector)
    image.SetSpacing(grid.GetSpacing())
    image.SetOrigin(grid.GetOrigin())
    image.SetDirection(grid.GetDirection())
    return image


def ants_image(itk_image):
    """An itk.Image as an ANTs image (indexed [x, y, z], ITK's spacing, origin and direction, LPS)."""
    import ants
    import itk
    import numpy as np
    array = itk.array_from_image(itk_image).astype(np.float32).transpose(2, 1, 0)
    return ants.from_numpy(array, origin=tuple(itk_image.GetOrigin()), spacing=tuple(itk_image.GetSpacing()),
                           direction=itk.array_from_matrix(itk_image.GetDirection()))


def register_ants(truth, folder, reduced):
    import ants
    import itk
    intraoperative, mask, preoperative, _ = scene_images(truth)
    settings = ANTS_REDUCED_SETTINGS if reduced else ANTS_SETTINGS
    fixed, moving = ants_image(intraoperative), ants_image(preoperative)
    start = time.perf_counter()
    syn = ants.registration(fixed, moving, mask=ants_image(mask), outprefix=os.path.join(folder, "ants-"), **settings)
    seconds = time.perf_counter() - start
    # ANTs' affine and warp composed into one field over the preoperative grid.
    composed = ants.apply_transforms(moving, moving, syn["fwdtransforms"], compose=os.path.join(folder, "composed-"))
    os.replace(composed, os.path.join(folder, "field.nii.gz"))
    itk.imwrite(itk_image_on(syn["warpedmovout"].numpy().transpose(2, 1, 0).copy(), intraoperative),
                os.path.join(folder, "warped.nii.gz"))
    for path in glob.glob(os.path.join(folder, "ants-*")):
        os.remove(path)
    return {"tool": "antspyx", "version": importlib.metadata.version("antspyx"), "seconds": seconds,
            "parameters": {key: list(value) if isinstance(value, tuple) else value for key, value in settings.items()}}


def on_grid(parameter_object, image):
    """The parameter maps with the last one's output grid set to `image`'s (transformix's field is made there)."""
    last = parameter_object.GetNumberOfParameterMaps() - 1
    size, spacing, origin = image.GetLargestPossibleRegion().GetSize(), image.GetSpacing(), image.GetOrigin()
    direction = image.GetDirection()
    parameter_object.SetParameter(last, "Size", [str(size[axis]) for axis in range(3)])
    parameter_object.SetParameter(last, "Spacing", ["%.17g" % spacing[axis] for axis in range(3)])
    parameter_object.SetParameter(last, "Origin", ["%.17g" % origin[axis] for axis in range(3)])
    # elastix's Direction is column-major.
    parameter_object.SetParameter(last, "Direction", ["%.17g" % direction(row, column)
                                                      for column in range(3) for row in range(3)])
    return parameter_object


def debian_elastix_parameters(folder):
    """The Debian elastix run's transform parameter files (TransformParameters.N.txt) as one chain of maps."""
    import itk
    files = sorted(glob.glob(os.path.join(folder, "TransformParameters.[0-9]*.txt")),
                   key=lambda path: int(path.rsplit(".", 2)[-2]))
    if not files:
        fail("%s holds no TransformParameters.N.txt: run the scene's elastix method first" % folder)
    parameter_object = itk.ParameterObject.New()
    for path in files:
        parameter_object.AddParameterFile(path)
    # The maps chain in the object's order, as itk-elastix's own results do; not through the files' paths.
    for index in range(parameter_object.GetNumberOfParameterMaps()):
        parameter_object.SetParameter(index, "InitialTransformParametersFileName", "NoInitialTransform")
    return parameter_object


def field_array(parameter_object, preoperative):
    import itk
    # transformix also writes the field as deformationField.nii (85 MB) into its output directory, the current one
    # unless told: a temporary one.
    with tempfile.TemporaryDirectory() as scratch:
        return itk.array_from_image(itk.transformix_deformation_field(
            preoperative, on_grid(parameter_object, preoperative), output_directory=scratch))


def register_itk_elastix(truth, folder, reduced, threads, debian_folder):
    import itk
    import numpy as np
    intraoperative, mask, preoperative, brain = scene_images(truth)
    files = ELASTIX_QUICK_PARAMETERS if reduced else ELASTIX_PARAMETERS
    parameter_object = itk.ParameterObject.New()
    for path in files:
        parameter_object.AddParameterFile(path)
    start = time.perf_counter()
    _, result = itk.elastix_registration_method(intraoperative, preoperative, parameter_object=parameter_object,
                                                fixed_mask=mask, log_to_console=False,
                                                number_of_threads=threads or os.cpu_count())
    seconds = time.perf_counter() - start
    itk.imwrite(itk.transformix_filter(preoperative, result), os.path.join(folder, "warped.nii.gz"))
    field = field_array(result, preoperative)
    itk.imwrite(itk_image_on(field, preoperative, is_vector=True), os.path.join(folder, "field.nii.gz"))
    details = {"tool": "itk-elastix", "version": importlib.metadata.version("itk-elastix"), "seconds": seconds,
               "parameter_files": files}
    if debian_folder:
        # The same transformix makes both fields, so their difference is the registrations'.
        difference = np.linalg.norm(field - field_array(debian_elastix_parameters(debian_folder), preoperative),
                                    axis=-1)[itk.array_view_from_image(brain) > 0]
        details["difference_from_debian_elastix_mm"] = {
            "mean": float(difference.mean()), "p95": float(np.percentile(difference, 95)),
            "max": float(difference.max()), "samples": int(difference.size), "debian_folder": debian_folder}
    return details


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("peer", choices=sorted(PEERS))
    parser.add_argument("truth", help="the scene's `biomech demo --truth-only` folder")
    parser.add_argument("folder", help="where field.nii.gz, warped.nii.gz and peer.json go")
    parser.add_argument("--threads", type=int, default=0, help="threads (0: all cores)")
    parser.add_argument("--reduced", action="store_true",
                        help="the reduced study's settings (ANTs SyN iterations (20, 10, 0); test/elastix-quick.txt)")
    parser.add_argument("--debian-elastix", default="",
                        help="itk-elastix: the Debian elastix run's folder to compare with (TransformParameters.N.txt)")
    arguments = parser.parse_args()
    if not os.path.isfile(os.path.join(arguments.truth, "run.json")):
        fail("%s is not a study truth folder (no run.json): run the scene's truth job first" % arguments.truth)
    os.makedirs(arguments.folder, exist_ok=True)
    # ANTs and ITK read their thread count from the environment when they first start threads.
    os.environ["ITK_GLOBAL_DEFAULT_NUMBER_OF_THREADS"] = str(arguments.threads or os.cpu_count())
    if arguments.peer == "ants-syn":
        details = register_ants(arguments.truth, arguments.folder, arguments.reduced)
    else:
        details = register_itk_elastix(arguments.truth, arguments.folder, arguments.reduced, arguments.threads,
                                       arguments.debian_elastix)
    details["name"] = PEERS[arguments.peer]
    path = os.path.join(arguments.folder, "peer.json")
    with open(path + ".tmp", "w") as handle:
        json.dump(details, handle, indent=1)
    os.replace(path + ".tmp", path)


if __name__ == "__main__":
    main()
