"""The 3-D experiments: rendered stereo pairs of a box world (the indoor room, the street), each matcher
characterised on frames it then does not map, every sensor model scored against the exact ground truth."""

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from prismap._progress import progress
from prismap._validate import check_integer, check_positive
from prismap.errors import PrismapInputError
from prismap.experiment._cells import ExperimentResult, claim_out_dir, draw_figures, run_cells
from prismap.experiment._results import (
    MAP_PRIOR_SUFFIX,
    MODELS_3D,
    prior_of,
    split_variant,
    variant_params,
    write_results,
)
from prismap.experiment._targets import format_targets, measure_targets

MATCHERS = ("bm", "sgbm", "variational")
"""Every matcher the 3-D experiments characterise and map with, in the order of the tables."""


@dataclass(frozen=True)
class RenderedWorld:
    """What a 3-D experiment needs to know of its world; the run itself is :func:`run_rendered_world`.

    Attributes
    ----------
    name : str
        ``settings["world"]`` and the experiment's name (``"scene3d"``, ``"street3d"``).
    title : str
        Heading of the results table.
    sizes : dict of bool -> dict
        Full (False) and ``quick`` (True) sizes: ``n_frames`` rendered along the drive,
        ``between_frames`` (extra characterisation frames from positions between the drive's; 0 without
        ``between_trajectory``), ``image_scale`` of the camera,
        ``voxel_size_m``, ``subsample`` (pixel step when mapping), ``max_range_m``, the integration
        ``mode`` of :class:`prismap.pipeline.MappingConfig`, and ``model_params`` (model name -> its
        extra parameters; models not named get their defaults).
    scene : callable
        ``scene(seed) -> Scene3D``.
    trajectory : callable
        ``trajectory(n_frames, seed) -> (N, 4, 4) T_world_cam``.
    between_trajectory : callable or None
        ``between_trajectory(n_frames, n_between, seed) -> (n_between, 4, 4) T_world_cam``: a second drive
        over the same stretch whose positions the drive of ``n_frames`` does not use; None = none.
    camera : callable
        ``camera(scale) -> StereoCamera``.
    slice_height_m : float, metres
        Height of the horizontal map slice drawn in the figures.
    description : str
        First words of the table's notes (the scene and camera).
    """

    name: str
    title: str
    sizes: dict
    scene: object
    trajectory: object
    camera: object
    slice_height_m: float
    description: str
    between_trajectory: object = None


def _scene3d_world():
    from prismap import sim

    return RenderedWorld(
        "scene3d", "3-D indoor scene, characterised matchers",
        {False: {"n_frames": 40, "between_frames": 0, "image_scale": 1.0, "voxel_size_m": 0.1, "subsample": 2,
                 "max_range_m": 10.0, "mode": "ray", "model_params": {}},
         True: {"n_frames": 16, "between_frames": 0, "image_scale": 0.25, "voxel_size_m": 0.1, "subsample": 1,
                "max_range_m": 10.0, "mode": "ray", "model_params": {}}},
        lambda seed: sim.indoor_scene(seed=seed), lambda n, seed: sim.indoor_trajectory(n, seed=seed),
        lambda scale: sim.tsukuba_camera(scale=scale), 1.0, "Indoor scene, New Tsukuba camera")


STREET_BETWEEN_FRAMES = 32
"""Extra characterisation frames of the full street, from positions between the drive's: with the drive's own
4 the per-class mixtures see the rare gross errors of every class (on 4 frames alone a class fitted no outlier
component and gave some errors of the mapped frames log-densities near -5800)."""

STREET_NEAR_M = 1.5
"""PRISM's ``near_m`` on the street: no surface is nearer than 1.8 m to the drive. PRISM's tables grow like
``1 / near_m``; at its default 0.1 m they outgrow the cache on this sequence and PRISM maps several times slower."""


