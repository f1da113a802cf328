"""Frames in, map out: a sequence integrated frame by frame, here or on Dask workers, resumably."""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from prismap._files import exclusive_lock
from prismap._progress import progress as progress_bar
from prismap._validate import check_integer
from prismap.camera import integrate_disparity
from prismap.errors import PrismapInputError
from prismap.grid import KEY_LIMIT, OccupancyMap, key_limit_m, key_range_text
from prismap.io import BagSequence, Sequence, read_kitti_disparity, read_sequence
from prismap.pipeline._checkpoint import open_checkpoint, run_fingerprint, save_checkpoint
from prismap.pipeline._config import DISPARITY_FROM_MATCHER, DISPARITY_FROM_SEQUENCE, MappingConfig
from prismap.pipeline._prefetch import Prefetch
from prismap.sensor_models import ConditionedModel, InverseSensorModel, flush_table_stores
from prismap.stereo import make_matcher


def open_sequence(sequence):
    """A :class:`~prismap.io.Sequence` (or an opened :class:`~prismap.io.BagSequence`) from itself or its directory path."""
    return sequence if isinstance(sequence, (Sequence, BagSequence)) else read_sequence(sequence)


def new_map(config, ndim=3):
    """An empty map on the config's grid (voxel size, prior) and fusion; no clamping, so chunks merge exactly."""
    return OccupancyMap(config.voxel_size_m, p0=config.p0, ndim=ndim, fusion=config.map_reading)


class DisparitySource:
    """The disparity image of each frame of a sequence, as ``config.disparity_source`` says, and its pixels' classes.

    Parameters
    ----------
    sequence : Sequence
    config : MappingConfig
    model : InverseSensorModel or None
        The run's sensor model, ``config.sensor_model(sequence.camera)`` (None builds it): a conditioned one
        (:class:`~prismap.sensor_models.ConditionedModel`) needs each pixel's error class.

    Raises
    ------
    PrismapInputError
        At construction, before any frame is read: a bad matcher or disparity directory, or a conditioned
        error model whose features this run cannot compute (:meth:`ErrorModel.check_usable`: another
        matcher; the left-right disagreement without the matcher's left-right check, or from precomputed
        disparities, which have none).
    """

    def __init__(
        self, sequence: Sequence | BagSequence, config: MappingConfig, *, model: InverseSensorModel | None = None
    ) -> None:
        self.sequence = sequence
        self.kind = config.disparity_source
        self.matcher = None
        if self.kind == DISPARITY_FROM_MATCHER:
            try:
                self.matcher = make_matcher(config.matcher, **config.matcher_options)
            except TypeError as exc:
                raise PrismapInputError(
                    f"matcher {config.matcher!r}: bad parameter(s) {config.matcher_options}: {exc}"
                ) from None
        elif self.kind != DISPARITY_FROM_SEQUENCE and not Path(self.kind).is_dir():
            raise PrismapInputError(f"disparity directory {self.kind}: not found")
        self.error_model = None
        if model is None:
            model = config.sensor_model(sequence.camera)
        if isinstance(model, ConditionedModel):
            self.error_model = config.error_model
            self.error_model.check_usable(
                config.matcher, left_right_check=bool(getattr(self.matcher, "left_right_check", False))
            )

    def __call__(self, index):
        """``(disparity, T_world_cam, ray_class)`` of frame ``index``.

        Returns
        -------
        disparity : (H, W) float32, pixels, NaN = invalid
        T_world_cam : (4, 4) float64, metres
        ray_class : (H, W) int32 or None
            Each pixel's error class (:meth:`ErrorModel.classify` of its confidence features, -1 = none)
            when the run is conditioned; None otherwise.
        """
        frame = self.sequence[index]
        if frame.T_world_cam is None:
            raise PrismapInputError(
                f"{self.sequence.path}: no poses.txt; mapping needs the pose of every frame (a KITTI odometry "
                "sequence ROOT/sequences/NN takes ROOT/poses/NN.txt, published for sequences 00-10 only)"
            )
        lr_disagreement = None
        if self.matcher is not None:
            disparity, lr_disagreement = self.matcher.compute_with_confidence(frame.left, frame.right)
        elif self.kind == DISPARITY_FROM_SEQUENCE:
            if frame.disparity_gt is None:
                raise PrismapInputError(
                    f"{self.sequence.path / 'disp' / self.sequence.names[index]}: disparity file missing"
                )
            disparity = frame.disparity_gt
        else:
            disparity = self._read(index, frame)
        if self.error_model is None:
            return disparity, frame.T_world_cam, None
        return (
            disparity,
            frame.T_world_cam,
            self.error_model.classify_frame(frame.left, frame.right, disparity, lr_disagreement),
        )

    def _read(self, index, frame):
        path = Path(self.kind) / self.sequence.names[index]
        if not path.is_file():
            raise PrismapInputError(
                f"{path}: disparity file missing (expected one uint16 PNG per frame, value / 256 = px)"
            )
        disparity = read_kitti_disparity(path)
        if disparity.shape != frame.left.shape[:2]:
            raise PrismapInputError(f"{path}: size {disparity.shape} differs from the images' {frame.left.shape[:2]}")
        return disparity


