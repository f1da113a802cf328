"""The 3-D experiment: rendered stereo pairs of the indoor scene, each matcher characterised on frames it
then does not map, every sensor model scored against the exact ground truth."""

import math
from pathlib import Path

import numpy as np

from prismap._progress import progress
from prismap._validate import check_positive
from prismap.camera import StereoCamera
from prismap.errors import PrismapInputError
from prismap.experiment._cells import ExperimentResult, claim_out_dir, draw_figures, run_cells
from prismap.experiment._results import MODELS, prior_of, write_results

MATCHERS = ("bm", "sgbm", "variational")

SCENE_SIZES = {
    False: {"n_frames": 40, "image_scale": 1.0, "voxel_size_m": 0.1, "subsample": 2},
    True: {"n_frames": 16, "image_scale": 0.25, "voxel_size_m": 0.1, "subsample": 1},
}
"""Full and ``quick`` sizes: frames rendered (every ``characterise_every``-th characterises), image scale of
the New Tsukuba camera (640x480 at 1), voxel size, pixel subsampling when mapping."""

SLICE_HEIGHT_M = 1.0
"""Height of the horizontal map slice drawn in the figures (table, boxes, shelves and walls cross it)."""


def scaled_tsukuba_camera(scale):
    """The New Tsukuba rig (:func:`prismap.sim.tsukuba_camera`) with its image resized by ``scale``."""
    from prismap.sim import tsukuba_camera

    base = tsukuba_camera()
    if scale == 1.0:
        return base
    width, height = round(base.width * scale), round(base.height * scale)
    return StereoCamera(base.focal_px * scale, (base.cx_px + 0.5) * scale - 0.5, (base.cy_px + 0.5) * scale - 0.5,
                        base.baseline_m, width=width, height=height)


def scene3d_settings(*, n_frames=None, voxel_size_m=None, seed=0, quick=False, matchers=MATCHERS,
                     characterise_every=4, max_range_m=10.0, grid_offset=0.5):
    """The settings dict of a 3-D run (sizes of ``SCENE_SIZES`` unless overridden)."""
    sizes = dict(SCENE_SIZES[bool(quick)])
    if n_frames is not None:
        if isinstance(n_frames, bool) or int(n_frames) != n_frames or n_frames < 2:
            raise PrismapInputError(f"`n_frames` must be an integer >= 2 (characterisation + mapping); got {n_frames!r}")
        sizes["n_frames"] = int(n_frames)
    if voxel_size_m is not None:
        sizes["voxel_size_m"] = check_positive(voxel_size_m, "voxel_size_m")
    every = characterise_every
    if isinstance(every, bool) or int(every) != every or every < 2:
        raise PrismapInputError(f"`characterise_every` must be an integer >= 2; got {every!r}")
    unknown = [m for m in matchers if m not in MATCHERS]
    if unknown or not matchers:
        raise PrismapInputError(f"`matchers` must be a non-empty subset of {list(MATCHERS)}; got {list(matchers)}")
    offset = float(grid_offset)
    if not 0.0 <= offset < 1.0:
        raise PrismapInputError(f"`grid_offset` must lie in [0, 1) voxels; got {grid_offset!r}")
    return {"world": "scene3d", "quick": bool(quick), "seed": int(seed), "characterise_every": int(every),
            "grid_offset_m": offset * sizes["voxel_size_m"],
            "max_range_m": check_positive(max_range_m, "max_range_m"), "matchers": list(matchers), **sizes}


def split_frames(n_frames, every):
    """Indices ``(characterisation, mapping)``: every ``every``-th frame (from 0) characterises, the rest map."""
    indices = np.arange(n_frames)
    return indices[indices % every == 0], indices[indices % every != 0]