def _street3d_world():
    from prismap import sim

    return RenderedWorld(
        "street3d", "3-D street, KITTI-like rig, characterised matchers",
        {False: {"n_frames": 16, "between_frames": STREET_BETWEEN_FRAMES, "image_scale": 0.5, "voxel_size_m": 0.2,
                 "subsample": 2, "max_range_m": 40.0, "mode": "projective",
                 "model_params": {"prism": {"near_m": STREET_NEAR_M}}},
         True: {"n_frames": 8, "between_frames": 4, "image_scale": 0.25, "voxel_size_m": 0.4, "subsample": 1,
                "max_range_m": 30.0, "mode": "projective", "model_params": {"prism": {"near_m": STREET_NEAR_M}}}},
        lambda seed: sim.street_scene(seed=seed), lambda n, seed: sim.street_trajectory(n, seed=seed),
        lambda scale: sim.kitti_camera(scale=scale), 1.0, "Street scene, KITTI-like camera",
        lambda n, n_between, seed: sim.street_trajectory_between(n, n_between, seed=seed))


WORLDS = {"scene3d": _scene3d_world, "street3d": _street3d_world}
"""Name -> :class:`RenderedWorld` factory of every 3-D experiment."""


def scene3d_settings(*, world="scene3d", n_frames=None, voxel_size_m=None, seed=0, quick=False, matchers=MATCHERS,
                     characterise_every=4, max_range_m=None, grid_offset=0.5, between_frames=None,
                     class_pass_through=False):
    """The settings dict of a 3-D run on ``world`` (its sizes unless overridden); ``class_pass_through`` is
    recorded only when set, so the settings of runs without it stay as they were."""
    if world not in WORLDS:
        raise PrismapInputError(f"`world` must be one of {sorted(WORLDS)}; got {world!r}")
    spec = WORLDS[world]()
    sizes = dict(spec.sizes[bool(quick)])
    if between_frames is not None:
        sizes["between_frames"] = check_integer(between_frames, "between_frames", expected="an integer >= 0",
                                                condition=lambda n: n >= 0)
        if sizes["between_frames"] and spec.between_trajectory is None:
            raise PrismapInputError(f"`between_frames`: world {world!r} has no drive between its frames; got "
                                    f"{between_frames!r} (0 or None)")
    if n_frames is not None:
        if isinstance(n_frames, bool) or int(n_frames) != n_frames or n_frames < 2:
            raise PrismapInputError(f"`n_frames` must be an integer >= 2 (characterisation + mapping); got {n_frames!r}")
        sizes["n_frames"] = int(n_frames)
    if voxel_size_m is not None:
        sizes["voxel_size_m"] = check_positive(voxel_size_m, "voxel_size_m")
    if max_range_m is not None:
        sizes["max_range_m"] = check_positive(max_range_m, "max_range_m")
    every = characterise_every
    if isinstance(every, bool) or int(every) != every or every < 2:
        raise PrismapInputError(f"`characterise_every` must be an integer >= 2; got {every!r}")
    unknown = [m for m in matchers if m not in MATCHERS]
    if unknown or not matchers:
        raise PrismapInputError(f"`matchers` must be a non-empty subset of {list(MATCHERS)}; got {list(matchers)}")
    offset = float(grid_offset)
    if not 0.0 <= offset < 1.0:
        raise PrismapInputError(f"`grid_offset` must lie in [0, 1) voxels; got {grid_offset!r}")
    return {"world": world, "quick": bool(quick), "seed": int(seed), "characterise_every": int(every),
            "grid_offset_m": offset * sizes["voxel_size_m"], "matchers": list(matchers), **sizes,
            **({"class_pass_through": True} if class_pass_through else {})}


def split_frames(n_frames, every):
    """Indices ``(characterisation, mapping)``: every ``every``-th frame (from 0) characterises, the rest map."""
    indices = np.arange(n_frames)
    return indices[indices % every == 0], indices[indices % every != 0]


def run_scene3d(out_dir, *, n_frames=None, voxel_size_m=None, seed=0, quick=False, matchers=MATCHERS,
                models=MODELS_3D, characterise_every=4, max_range_m=None, grid_offset=0.5, between_frames=None,
                class_pass_through=False):
    """Characterise each matcher on some frames of the indoor room, map the others with every model, score.

    The seeded :func:`prismap.sim.indoor_scene` rendered along :func:`prismap.sim.indoor_trajectory` by the
    New Tsukuba camera. Full size: 640x480, 40 frames, 0.1 m voxels, every 2nd pixel, rays to 10 m.
    ``quick``: 160x120, 16 frames, every pixel: the smallest size found where PRISM beats ideal and
    hit/miss with SGBM on Brier, log-loss and occupied-called-free. Ray mode, so
    ``models=MODELS_3D_MAP_PRIOR`` adds conditioned PRISM with the map as prior. Arguments and result: see
    :func:`run_rendered_world`.
    """
    return run_rendered_world("scene3d", out_dir, n_frames=n_frames, voxel_size_m=voxel_size_m, seed=seed,
                              quick=quick, matchers=matchers, models=models, characterise_every=characterise_every,
                              max_range_m=max_range_m, grid_offset=grid_offset,
                              between_frames=between_frames, class_pass_through=class_pass_through)


