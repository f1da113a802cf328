"""The prose and sections of a 3-D experiment's report: the run's notes, the error classes, how well each error
model predicts the mapping frames' errors, and how the errors repeat from frame to frame."""

import numpy as np

from prismap.errors import PrismapInputError
from prismap.experiment._results import MAP_PRIOR_SUFFIX
from prismap.experiment._steps3d import read_disparities


def classes_note(error_models, mapped_likelihoods):
    """One sentence per matcher: its error classes (the per-class view is in its characterisation table)."""
    lines = []
    for name, model in error_models.items():
        chosen = model.class_selection
        features = ", ".join(model.classes.features) or "none"
        mapped = mapped_likelihoods[name]
        lines.append(
            f"{name}: {model.n_classes} error class(es) by {features} (see {name}/characterisation/table.md); "
            "held-out log-likelihood "
            f"{chosen.get('conditioned_nats_per_error', float('nan')):.4f} nats/error conditioned, "
            f"{chosen.get('plain_nats_per_error', float('nan')):.4f} plain (characterisation folds), "
            f"{mapped['conditioned_nats_per_error']:.4f} and {mapped['plain_nats_per_error']:.4f} on the "
            "mapping frames' errors."
        )
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
        The matcher's disparity of frame ``i`` as ``{i:06d}.png`` (see :func:`match_frames`).

    Returns
    -------
    dict: ``conditioned_nats_per_error``, ``plain_nats_per_error`` (nats per error) and ``n_errors``.
    """
    mixtures = error_model.class_mixtures if error_model.conditioned else (error_model.mixture,)
    conditioned = plain = 0.0
    count = 0
    for frame, disparity in zip(frames, read_disparities(disparity_dir, len(frames))):
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
    return {"conditioned_nats_per_error": conditioned / count, "plain_nats_per_error": plain / count, "n_errors": count}


def mapped_error_correlation(frames, disparity_dir, camera):
    """How the matcher's errors at one surface point repeat in consecutive mapping frames: the independence
    the map's fusion assumes (:func:`prismap.characterise.frame_error_correlation`, ``lag=1``).

    Parameters
    ----------
    frames : Sequence or sequence of StereoFrame
        The mapping frames in drive order as mapped (the written sequence), with ``disparity_gt`` (pixels) and
        ``T_world_cam``.
    disparity_dir : Path
        The matcher's disparity of frame ``i`` as ``{i:06d}.png`` (see :func:`match_frames`).
    camera : StereoCamera

    Returns
    -------
    prismap.characterise.ErrorCorrelation
    """
    from prismap.characterise import frame_error_correlation

    return frame_error_correlation(frames, list(read_disparities(disparity_dir, len(frames))), camera, lag=1)


def format_error_correlation(correlations):
    """Markdown section: each matcher's :func:`mapped_error_correlation` and what it means for the fused maps."""
    lines = [
        "## Errors repeated across frames",
        "",
        "Each mapping frame's pixels placed at their true depth and paired with the pixel of the next mapping "
        "frame that sees the same surface point (`characterise.frame_error_correlation`). The map adds frames' "
        "evidence as if their errors were independent (docs/SENSOR_MODELS.md, section 3): a correlation above 0 "
        "and gross errors that repeat more often than they strike are evidence counted more than once, most "
        "where a model is sure of the surface.",
        "",
        r"| matcher | pairs | correlation (\|e\| <= 3 px) | gross (\|e\| > 1 px) | gross after gross |",
        "|---|---|---|---|---|",
    ]
    lines += [
        f"| {name} | {c.n_pairs} | {c.correlation:.3f} | {c.gross_rate:.2%} | {c.gross_repeat:.2%} |"
        for name, c in correlations.items()
    ]
    return "\n".join(lines + [""])


def run_notes(
    spec, scene, camera, settings, char_index, map_index, p0, model_params, models, error_models, mapped_likelihoods
):
    """The notes under a 3-D run's results table: its setup, the prior and PRISM's measured parameters, what
    the models' variants are, and each matcher's error classes (:func:`classes_note`).

    Parameters
    ----------
    spec : RenderedWorld
    scene : prismap.sim.Scene3D
        The world as mapped (shifted by the grid offset).
    camera : StereoCamera
    settings : dict
        The run's settings (:func:`prismap.experiment._worlds3d.scene3d_settings`).
    char_index, map_index : (N,) int
        The drive's characterisation and mapping frames (:func:`prismap.experiment.split_frames`).
    p0 : float
        The scored voxels' occupancy ratio.
    model_params : dict
        Model name -> its parameters, PRISM's ``pass_through`` and ``solid_depth_m`` measured.
    models : sequence of str
        The cells' model names.
    error_models, mapped_likelihoods : dict
        Matcher name -> its error model and its :func:`mapped_log_likelihood`.

    Returns
    -------
    tuple of str
    """
    from prismap.sim import SOLID_DEPTH_QUANTILE

    n_between, voxel, shift = settings["between_frames"], settings["voxel_size_m"], settings["grid_offset_m"]
    setup = (
        f"{spec.description} ({scene.name}, {camera.width}x{camera.height}, f = {camera.focal_px:g} px, "
        f"b = {camera.baseline_m:g} m), {len(char_index)} characterisation frames ({char_index.tolist()}) and "
        f"{len(map_index)} other mapping frames of a drive"
        + (f", {n_between} more characterisation frames from positions between the drive's" if n_between else "")
        + f", {voxel} m voxels, pixel step {settings['subsample']}, "
        f"{settings['mode']} integration, rays to {settings['max_range_m']} m; scene and trajectory shifted by "
        f"{shift:g} m on each axis so that floors and walls cut voxels through the middle."
    )
    models_note = (
        "Each matcher's PRISM, convolution and Andert models use the error model characterised on the "
        'characterisation frames: "plain" its whole-image mixture for every pixel, "conditioned" the '
        "mixture of each pixel's error class (from the features of the mapped frame's own disparity and "
        "image)"
        + (
            "; \"map prior\": PRISM with each cell's prior the map's current probability of its voxel "
            'instead of p0 (`prior="map"`, ray mode only), a variant of conditioned PRISM, so the targets '
            "do not count it as a rival"
            if any(m.endswith(MAP_PRIOR_SUFFIX) for m in models)
            else ""
        )
        + "; time = mapping wall time (PRISM's tables and the features included)."
    )
    return (
        setup,
        f"p0 = {p0:.4f}: the occupancy ratio of the voxels a perfect sensor observed (the scored voxels). "
        f"PRISM's pass_through = {model_params['prism']['pass_through']:.4f}: how often the drive's "
        "characterisation frames' noise-free rays cross an occupied voxel before their surface (beyond its voxel overhang) "
        "without stopping (`Scene3D.pass_through_ratio`). "
        f"PRISM's solid_depth_m = {model_params['prism']['solid_depth_m']:.3f} m: the depth of solid behind "
        f"all but {SOLID_DEPTH_QUANTILE:.0%} of those rays' hits (`Scene3D.solid_depth`)."
        + (
            " Conditioned PRISM takes the pass-through ratio of each error class's rays (`class_pass_through`, "
            "the classes of the matcher's disparity of those frames; see each cell's settings): passes crowd at "
            "the silhouettes of solids, where the classes by distance to a disparity edge put them."
            if settings.get("class_pass_through")
            else ""
        ),
        models_note,
        classes_note(error_models, mapped_likelihoods),
    )