def integrate_frames(
    grid: OccupancyMap,
    sequence: Sequence | BagSequence,
    config: MappingConfig,
    indices: Iterable[int],
    *,
    model: InverseSensorModel | None = None,
    on_frame: Callable[[OccupancyMap], object] | None = None,
) -> OccupancyMap:
    """Integrate frames ``indices`` of ``sequence`` into ``grid`` (in place), in order.

    Parameters
    ----------
    grid : OccupancyMap
    sequence : Sequence
    config : MappingConfig
    indices : iterable of int
    model : InverseSensorModel or None
        ``config.sensor_model(sequence.camera)``, built once per run and passed to every call (PRISM's tables,
        built as frames need them, then serve every later frame); None builds it.
    on_frame : callable or None
        Called with ``grid`` after each frame (progress bars, checkpoints).

    Notes
    -----
    The next frame's disparity (read, match, classify: :class:`DisparitySource`) is computed in a background
    thread while this one is integrated (:class:`~prismap.pipeline._prefetch.Prefetch`); the map is that of
    the frames one after the other, and an error of frame k's disparity is raised after frame k - 1 is
    integrated and ``on_frame`` called, as without the look-ahead.
    """
    if model is None:
        model = config.sensor_model(sequence.camera)
    source = DisparitySource(sequence, config, model=model)
    with Prefetch(source, indices) as frames:
        for _, (disparity, pose, ray_class) in frames:
            integrate_disparity(
                grid,
                disparity,
                sequence.camera,
                pose,
                model,
                mode=config.mode,
                policy=config.policy,
                max_range_m=config.max_range_m,
                subsample=config.subsample,
                ray_class=ray_class,
                floor_rays=config.floor_rays,
            )
            if on_frame is not None:
                on_frame(grid)
    flush_table_stores()
    return grid


def check_key_reach(sequence, config, indices, model):
    """Refuse, before any work, a voxel size whose key range cannot hold the rays of ``sequence``.

    The rays reach at most the farthest camera position plus the longest depth: ``config.max_range_m``,
    else ``model``'s ``far_depth_m`` (PRISM), else the depth of a 1 px disparity (``f b``).
    """
    if sequence.poses is None:
        return
    depth = config.max_range_m
    if math.isinf(depth):
        depth = getattr(model, "far_depth_m", sequence.camera.focal_baseline)
    positions = np.abs(sequence.poses[list(indices)][:, :3, 3]).max()
    reach_m = float(positions + depth)
    if reach_m >= key_limit_m(config.voxel_size_m):
        raise PrismapInputError(
            f"voxel size {config.voxel_size_m:g} m: the map's key range {key_range_text(config.voxel_size_m)} "
            f"cannot hold rays reaching {reach_m:.4g} m (camera positions up to {positions:.4g} m plus depths up "
            f"to {depth:.4g} m); use a voxel size of at least {reach_m / KEY_LIMIT:.3g} m or a shorter --max-range"
        )