def run_street3d(out_dir, *, n_frames=None, voxel_size_m=None, seed=0, quick=False, matchers=MATCHERS,
                 models=MODELS_3D, characterise_every=4, max_range_m=None, grid_offset=0.5, between_frames=None,
                class_pass_through=False):
    """Characterise each matcher on some frames of the street drive, map the others with every model, score.

    The seeded :func:`prismap.sim.street_scene` rendered along :func:`prismap.sim.street_trajectory` by
    :func:`prismap.sim.kitti_camera`. Full size: half resolution (621x188), 16 frames 1 m apart and 32 more
    characterisation frames from the positions between them (:func:`prismap.sim.street_trajectory_between`),
    0.2 m voxels, every 2nd pixel, rays to 40 m, projective integration. ``quick``: 310x94, 8 + 4 frames,
    0.4 m voxels, every pixel, rays to 30 m. Arguments and result: see :func:`run_rendered_world`.
    """
    return run_rendered_world("street3d", out_dir, n_frames=n_frames, voxel_size_m=voxel_size_m, seed=seed,
                              quick=quick, matchers=matchers, models=models, characterise_every=characterise_every,
                              max_range_m=max_range_m, grid_offset=grid_offset,
                              between_frames=between_frames, class_pass_through=class_pass_through)