def run_scene3d(out_dir, *, n_frames=None, voxel_size_m=None, seed=0, quick=False, matchers=MATCHERS,
                models=MODELS, characterise_every=4, max_range_m=10.0, grid_offset=0.5):
    """Characterise each matcher on some frames of the indoor scene, map the others with every model, score.

    The seeded :func:`prismap.sim.indoor_scene` is rendered along :func:`prismap.sim.indoor_trajectory`.
    Frames ``0, k, 2k, ...`` (``k = characterise_every``) characterise each matcher
    (:func:`prismap.characterise.characterise_matcher`: thesis tables 3.1-3.3 with coverage, bad-1px and
    bad-2px, and the error figures, in ``MATCHER/characterisation/``); the other frames are matched once
    (``MATCHER/disparity/``, uint16 PNG, value / 256 px) and mapped by :func:`prismap.pipeline.map_sequence`
    with every model, using that matcher's error model. Maps are scored on the voxels a perfect sensor
    observed from the mapping frames within ``max_range_m``; ``p0`` is their occupancy ratio.

    Parameters
    ----------
    out_dir : str or Path
        A rerun with the same settings reuses every finished step (sequence, characterisations,
        disparities, cells).
    n_frames : int or None
        Frames rendered; None = :data:`SCENE_SIZES`.
    voxel_size_m : float or None, metres
    seed : int
        Scene layout, trajectory and image noise.
    quick : bool
        Quarter-size images (160x120), 16 frames, 0.1 m voxels: the smallest size found where PRISM
        beats ideal and hit/miss with SGBM on Brier, log-loss and occupied-called-free (not at 12 frames
        or 0.2 m voxels).
    matchers, models : sequence of str
    characterise_every : int >= 2
    max_range_m : float, metres
        Distance along a ray beyond which maps are not updated (and the ground truth not observed).
    grid_offset : float in [0, 1), voxels
        The scene and trajectory are translated by this many voxels on every axis. The room's floor,
        walls and box faces lie at round coordinates; at offset 0 they coincide with voxel faces, and a
        closed box then marks the voxel beyond its face as occupied although only its boundary plane
        is solid (the whole floor layer above z = 0, for instance): ground truth no sensor could
        confirm. The default half voxel puts those planes through voxel middles.

    Returns
    -------
    ExperimentResult
    """
    from prismap import sim
    from prismap.io import read_sequence, write_sequence

    settings = scene3d_settings(n_frames=n_frames, voxel_size_m=voxel_size_m, seed=seed, quick=quick,
                                matchers=matchers, characterise_every=characterise_every, max_range_m=max_range_m,
                                grid_offset=grid_offset)
    out = claim_out_dir(out_dir, settings)
    voxel = settings["voxel_size_m"]
    camera = scaled_tsukuba_camera(settings["image_scale"])
    base = sim.indoor_scene(seed=seed)
    shift = settings["grid_offset_m"]
    scene = sim.Scene3D(base.box_lo + shift, base.box_hi + shift, base.box_texture, base.box_texel_m, base.box_tint,
                        name=base.name)
    poses = sim.indoor_trajectory(settings["n_frames"], seed=seed)
    poses[:, :3, 3] += shift
    char_index, map_index = split_frames(settings["n_frames"], settings["characterise_every"])
    if len(map_index) == 0:
        raise PrismapInputError(f"{settings['n_frames']} frames leave none to map after characterisation")
    frames = list(progress(scene.frames(camera, poses, seed=seed), total=len(poses), desc="render", unit="frame"))
    char_frames = [frames[i] for i in char_index]
    map_frames = [frames[i] for i in map_index]
    sequence_dir = out / "sequence"
    if not (sequence_dir / "occupancy.npz").is_file():  # written last: its presence means the sequence is whole
        truth = scene.ground_truth(map_frames, voxel, max_range_m=settings["max_range_m"])
        write_sequence(map_frames, sequence_dir, occupancy=truth)
    sequence = read_sequence(sequence_dir)
    truth = sequence.ground_truth
    p0 = prior_of(truth)
    largest = max(float(np.nanmax(f.disparity_gt)) for f in frames)

    results, artifacts = [], []
    for matcher_name in settings["matchers"]:
        matcher = _matcher(matcher_name, largest)
        mixture, char_artifacts = _characterise(out / matcher_name / "characterisation", char_frames, matcher,
                                                f"{scene.name} frames {char_index.tolist()}")
        disparity_dir = _match(out / matcher_name / "disparity", map_frames, matcher)
        build_map = _mapper(sequence, disparity_dir, matcher_name, mixture, p0, settings)
        cells, maps = run_cells(out, matcher_name, models, build_map, truth, settings)
        results += cells
        artifacts += char_artifacts
        artifacts += draw_figures(out, matcher_name, cells, maps, truth, layer=math.floor((SLICE_HEIGHT_M + shift) / voxel),
                                  where=f"z = {SLICE_HEIGHT_M} m")
    notes = (
        f"Indoor scene {scene.name}, {camera.width}x{camera.height} New Tsukuba camera, {len(char_index)} "
        f"characterisation frames ({char_index.tolist()}) and {len(map_index)} other mapping frames, "
        f"{voxel} m voxels, pixel step {settings['subsample']}, rays to {settings['max_range_m']} m; scene and "
        f"trajectory shifted by {shift:g} m on each axis so that floor and walls cut voxels through the middle.",
        f"p0 = {p0:.4f}: the occupancy ratio of the voxels a perfect sensor observed (the scored voxels).",
        "Each matcher's PRISM, convolution and Andert models use the error model characterised on the "
        "characterisation frames; time = mapping wall time (PRISM's tables included).",
    )
    paths = write_results(results, out, title="3-D indoor scene, characterised matchers", notes=notes,
                          settings=settings)
    artifacts = [(paths["table"], "Scores of every matcher x sensor model on the 3-D indoor scene (Markdown)."),
                 (paths["json"], "The same scores with reliability bins and histograms (JSON).")] + artifacts
    return ExperimentResult("scene3d", tuple(results), p0, settings, tuple(artifacts))