def map_chunk(sequence_path, config, model, start, stop):
    """Map frames ``start <= i < stop`` into a fresh map (what a Dask worker runs).

    The worker opens the sequence itself, so no image crosses the network. ``model`` is the run's sensor model,
    scattered to every worker once (:func:`map_sequence`): a worker holds one copy for all its chunks, and the
    PRISM tables one chunk builds serve the next. The chunk's :class:`~prismap.grid.OccupancyMap` travels back
    pickled as its own fixed-point blocks (int64 log-odds sums, counts, ``n_frames``, ``policies``: no float
    in between), ready to :meth:`~prismap.grid.OccupancyMap.merge`.
    """
    return integrate_frames(new_map(config), read_sequence(sequence_path), config, range(start, stop), model=model)


def map_sequence(
    sequence: str | os.PathLike[str] | Sequence | BagSequence,
    config: MappingConfig,
    *,
    progress: bool = True,
    checkpoint: str | os.PathLike[str] | None = None,
    checkpoint_every: int = 0,
    client: Any = None,
    chunk_frames: int | None = None,
) -> OccupancyMap:
    """Integrate a stereo sequence into an occupancy map.

    Parameters
    ----------
    sequence : str or Path or Sequence
        A sequence directory with poses (:func:`prismap.io.read_sequence`: prismap's layout with ``poses.txt``,
        or a KITTI odometry ``ROOT/sequences/NN`` with ``ROOT/poses/NN.txt``).
    config : MappingConfig
    progress : bool
        Show a progress bar (when stderr is a terminal, see :func:`prismap._progress.progress`).
    checkpoint : str or Path or None
        Checkpoint name (``NAME.npz`` + ``NAME.json``, see :func:`open_checkpoint`). An existing
        checkpoint of the same config and inputs is resumed; one of another run is refused. The files
        are left in place on return, so the caller can write its result first and then call
        :func:`remove_checkpoint`.
    checkpoint_every : int >= 0
        Write the checkpoint after every ``checkpoint_every`` frames (0 = never). With Dask, at the
        first chunk boundary after each ``checkpoint_every`` frames.
    client : distributed.Client or None
        Integrate chunks of frames on this Dask cluster (see Notes); None = here, sequentially.
    chunk_frames : int or None
        Frames per Dask task; None = half of the frames per worker, at most ``checkpoint_every``.

    Returns
    -------
    OccupancyMap
        ``n_frames`` is the number of frames integrated (resumed ones included).

    Notes
    -----
    The sensor model is built once per run. On Dask, it is sent to every worker once, and each task maps a
    contiguous chunk of frames into its own map (the worker reads the frames from ``sequence``'s path, which
    every worker must see) and returns that map in its fixed-point storage (:func:`map_chunk`); chunk maps are
    merged in frame order, at most two per worker in flight, so memory stays bounded by the chunks.
    Without clamping, a merged map equals the sequential one bit for bit: the map sums fixed-point log-odds,
    which add in any order (:meth:`OccupancyMap.merge`, ``prismap.grid._logodds``). A sequential run resumed from a checkpoint equals an
    uninterrupted one exactly. A model that ``takes_map_prior`` (PRISM with ``prior="map"``) weighs each
    frame against the map before it, so chunks mapped apart and merged are not that map: it is refused on
    Dask (checkpoints work: they hold the whole map).
    """
    if not isinstance(config, MappingConfig):
        raise PrismapInputError(f"`config` must be a MappingConfig; got {type(config).__name__}")
    checkpoint_every = check_integer(
        checkpoint_every, "checkpoint_every", expected="an integer >= 0", condition=lambda n: n >= 0
    )
    sequence = open_sequence(sequence)
    indices = config.frame_indices(len(sequence))
    model = config.sensor_model(sequence.camera)
    check_key_reach(sequence, config, indices, model)
    DisparitySource(sequence, config, model=model)  # refuses a bad matcher, disparity directory or error model first
    map_prior = model.takes_map_prior
    if client is not None and map_prior:
        raise PrismapInputError(
            f"sensor model {config.model!r} with the map as prior (prior='map') weighs each frame against the map "
            "before it, so chunks mapped apart on Dask cannot be merged into that map: map sequentially (no client)"
        )
    if config.mode != "ray" and map_prior:
        raise PrismapInputError(
            f"sensor model {config.model!r} with the map as prior (prior='map') needs whole rays: "
            f"mode 'ray', not {config.mode!r}"
        )
    if checkpoint is None:
        return _map_frames(sequence, config, model, indices, progress, None, checkpoint_every, client, chunk_frames)
    with exclusive_lock(checkpoint, "checkpoint"):
        return _map_frames(
            sequence, config, model, indices, progress, checkpoint, checkpoint_every, client, chunk_frames
        )