def run_rendered_world(world, out_dir, *, n_frames=None, voxel_size_m=None, seed=0, quick=False, matchers=MATCHERS,
                       models=MODELS_3D, characterise_every=4, max_range_m=None, grid_offset=0.5,
                       between_frames=None, class_pass_through=False):
    """The 3-D experiment on the world named ``world`` (a key of :data:`WORLDS`).

    Frames ``0, k, 2k, ...`` (``k = characterise_every``) of the drive, and the world's frames between the
    drive's positions (``between_frames``), characterise each matcher
    (:func:`prismap.characterise.characterise_matcher`: thesis tables 3.1-3.3 with coverage, bad-1px and
    bad-2px, and the error figures, in ``MATCHER/characterisation/``); the other frames are matched once
    (``MATCHER/disparity/``, uint16 PNG, value / 256 px) and mapped by :func:`prismap.pipeline.map_sequence`
    with every model of ``models``, using that matcher's error model. Maps are scored on the voxels a
    perfect sensor observed from the mapping frames within ``max_range_m``; ``p0`` is their occupancy ratio.
    The targets include the log-likelihood of the mapping frames' errors under each error model
    (:func:`mapped_log_likelihood`), the test of a characterisation on errors it never saw; a last section
    measures how each matcher's errors repeat in consecutive mapping frames (:func:`mapped_error_correlation`),
    which the maps' fusion assumes they do not.

    Parameters
    ----------
    world : str
        ``"scene3d"`` or ``"street3d"``.
    out_dir : str or Path
        A rerun with the same settings reuses every finished step (sequence, characterisations,
        disparities, cells).
    n_frames : int or None
        Frames rendered; None = the world's size.
    voxel_size_m : float or None, metres
    seed : int
        Scene layout, trajectory and image noise.
    quick : bool
        The world's small size (tests, quick demo).
    matchers, models : sequence of str
        Subsets of :data:`MATCHERS` and :data:`prismap.experiment.MODELS`.
    characterise_every : int >= 2
    between_frames : int >= 0 or None
        Extra characterisation frames rendered along the world's ``between_trajectory`` (their images
        continue the drive's noise stream, so the drive's frames do not change); None = the world's size.
    max_range_m : float or None, metres
        Distance along a ray beyond which maps are not updated (and the ground truth not observed);
        None = the world's size.
    class_pass_through : bool
        Conditioned PRISM takes one pass-through ratio per error class (``class_pass_through``, measured on
        the matcher's classes of its own disparity of the drive's characterisation frames) instead of the
        whole one. Off by default: it improved every conditioned PRISM score in the room but cost the
        street's semiglobal log-loss its 10 % gain over plain PRISM (README, "Pass-through").
    grid_offset : float in [0, 1), voxels
        The scene and trajectory are translated by this many voxels on every axis. The worlds' floors,
        walls and box faces lie at round coordinates; at offset 0 they coincide with voxel faces, and a
        closed box then marks the voxel beyond its face as occupied although only its boundary plane
        is solid (the whole layer above the floor, for instance): ground truth no sensor could
        confirm. The default half voxel puts those planes through voxel middles.

    Returns
    -------
    ExperimentResult
    """
    from prismap import sim
    from prismap.io import read_sequence, write_sequence

    settings = scene3d_settings(world=world, n_frames=n_frames, voxel_size_m=voxel_size_m, seed=seed, quick=quick,
                                matchers=matchers, characterise_every=characterise_every, max_range_m=max_range_m,
                                grid_offset=grid_offset, between_frames=between_frames,
                                class_pass_through=class_pass_through)
    spec = WORLDS[world]()
    n_drive, n_between = settings["n_frames"], settings["between_frames"]
    char_index, map_index = split_frames(n_drive, settings["characterise_every"])
    if len(map_index) == 0:
        raise PrismapInputError(f"{n_drive} frames leave none to map after characterisation")
    poses = spec.trajectory(n_drive, seed)
    if n_between:
        poses = np.concatenate([poses, spec.between_trajectory(n_drive, n_between, seed)])
    out = claim_out_dir(out_dir, settings)
    voxel = settings["voxel_size_m"]
    camera = spec.camera(settings["image_scale"])
    base = spec.scene(seed)
    shift = settings["grid_offset_m"]
    scene = sim.Scene3D(base.box_lo + shift, base.box_hi + shift, base.box_texture, base.box_texel_m, base.box_tint,
                        name=base.name)
    poses[:, :3, 3] += shift
    frames = list(progress(scene.frames(camera, poses, seed=seed), total=len(poses), desc="render", unit="frame"))
    drive_char_frames = [frames[i] for i in char_index]
    char_frames = drive_char_frames + frames[n_drive:]
    map_frames = [frames[i] for i in map_index]
    sequence_dir = out / "sequence"
    if not (sequence_dir / "occupancy.npz").is_file():  # written last: its presence means the sequence is whole
        truth = scene.ground_truth(map_frames, voxel, max_depth_m=settings["max_range_m"])
        write_sequence(map_frames, sequence_dir, occupancy=truth)
    sequence = read_sequence(sequence_dir)
    truth = sequence.ground_truth
    p0 = prior_of(truth)
    largest = max(float(np.nanmax(f.disparity_gt)) for f in frames)
    model_params = _derived_model_params(settings, scene, drive_char_frames)
    cell_settings = dict(settings, derived_model_params=model_params)

    results, artifacts, error_models, mapped_likelihoods, correlations = [], [], {}, {}, {}
    layer = math.floor((spec.slice_height_m + shift) / voxel)
    for matcher_name in settings["matchers"]:
        matcher = _matcher(matcher_name, largest)
        error_model, char_artifacts = _characterise(out / matcher_name / "characterisation", char_frames, matcher,
                                                    f"{scene.name} frames {char_index.tolist()}"
                                                    + (f" and {n_between} between" if n_between else ""))
        error_models[matcher_name] = error_model
        disparity_dir = _match(out / matcher_name / "disparity", map_frames, matcher)
        mapped_likelihoods[matcher_name] = mapped_log_likelihood(error_model, map_frames, disparity_dir)
        correlations[matcher_name] = mapped_error_correlation(sequence, disparity_dir, sequence.camera)
        matcher_params = model_params
        if settings.get("class_pass_through"):
            matcher_params = _class_model_params(model_params, settings, scene, drive_char_frames, error_model,
                                                 _match(out / matcher_name / "characterisation_disparity",
                                                        drive_char_frames, matcher))
        build_map = _mapper(sequence, disparity_dir, matcher_name, error_model, p0, matcher_params, settings)
        cells, maps = run_cells(out, matcher_name, models, build_map, truth,
                                dict(cell_settings, derived_model_params=matcher_params))
        results += cells
        artifacts += char_artifacts
        artifacts += draw_figures(out, matcher_name, cells, maps, truth, layer=layer,
                                  where=f"z = {spec.slice_height_m} m")
    setup = (f"{spec.description} ({scene.name}, {camera.width}x{camera.height}, f = {camera.focal_px:g} px, "
             f"b = {camera.baseline_m:g} m), {len(char_index)} characterisation frames ({char_index.tolist()}) and "
             f"{len(map_index)} other mapping frames of a drive"
             + (f", {n_between} more characterisation frames from positions between the drive's" if n_between else "")
             + f", {voxel} m voxels, pixel step {settings['subsample']}, "
             f"{settings['mode']} integration, rays to {settings['max_range_m']} m; scene and trajectory shifted by "
             f"{shift:g} m on each axis so that floors and walls cut voxels through the middle.")
    models_note = ("Each matcher's PRISM, convolution and Andert models use the error model characterised on the "
                   "characterisation frames: \"plain\" its whole-image mixture for every pixel, \"conditioned\" the "
                   "mixture of each pixel's error class (from the features of the mapped frame's own disparity and "
                   "image)"
                   + ("; \"map prior\": PRISM with each cell's prior the map's current probability of its voxel "
                      "instead of p0 (`prior=\"map\"`, ray mode only), a variant of conditioned PRISM, so the targets "
                      "do not count it as a rival" if any(m.endswith(MAP_PRIOR_SUFFIX) for m in models) else "")
                   + "; time = mapping wall time (PRISM's tables and the features included).")
    from prismap.sim import SOLID_DEPTH_QUANTILE

    notes = (setup, f"p0 = {p0:.4f}: the occupancy ratio of the voxels a perfect sensor observed (the scored voxels). "
             f"PRISM's pass_through = {model_params['prism']['pass_through']:.4f}: how often the drive's "
             "characterisation frames' noise-free rays cross an occupied voxel before their surface (beyond its voxel overhang) "
             "without stopping (`Scene3D.pass_through_ratio`). "
             f"PRISM's solid_depth_m = {model_params['prism']['solid_depth_m']:.3f} m: the depth of solid behind "
             f"all but {SOLID_DEPTH_QUANTILE:.0%} of those rays' hits (`Scene3D.solid_depth`)."
             + (" Conditioned PRISM takes the pass-through ratio of each error class's rays (`class_pass_through`, "
                "the classes of the matcher's disparity of those frames; see each cell's settings): passes crowd at "
                "the silhouettes of solids, where the classes by distance to a disparity edge put them."
                if settings.get("class_pass_through") else ""),
             models_note, _classes_note(error_models, mapped_likelihoods))
    targets = measure_targets(world, results, error_models, mapped_likelihoods)
    paths = write_results(results, out, title=spec.title, notes=notes, settings=settings,
                          sections=(format_targets(targets), format_error_correlation(correlations)),
                          extra={"targets": [t.to_dict() for t in targets],
                                 "error_correlation": {name: c.to_dict() for name, c in correlations.items()}})
    artifacts = [(paths["table"], f"Scores of every matcher x sensor model: {spec.title} (Markdown)."),
                 (paths["json"], "The same scores with reliability bins and histograms (JSON).")] + artifacts
    return ExperimentResult(world, tuple(results), p0, settings, tuple(artifacts))


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
        # the class search samples every frame: classes chosen on a subset of the street's frames predicted the
        # mapping frames' errors worse (README, conditioned error models)
        characterisation = characterise_matcher(frames, matcher, dataset=dataset, search_frames=len(frames))
        paths = write_characterisation(characterisation, out_dir)
    name = matcher.name
    artifacts = [
        (paths["table"], f"{name}: fitted error mixtures G = 1..4 with AIC/BIC, coverage, bad-1px, bad-2px "
                         "(thesis tables 3.1-3.3 layout)."),
        (paths["figure"], f"{name}: disparity error histogram with the fitted mixtures."),
        (paths["figure_wide"], f"{name}: the error tails on a log scale."),
        (paths["model"], f"{name}: the error model (JSON) every model of this matcher used."),
    ]
    return load_error_model(paths["model"]), artifacts