def _matcher(name, largest_disparity_px):
    """``name`` with a disparity range covering the largest true disparity of the scene."""
    from prismap.stereo import make_matcher

    if name == "variational":
        return make_matcher(name, max_disparity=float(math.ceil(largest_disparity_px) + 1))
    return make_matcher(name, num_disparities=16 * math.ceil((largest_disparity_px + 1) / 16))


def _characterise(out_dir, frames, matcher, dataset):
    """The matcher's error mixture (characterised once, then read back) and its table and figures."""
    from prismap.characterise import characterise_matcher, load_error_model, write_characterisation

    paths = {"model": out_dir / "error_model.json", "table": out_dir / "table.md",
             "figure": out_dir / "errors.png", "figure_wide": out_dir / "errors_wide.png"}
    if not all(p.is_file() for p in paths.values()):
        paths = write_characterisation(characterise_matcher(frames, matcher, dataset=dataset), out_dir)
    name = matcher.name
    artifacts = [
        (paths["table"], f"{name}: fitted error mixtures G = 1..4 with AIC/BIC, coverage, bad-1px, bad-2px "
                         "(thesis tables 3.1-3.3 layout)."),
        (paths["figure"], f"{name}: disparity error histogram with the fitted mixtures."),
        (paths["figure_wide"], f"{name}: the error tails on a log scale."),
        (paths["model"], f"{name}: the error model (JSON) every model of this matcher used."),
    ]
    return load_error_model(paths["model"]).mixture, artifacts


def _match(out_dir, frames, matcher):
    """Write the matcher's disparity of each mapping frame as ``NNNNNN.png`` (uint16, value / 256 px, 0 = invalid)."""
    from prismap.io import write_disparity_png

    out_dir = Path(out_dir)
    for index, frame in enumerate(progress(frames, total=len(frames), desc=f"match {matcher.name}", unit="frame")):
        path = out_dir / f"{index:06d}.png"
        if not path.is_file():
            write_disparity_png(path, matcher.compute(frame.left, frame.right), f"{matcher.name} disparity of frame {index}")
    return out_dir


def _mapper(sequence, disparity_dir, matcher_name, mixture, p0, settings):
    """``build_map(model_name)``: the pipeline's map of the mapping frames from the matcher's disparities."""
    from prismap.pipeline import MappingConfig, map_sequence

    def build_map(model_name):
        config = MappingConfig(model=model_name, voxel_size_m=settings["voxel_size_m"], p0=p0, error_model=mixture,
                               matcher=matcher_name, disparity_source=str(Path(disparity_dir).resolve()),
                               max_range_m=settings["max_range_m"], subsample=settings["subsample"])
        return map_sequence(sequence, config)

    return build_map