def _map_frames(sequence, config, model, indices, progress, checkpoint, checkpoint_every, client, chunk_frames):
    """:func:`map_sequence` after its checks, with the checkpoint (if any) locked."""
    grid = None
    fingerprint = None
    if checkpoint is not None:
        fingerprint = run_fingerprint(sequence, config)
        grid = open_checkpoint(checkpoint, fingerprint, config, len(indices))
    grid = new_map(config) if grid is None else grid
    todo = indices[grid.n_frames :]
    bar = progress_bar(
        total=len(indices), desc=f"map {config.label}", unit="frame", enabled=None if progress else False
    )
    bar.update(grid.n_frames)
    saved = [grid.n_frames]

    def after(done):
        bar.update(done.n_frames - bar.n)
        if (
            checkpoint is not None
            and checkpoint_every
            and done.n_frames - saved[0] >= checkpoint_every
            and done.n_frames < len(indices)
        ):
            save_checkpoint(checkpoint, fingerprint, done)
            saved[0] = done.n_frames

    try:
        if client is None:
            integrate_frames(grid, sequence, config, todo, model=model, on_frame=after)
        else:
            _map_on_dask(grid, sequence, config, model, todo, client, chunk_frames, checkpoint_every, after)
    finally:
        bar.close()
    return grid


def _map_on_dask(grid, sequence, config, model, todo, client, chunk_frames, checkpoint_every, after):
    """Merge chunk maps computed by ``client``'s workers into ``grid`` in frame order; ``model`` goes to every
    worker once, before the first chunk."""
    n_workers = max(1, sum(client.nthreads().values()))
    if chunk_frames is None:
        chunk_frames = max(1, math.ceil(len(todo) / (2 * n_workers)))
        if checkpoint_every:
            chunk_frames = min(chunk_frames, checkpoint_every)
    else:
        chunk_frames = check_integer(
            chunk_frames, "chunk_frames", expected="an integer >= 1", condition=lambda n: n >= 1
        )
    chunks = [
        (todo[i], todo[min(i + int(chunk_frames), len(todo)) - 1] + 1) for i in range(0, len(todo), int(chunk_frames))
    ]
    path = os.path.abspath(sequence.path)  # symbolic links kept: a KITTI tree is recognised by its path
    model_future = client.scatter(model, broadcast=True, hash=False)
    pending = []
    try:
        for start, stop in chunks:
            pending.append(client.submit(map_chunk, path, config, model_future, start, stop, pure=False))
            if len(pending) >= 2 * n_workers:
                _merge_next(grid, pending, after)
        while pending:
            _merge_next(grid, pending, after)
    finally:
        model_future.release()


def _merge_next(grid, pending, after):
    future = pending.pop(0)
    grid.merge(future.result())
    future.release()
    after(grid)