def _classes_note(error_models, mapped_likelihoods):
    """One sentence per matcher: its error classes (the per-class view is in its characterisation table)."""
    lines = []
    for name, model in error_models.items():
        chosen = model.class_selection
        features = ", ".join(model.classes.features) or "none"
        mapped = mapped_likelihoods[name]
        lines.append(f"{name}: {model.n_classes} error class(es) by {features} (see {name}/characterisation/table.md); "
                     "held-out log-likelihood "
                     f"{chosen.get('conditioned_nats_per_error', float('nan')):.4f} nats/error conditioned, "
                     f"{chosen.get('plain_nats_per_error', float('nan')):.4f} plain (characterisation folds), "
                     f"{mapped['conditioned_nats_per_error']:.4f} and {mapped['plain_nats_per_error']:.4f} on the "
                     "mapping frames' errors.")
    return " ".join(lines)


def mapped_log_likelihood(error_model, frames, disparity_dir):
    """Mean log-density of the mapping frames' disparity errors under the conditioned and the plain model.

    The truly held-out test of a characterisation: errors of frames it never saw, each pixel under its own
    class's mixture (conditioned) and under the whole-image mixture (plain), on the same pixels (those
    with a class).

    Parameters
    ----------
    error_model : ErrorModel
    frames : sequence of StereoFrame
        The mapping frames, with ``disparity_gt`` (pixels).
    disparity_dir : Path
        The matcher's disparity of frame ``i`` as ``{i:06d}.png`` (see :func:`_match`).

    Returns
    -------
    dict: ``conditioned_nats_per_error``, ``plain_nats_per_error`` (nats per error) and ``n_errors``.
    """
    mixtures = error_model.class_mixtures if error_model.conditioned else (error_model.mixture,)
    conditioned = plain = 0.0
    count = 0
    for frame, disparity in zip(frames, _disparities(disparity_dir, len(frames))):
        if error_model.conditioned:
            label = error_model.classify_frame(frame.left, frame.right, disparity)
        else:
            label = np.where(np.isfinite(disparity), 0, -1)
        errors = np.asarray(frame.disparity_gt, dtype=np.float64) - disparity
        keep = (label >= 0) & np.isfinite(errors)
        errors, label = errors[keep], label[keep]
        plain += float(error_model.mixture.logpdf(errors).sum())
        conditioned += sum(float(mixture.logpdf(errors[label == k]).sum()) for k, mixture in enumerate(mixtures))
        count += errors.size
    if count == 0:
        raise PrismapInputError("no mapping frame has a pixel with both a computed and a true disparity")
    return {"conditioned_nats_per_error": conditioned / count, "plain_nats_per_error": plain / count,
            "n_errors": count}


