"""The 3-D experiments: rendered stereo pairs of a box world (the indoor room, the street, the avenue), each matcher
characterised on frames it then does not map, every sensor model scored against the exact ground truth."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from prismap.characterise import fusion_from_block
from prismap.errors import PrismapInputError
from prismap.experiment._cells import ExperimentResult, claim_out_dir, draw_figures, run_cells
from prismap.experiment._fusion import compare_run_fusions, fit_run_fusion, format_fusion_section
from prismap.experiment._report3d import (
    format_error_correlation,
    mapped_error_correlation,
    mapped_log_likelihood,
    run_notes,
)
from prismap.experiment._results import (
    MODELS_3D,
    prior_of,
    write_results,
)
from prismap.experiment._steps3d import (
    characterise_frames,
    class_model_params,
    derived_model_params,
    mapper,
    match_frames,
    matcher_for,
)
from prismap.experiment._targets import format_targets, measure_targets
from prismap.experiment._worlds3d import MATCHERS, WORLDS, render_world, scene3d_settings, split_frames


def run_scene3d(out_dir: str | os.PathLike[str], **options: Any) -> ExperimentResult:
    """Characterise each matcher on some frames of the indoor room, map the others with every model, score.

    The seeded :func:`prismap.sim.indoor_scene` rendered along :func:`prismap.sim.indoor_trajectory` by the
    New Tsukuba camera. Full size: 640x480, 40 frames, 0.1 m voxels, every 2nd pixel, rays to 10 m.
    ``quick``: 160x120, 16 frames, every pixel: the smallest size found where PRISM beats ideal and
    hit/miss with SGBM on Brier, log-loss and occupied-called-free. Ray mode, so
    ``models=MODELS_3D_MAP_PRIOR`` adds conditioned PRISM with the map as prior. Keyword arguments and
    result: :func:`run_rendered_world`.
    """
    return run_rendered_world("scene3d", out_dir, **options)


def run_street3d(out_dir: str | os.PathLike[str], **options: Any) -> ExperimentResult:
    """Characterise each matcher on some frames of the street drive, map the others with every model, score.

    The seeded :func:`prismap.sim.street_scene` rendered along :func:`prismap.sim.street_trajectory` by
    :func:`prismap.sim.kitti_camera`. Full size: half resolution (621x188), 16 frames 1 m apart and 32 more
    characterisation frames from the positions between them (:func:`prismap.sim.street_trajectory_between`),
    0.2 m voxels, every 2nd pixel, rays to 40 m, projective integration. ``quick``: 310x94, 8 + 4 frames,
    0.4 m voxels, every pixel, rays to 30 m. Keyword arguments and result: :func:`run_rendered_world`.
    """
    return run_rendered_world("street3d", out_dir, **options)


def run_rendered_world(
    world: str,
    out_dir: str | os.PathLike[str],
    *,
    n_frames: int | None = None,
    voxel_size_m: float | None = None,
    seed: int = 0,
    quick: bool = False,
    matchers: Sequence[str] = MATCHERS,
    models: Sequence[str] = MODELS_3D,
    characterise_every: int = 4,
    max_range_m: float | None = None,
    grid_offset: float = 0.5,
    between_frames: int | None = None,
    class_pass_through: bool = False,
) -> ExperimentResult:
    """The 3-D experiment on the world named ``world`` (a key of :data:`WORLDS`).

    Frames ``0, k, 2k, ...`` (``k = characterise_every``) of the drive, and the world's frames between the
    drive's positions (``between_frames``), characterise each matcher
    (:func:`prismap.characterise.characterise_matcher`: thesis tables 3.1-3.3 with coverage, bad-1px and
    bad-2px, and the error figures, in ``MATCHER/characterisation/``); the other frames are matched once
    (``MATCHER/disparity/``, uint16 PNG, value / 256 px) and mapped by :func:`prismap.pipeline.map_sequence`
    with every model of ``models``, using that matcher's error model. Maps are scored on the voxels a
    perfect sensor observed from the mapping frames within ``max_range_m``; ``p0`` is their occupancy ratio.
    The targets include the log-likelihood of the mapping frames' errors under each error model
    (:func:`mapped_log_likelihood`), the test of a characterisation on errors it never saw; a section
    measures how each matcher's errors repeat in consecutive mapping frames (:func:`mapped_error_correlation`).
    Each matcher's failure rate and persistence are fitted on the characterisation frames before mapping
    (:func:`~prismap.experiment._fusion.fit_run_fusion`), so the error-model maps take ``prismap map``'s default
    reading, a failure for good (:class:`~prismap.grid.FailureMixture`); a last section reads them also under
    independent fusion, the persistent-failure state and the clamp at the one-view bound
    (:func:`~prismap.experiment._fusion.compare_run_fusions`).

    Parameters
    ----------
    world : str
        A key of :data:`WORLDS`: ``"scene3d"``, ``"street3d"`` or ``"avenue3d"``.
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
    from prismap.io import read_sequence, write_sequence

    settings = scene3d_settings(
        world=world,
        n_frames=n_frames,
        voxel_size_m=voxel_size_m,
        seed=seed,
        quick=quick,
        matchers=matchers,
        characterise_every=characterise_every,
        max_range_m=max_range_m,
        grid_offset=grid_offset,
        between_frames=between_frames,
        class_pass_through=class_pass_through,
    )
    spec = WORLDS[world]()
    n_drive, n_between = settings["n_frames"], settings["between_frames"]
    char_index, map_index = split_frames(n_drive, settings["characterise_every"])
    if len(map_index) == 0:
        raise PrismapInputError(f"{n_drive} frames leave none to map after characterisation")
    spec.trajectory(n_drive, seed)  # a drive the world cannot hold is refused before --out is claimed
    out = claim_out_dir(out_dir, settings)
    voxel = settings["voxel_size_m"]
    scene, camera, drive_char_frames, char_frames, map_frames = render_world(settings)
    shift = settings["grid_offset_m"]
    sequence_dir = out / "sequence"
    if not (sequence_dir / "occupancy.npz").is_file():  # written last: its presence means the sequence is whole
        truth = scene.ground_truth(map_frames, voxel, max_depth_m=settings["max_range_m"])
        write_sequence(map_frames, sequence_dir, occupancy=truth)
    sequence = read_sequence(sequence_dir)
    truth = sequence.ground_truth
    p0 = prior_of(truth)
    largest = max(float(np.nanmax(f.disparity_gt)) for f in char_frames + map_frames)
    model_params = derived_model_params(settings, scene, drive_char_frames)
    cell_settings = dict(settings, derived_model_params=model_params)

    results, artifacts, error_models, mapped_likelihoods, correlations = [], [], {}, {}, {}
    fusion_blocks, fusion_rows = {}, []
    layer = math.floor((spec.slice_height_m + shift) / voxel)
    for matcher_name in settings["matchers"]:
        matcher = matcher_for(matcher_name, largest)
        error_model, char_artifacts = characterise_frames(
            out / matcher_name / "characterisation",
            char_frames,
            matcher,
            f"{scene.name} frames {char_index.tolist()}" + (f" and {n_between} between" if n_between else ""),
        )
        error_model = fit_run_fusion(out / matcher_name, char_frames, matcher, camera, error_model)
        error_models[matcher_name] = error_model
        fusion_blocks[matcher_name] = error_model.fusion
        disparity_dir = match_frames(out / matcher_name / "disparity", map_frames, matcher)
        mapped_likelihoods[matcher_name] = mapped_log_likelihood(error_model, map_frames, disparity_dir)
        correlations[matcher_name] = mapped_error_correlation(sequence, disparity_dir, sequence.camera)
        matcher_params = model_params
        if settings.get("class_pass_through"):
            matcher_params = class_model_params(
                model_params,
                settings,
                scene,
                drive_char_frames,
                error_model,
                match_frames(out / matcher_name / "characterisation_disparity", drive_char_frames, matcher),
            )
        build_map = mapper(
            sequence,
            disparity_dir,
            matcher_name,
            error_model,
            p0,
            matcher_params,
            settings,
            error_model_path=out / matcher_name / "characterisation" / "error_model.json",
        )
        cells, maps = run_cells(
            out, matcher_name, models, build_map, truth, dict(cell_settings, derived_model_params=matcher_params)
        )
        results += cells
        fusion_rows += compare_run_fusions(matcher_name, error_model, maps, truth)
        artifacts += char_artifacts
        artifacts += draw_figures(
            out, matcher_name, cells, maps, truth, layer=layer, where=f"z = {spec.slice_height_m} m"
        )
    notes = run_notes(
        spec, scene, camera, settings, char_index, map_index, p0, model_params, models, error_models, mapped_likelihoods
    )
    targets = measure_targets(world, results, error_models, mapped_likelihoods)
    failures = {name: fusion_from_block(block) for name, block in fusion_blocks.items()}
    paths = write_results(
        results,
        out,
        title=spec.title,
        notes=notes,
        settings=settings,
        sections=(
            format_targets(targets),
            format_error_correlation(correlations),
            format_fusion_section(fusion_rows, failures),
        ),
        extra={
            "targets": [t.to_dict() for t in targets],
            "error_correlation": {name: c.to_dict() for name, c in correlations.items()},
            "fusion": {"blocks": fusion_blocks, "rows": [r.to_dict() for r in fusion_rows]},
        },
    )
    artifacts = [
        (paths["table"], f"Scores of every matcher x sensor model: {spec.title} (Markdown)."),
        (paths["json"], "The same scores with reliability bins and histograms (JSON)."),
    ] + artifacts
    return ExperimentResult(world, tuple(results), p0, settings, tuple(artifacts))