def mapped_error_correlation(frames, disparity_dir, camera):
    """How the matcher's errors at one surface point repeat in consecutive mapping frames: the independence
    the map's fusion assumes (:func:`prismap.characterise.frame_error_correlation`, ``lag=1``).

    Parameters
    ----------
    frames : Sequence or sequence of StereoFrame
        The mapping frames in drive order as mapped (the written sequence), with ``disparity_gt`` (pixels) and
        ``T_world_cam``.
    disparity_dir : Path
        The matcher's disparity of frame ``i`` as ``{i:06d}.png`` (see :func:`_match`).
    camera : StereoCamera

    Returns
    -------
    prismap.characterise.ErrorCorrelation
    """
    from prismap.characterise import frame_error_correlation

    return frame_error_correlation(frames, list(_disparities(disparity_dir, len(frames))), camera, lag=1)


def format_error_correlation(correlations):
    """Markdown section: each matcher's :func:`mapped_error_correlation` and what it means for the fused maps."""
    lines = ["## Errors repeated across frames", "",
             "Each mapping frame's pixels placed at their true depth and paired with the pixel of the next mapping "
             "frame that sees the same surface point (`characterise.frame_error_correlation`). The map adds frames' "
             "evidence as if their errors were independent (docs/SENSOR_MODELS.md, section 3): a correlation above 0 "
             "and gross errors that repeat more often than they strike are evidence counted more than once, most "
             "where a model is sure of the surface.", "",
             r"| matcher | pairs | correlation (\|e\| <= 3 px) | gross (\|e\| > 1 px) | gross after gross |",
             "|---|---|---|---|---|"]
    lines += [f"| {name} | {c.n_pairs} | {c.correlation:.3f} | {c.gross_rate:.2%} | {c.gross_repeat:.2%} |"
              for name, c in correlations.items()]
    return "\n".join(lines + [""])


def _disparities(disparity_dir, n_frames):
    """The matcher's disparity (pixels, NaN = invalid) of frames ``0 .. n_frames - 1`` from ``disparity_dir``."""
    from prismap.io import read_kitti_disparity

    for index in range(n_frames):
        yield read_kitti_disparity(Path(disparity_dir) / f"{index:06d}.png")


def _match(out_dir, frames, matcher):
    """Write the matcher's disparity of each of ``frames`` as ``NNNNNN.png`` (uint16, value / 256 px, 0 = invalid)."""
    from prismap.io import write_disparity_png

    out_dir = Path(out_dir)
    for index, frame in enumerate(progress(frames, total=len(frames), desc=f"match {matcher.name}", unit="frame")):
        path = out_dir / f"{index:06d}.png"
        if not path.is_file():
            write_disparity_png(path, matcher.compute(frame.left, frame.right), f"{matcher.name} disparity of frame {index}")
    return out_dir


def _derived_model_params(settings, scene, char_frames):
    """The run's model parameters, PRISM's ``pass_through`` and ``solid_depth_m`` measured on ``char_frames``
    unless the settings set them."""
    params = {name: dict(values) for name, values in settings["model_params"].items()}
    prism = params.setdefault("prism", {})
    if "pass_through" not in prism:
        prism["pass_through"] = scene.pass_through_ratio(char_frames, settings["voxel_size_m"],
                                                         max_depth_m=settings["max_range_m"],
                                                         subsample=settings["subsample"])
    if "solid_depth_m" not in prism:
        prism["solid_depth_m"] = scene.solid_depth(char_frames, settings["voxel_size_m"],
                                                   max_depth_m=settings["max_range_m"], subsample=settings["subsample"])
    return params


def _class_model_params(model_params, settings, scene, char_frames, error_model, disparity_dir):
    """``model_params`` with PRISM's ``class_pass_through`` for a conditioned ``error_model`` (unless the settings
    set it): the pass-through ratio of the rays of each class of the matcher's disparity of ``char_frames``
    (``disparity_dir``, see :func:`_match`), measured as the whole ratio is."""
    from prismap.sensor_models import CLASS_PASS_THROUGH

    prism = model_params["prism"]
    if not error_model.conditioned or CLASS_PASS_THROUGH in prism:
        return model_params
    labels = [error_model.classify_frame(frame.left, frame.right, disparity)
              for frame, disparity in zip(char_frames, _disparities(disparity_dir, len(char_frames)))]
    ratios = scene.pass_through_ratio(char_frames, settings["voxel_size_m"], max_depth_m=settings["max_range_m"],
                                      subsample=settings["subsample"], ray_classes=labels,
                                      n_classes=error_model.n_classes)
    return dict(model_params, prism=dict(prism, **{CLASS_PASS_THROUGH: [float(m) for m in ratios]}))


def _mapper(sequence, disparity_dir, matcher_name, error_model, p0, model_params, settings):
    """``build_map(cell_model)``: the pipeline's map of the mapping frames from the matcher's disparities.

    ``model_params``: model name -> its parameters (the settings' with what the run derived).

    ``cell_model`` is a model name, plain, or with :data:`~prismap.experiment.CONDITIONED_SUFFIX`: conditioned
    on the error model's classes (plain when the characterisation chose none; PRISM then takes
    ``class_pass_through`` when ``model_params`` has it), then optionally
    :data:`~prismap.experiment.MAP_PRIOR_SUFFIX`: PRISM with the map as prior.
    """
    from prismap.pipeline import MappingConfig, map_sequence
    from prismap.sensor_models import CLASS_PASS_THROUGH

    def build_map(cell_model):
        model_name, conditioned = split_variant(cell_model)
        params = {**model_params.get(model_name, {}), **variant_params(cell_model)}
        if params.get("prior") == "map":  # PRISM's solid depth is a p0-prior model only
            params.pop("solid_depth_m", None)
        if not conditioned:  # one pass-through per error class is for conditioned PRISM
            params.pop(CLASS_PASS_THROUGH, None)
        config = MappingConfig(model=model_name, model_params=params,
                               voxel_size_m=settings["voxel_size_m"], p0=p0, error_model=error_model,
                               conditioned=None if conditioned else False, matcher=matcher_name,
                               disparity_source=str(Path(disparity_dir).resolve()),
                               max_range_m=settings["max_range_m"], subsample=settings["subsample"], mode=settings["mode"])
        return map_sequence(sequence, config)

    return build_map
