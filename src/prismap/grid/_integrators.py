"""Integrators, as Voxblox has them: one frame's rays -> (voxel, increment) pairs in the frame accumulator.

Two variants behind one base class, built by :func:`make_integrator`:

- ``"ray"`` (:class:`RayIntegrator`): casts every ray through the grid (Amanatides & Woo); exact per ray,
  costs per crossed voxel and ray, so near voxels crossed by many rays are visited many times (in front of their
  rays' failure floors, by a nested subsample of the rays, each cell weighed for the rays it stands for:
  :mod:`prismap.grid._floor_sampling`).
- ``"projective"`` (:class:`ProjectiveIntegrator`): visits each voxel of the frustum once, projects its
  centre into the image and takes the ray of that pixel; one visit per voxel, needs the frame's image
  geometry (:class:`ImageProjection`).

The grid never knows which sensor model it runs: it hands the model flat arrays (per ray the measurement, a
disparity or a range as the batch's ``kind`` says, and ``|r|``, per cell the ray index and the cell's depth
interval on that ray) and gets back per-cell log-odds increments (SENSOR_MODELS.md section 3). A model that states
hit/miss increments (``hit_miss_increments``) is applied without a model call (in ray mode while casting). A
per-ray class (``RayBatch.ray_class``) reaches the model as the keyword ``ray_class`` only when the batch has one
(the rays of a call in class order), a per-ray voxel overhang (``RayBatch.voxel_overhang_m``) as
``voxel_overhang_m`` only when the batch has one and the model ``takes_voxel_overhang``, and each cell's map
log-odds before the frame as ``map_log_odds`` when the model ``takes_map_prior`` (ray mode only: such a model
needs each ray's cells from the camera on).

Work per frame is bounded before it starts (:data:`MAX_FRAME_CELLS`, :data:`MAX_RAY_CELLS`) and the
accumulator's memory while it runs (``_accumulator.frame_budget_bytes``); docs/errors.md lists the bounds.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Any

import numpy as np

from prismap._cores import usable_cores
from prismap.errors import PrismapInputError
from prismap.grid import _accumulator, _kernels_project, _kernels_traverse
from prismap.grid._floor_sampling import FLOOR_RAYS, cell_weights, check_floor_rays, floor_plan
from prismap.grid._kernel_args import Projection
from prismap.grid._ray_batch import RayBatch, take_rows
from prismap.grid._sensor_model import SensorModel
from prismap.grid._shared_jobs import SharedJobs
from prismap.grid._storage import BlockTable

RAYS_PER_CHUNK = 4096
"""Rays cast per model call in ray mode (fewer when they cross more than :data:`CELLS_PER_CHUNK` voxels)."""

MODEL_THREADS = min(max(usable_cores() - 1, 1), 3)
"""Threads running the model on ray-mode chunks beside the casting thread, which runs chunks too while it would wait
(``_shared_jobs``): one on two cores, so that two threads keep both busy; at most 3, beyond which the casting
thread, the accumulator's only writer, is the limit."""

CHUNKS_AHEAD = MODEL_THREADS + 2
"""Ray-mode chunks cast and queued for the model before the casting thread adds the oldest one's increments."""

CELLS_PER_CHUNK = 1 << 17
"""Voxel visits per ray-mode chunk (~950 street rays): its arrays, about 90 bytes a cell, stay small (12 MiB)."""

MAX_FRAME_CELLS = 1 << 30
"""Voxel visits one frame may ask for: the sum over rays of the voxels between the origin and the stop depth
(ray mode), or the voxels of the frustum's key box (projective mode)."""

PROJECTIVE_PARTS = 16
"""Parts (ranges of the walk's lines) of a projective frame: each is walked and run through the model by one of
:data:`PROJECTIVE_THREADS` threads while the others take the next parts."""

PROJECTIVE_THREADS = 2
"""Threads walking the parts of a projective frame and running their cells through the model (beside the thread
that adds them to the accumulator, which walks parts too while it would wait)."""

BLOCK_FILL = 0.5
"""Share of the voxels of the accumulator blocks a projective frame touches that it is assumed to keep, to reserve
the blocks before the walk (a frustum's voxels fill about half of the blocks its surface cuts)."""

MAX_RAY_CELLS = 1 << 20
"""Voxels one ray may cross (1 M: 105 km at 0.1 m voxels, 1 km at 1 mm)."""

NOISE_BIN_RATIO = 1.25
"""Rays whose pose-induced disparity noise falls in one geometric bin share one widened model."""

MIN_NOISE_PX = 0.01
"""Pose-induced disparity noise below this (pixels) leaves the model unchanged."""


def noise_groups(model, extra_noise_px):
    """Split rays by pose-induced noise: list of ``(model, ray indices or None for all)``.

    Rays below :data:`MIN_NOISE_PX` use ``model`` itself; the others are binned geometrically
    (ratio :data:`NOISE_BIN_RATIO`) and each bin uses ``model.with_extra_noise(bin value)``.
    """
    if extra_noise_px is None:
        return [(model, None)]
    sigma = np.asarray(extra_noise_px, dtype=np.float64)
    small = ~(sigma >= MIN_NOISE_PX)
    groups = [(model, np.flatnonzero(small))] if small.any() else []
    bins = np.round(np.log(np.where(small, MIN_NOISE_PX, sigma) / MIN_NOISE_PX) / np.log(NOISE_BIN_RATIO)).astype(
        np.int64
    )
    for b in np.unique(bins[~small]):
        members = np.flatnonzero(~small & (bins == b))
        groups.append((model.with_extra_noise(MIN_NOISE_PX * NOISE_BIN_RATIO**b), members))
    return groups


class Integrator(ABC):
    """Base of the integrators: the shared maths (stop depths, model calls, bounds); subclasses override
    only :meth:`_integrate`.

    Parameters
    ----------
    voxel_size_m : float, metres
    max_range_m : float, metres, > 0 or inf
        Distance along a ray beyond which nothing is updated; a ray whose measurement lies beyond it
        only clears free space up to it, excluding the voxel that contains the max-range point (as
        OctoMap does).
    reach_m : float, metres
        Distance from the origin to the edge of the key space: a ray that would run further is an error.
    map_log_odds : callable or None
        ``map_log_odds(rows)``: the map's log-odds (float64, before this frame) of the voxels of accumulator
        rows ``rows`` ((C,) int64), for models that ``takes_map_prior``; only integrators that cast whole
        rays (:attr:`whole_rays`) use it.
    """

    name = "base"
    whole_rays = False
    """Whether the cells handed to the model tile each ray from the camera on (what ``takes_map_prior`` needs)."""

    def __init__(
        self,
        *,
        voxel_size_m: float,
        max_range_m: float = np.inf,
        reach_m: float = np.inf,
        map_log_odds: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> None:
        self.voxel_size_m = float(voxel_size_m)
        self.max_range_m = float(max_range_m)
        self.reach_m = float(reach_m)
        self.map_log_odds = map_log_odds

    def integrate(self, accumulator: BlockTable, batch: RayBatch, model: SensorModel) -> None:
        """Add the batch's (voxel, increment) pairs of ``model`` to ``accumulator`` (cleared by the caller)."""
        if model.takes_map_prior:
            if not self.whole_rays:
                raise PrismapInputError(
                    f"sensor model {model.name!r} with the map as prior needs whole rays: use mode='ray' "
                    f"(the {self.name} integrator does not cast rays from the camera)"
                )
            if self.map_log_odds is None:
                raise PrismapInputError(
                    f"sensor model {model.name!r} takes the map as prior: the integrator needs "
                    "`map_log_odds` (OccupancyMap passes it)"
                )
        if len(batch):
            self._integrate(accumulator, batch, noise_groups(model, batch.extra_noise_px))

    @abstractmethod
    def _integrate(self, accumulator, batch, groups):
        """Fill ``accumulator`` from ``batch``; ``groups`` from :func:`noise_groups`."""

    def stop_depths(
        self, model: SensorModel, batch: RayBatch, idx: np.ndarray | None, influence: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Depth at which each ray of ``idx`` stops and whether that stop excludes its voxel (cut by max range), from
        the rays' influence depths (None: the model's ``influence_depth``)."""
        measurement, ray_norm = take_rows(batch.measurement, idx), take_rows(batch.ray_norm, idx)
        if influence is None:
            influence = model.influence_depth(measurement, ray_norm, **batch.cell_kwargs(idx, model))
        influence = _per_ray(influence, measurement.size, model, "influence_depth")
        range_depth = self.max_range_m / ray_norm
        exclusive = range_depth < influence
        t_stop = np.where(exclusive, range_depth, influence)
        too_far = ~(t_stop * ray_norm <= self.reach_m) & ~(t_stop <= 0)
        if too_far.any():
            raise PrismapInputError(
                f"rays would run beyond the map's key range ({self.reach_m:.4g} m from the origin; influence depths up to "
                f"{np.nanmax(influence):.4g} m): pass a finite `max_range_m`"
            )
        return t_stop, exclusive

    def cell_increments(
        self,
        model: SensorModel,
        batch: RayBatch,
        idx: np.ndarray | None,
        ray_of_cell: np.ndarray,
        t_in: np.ndarray,
        t_out: np.ndarray,
        map_log_odds: np.ndarray | None = None,
    ) -> np.ndarray:
        """The model's log-odds increments of the cells of rays ``idx``, checked for shape; ``map_log_odds``
        ((C,) float64 or None) is passed on as the keyword of that name when given."""
        kwargs = batch.cell_kwargs(idx, model)
        if map_log_odds is not None:
            kwargs["map_log_odds"] = map_log_odds
        _, increment = model.cell_posteriors(
            take_rows(batch.measurement, idx), take_rows(batch.ray_norm, idx), ray_of_cell, t_in, t_out, **kwargs
        )
        increment = np.asarray(increment, dtype=np.float64)
        if increment.shape != t_in.shape:
            raise PrismapInputError(
                f"sensor model {model.name!r}: cell_posteriors returned {increment.shape} increments for {t_in.shape} cells"
            )
        return increment

    def _check_work(self, cells, what):
        if cells > MAX_FRAME_CELLS:
            raise PrismapInputError(
                f"the frame asks for {cells:.3g} voxel visits ({what}), more than the bound {MAX_FRAME_CELLS} "
                f"(docs/errors.md) at `voxel_size_m`={self.voxel_size_m:g}: lower `max_range_m` (now {self.max_range_m:g} m), "
                "raise the voxel size, or subsample the rays"
            )


class RayIntegrator(Integrator):
    """Ray casting: every ray is traversed (Amanatides & Woo [1]_) from the origin to
    ``min(model.influence_depth, max range)``, including the voxel that contains the stop depth.

    Hit/miss models go through ``cast_hit_miss`` (increments added while casting). For the others, rays go
    in chunks (:data:`RAYS_PER_CHUNK`, :data:`CELLS_PER_CHUNK`; with per-ray classes, one class a chunk) through
    a pipeline: this thread casts chunk k + 1 (the kernel releases the GIL) while :data:`MODEL_THREADS` threads
    run the model on the :data:`CHUNKS_AHEAD` chunks before it (the model costs several times the cast); this
    thread then adds the increments of finished chunks in chunk order, so only it writes the accumulator, and while
    the oldest is unfinished it runs the model on a queued chunk itself (:class:`~prismap.grid._shared_jobs.SharedJobs`:
    on two cores, one model thread and this one keep both busy without a third thread taking turns). A model that
    ``takes_map_prior`` gets each chunk's cells' map log-odds, looked up by this thread right after the chunk's
    cast (the map changes only after the frame). With ``floor_rays`` > 0, a batch with ``levels`` and a model with a
    floor depth (``influence_and_floor_depths``), the cells at a ray's failure floor are cast by a nested subsample
    of the rays and weighed for the rays each stands for (:mod:`prismap.grid._floor_sampling`): each ray's cast
    starts where its level's bands begin, and the threads that run the model weigh its cells beside their
    increments.

    References
    ----------
    .. [1] J. Amanatides, A. Woo, "A fast voxel traversal algorithm for ray tracing", Eurographics 1987.
    """

    name = "ray"
    whole_rays = True

    def __init__(self, *, floor_rays: int = FLOOR_RAYS, **config: Any) -> None:
        super().__init__(**config)
        self.floor_rays = check_floor_rays(floor_rays)

    def _integrate(self, accumulator, batch, groups):
        origin, voxel = batch.origin_w, self.voxel_size_m
        stops, plans = [], []
        for model, members in groups:
            influence, floor_end = self._model_depths(model, batch, members)
            t_stop, exclusive = self.stop_depths(model, batch, members, influence)
            stops.append((model, members, t_stop, exclusive))
            plans.append(self._floor_plan(batch, members, t_stop, floor_end))
        limits = [
            _kernels_traverse.cell_limits(
                origin, np.ascontiguousarray(take_rows(batch.rays_w, members)), plan[0], t_stop, voxel
            )
            for (_, members, t_stop, _), plan in zip(stops, plans)
        ]
        longest = max((int(lim.max()) for lim in limits if lim.size), default=0)
        if longest > MAX_RAY_CELLS:
            raise PrismapInputError(
                f"a ray would cross {longest} voxels, more than the bound {MAX_RAY_CELLS} (docs/errors.md) at "
                f"`voxel_size_m`={voxel:g}: lower `max_range_m` (now {self.max_range_m:g} m) or check the disparities "
                "(one near 0 px reaches very far)"
            )
        self._check_work(sum(int(lim.sum()) for lim in limits), "the sum over rays of the voxels each crosses")
        if _hit_miss_rule(groups) is not None:
            for model, members, t_stop, exclusive in stops:
                _cast_hit_miss(
                    accumulator,
                    origin,
                    np.ascontiguousarray(take_rows(batch.rays_w, members)),
                    t_stop,
                    exclusive,
                    model,
                    voxel,
                )
            return
        chunks = []
        for (model, members, t_stop, exclusive), (t_start, floor_end, bands), limit in zip(stops, plans, limits):
            idx = np.arange(len(batch)) if members is None else members
            by_class, parts = _class_chunks(batch.class_kwargs(idx, model).get("ray_class"), limit)
            idx, t_start, t_stop, exclusive = idx[by_class], t_start[by_class], t_stop[by_class], exclusive[by_class]
            floor_end = None if floor_end is None else floor_end[by_class]
            for part in parts:
                chunk = idx[part]
                cast = (t_start[part], t_stop[part], exclusive[part])
                weighting = None if floor_end is None else (floor_end[part], *bands)
                rays = batch.rays_w[chunk]
                chunks.append((model, chunk, weighting, *(np.ascontiguousarray(a) for a in (rays, *cast))))
        # The model runs on the chunks cast before in MODEL_THREADS threads (and in this one while it would wait)
        # while this thread casts the next and adds finished chunks' increments in chunk order: it alone writes
        # the accumulator (so the cast may grow it), and the map is that of one thread.
        with SharedJobs(MODEL_THREADS) as jobs:
            for model, chunk, weighting, *cast in chunks:
                ray_of_cell, cell_index, t_in, t_out = _accumulator.cast_into(accumulator, origin, *cast, voxel)
                if cell_index.size:
                    prior = self.map_log_odds(cell_index) if model.takes_map_prior else None
                    jobs.submit(
                        self._chunk_update, model, batch, chunk, cell_index, ray_of_cell, t_in, t_out, prior, weighting
                    )
                while len(jobs) > CHUNKS_AHEAD:
                    _accumulator.scatter(accumulator, *jobs.next_result())
            while jobs:
                _accumulator.scatter(accumulator, *jobs.next_result())

    def _chunk_update(self, model, batch, chunk, cell_index, ray_of_cell, t_in, t_out, prior, weighting):
        """A chunk's accumulator rows ``cell_index``, its cell increments (:meth:`cell_increments`) and weights
        (``_floor_sampling.cell_weights`` of ``weighting``, ``(floor_end, band_depth, base)``; None: every cell
        once): the arguments of ``_accumulator.scatter``."""
        increments = self.cell_increments(model, batch, chunk, ray_of_cell, t_in, t_out, prior)
        return cell_index, increments, None if weighting is None else cell_weights(ray_of_cell, t_out, *weighting)

    def _model_depths(self, model, batch, idx):
        """Each ray's influence depth and floor depth (None: no floor sampling) of rays ``idx``: from the model's
        ``influence_and_floor_depths`` (one look-up for both) when the frame samples floors (``floor_rays`` > 0, a batch
        with ``levels``, a model with that method and without the map as prior), else its ``influence_depth``."""
        measurement, ray_norm = take_rows(batch.measurement, idx), take_rows(batch.ray_norm, idx)
        kwargs = batch.cell_kwargs(idx, model)
        both = getattr(model, "influence_and_floor_depths", None)
        if not self.floor_rays or batch.levels is None or both is None or model.takes_map_prior:
            return model.influence_depth(measurement, ray_norm, **kwargs), None
        influence, floor_end = both(measurement, ray_norm, **kwargs)
        if floor_end is not None:
            floor_end = _per_ray(floor_end, measurement.size, model, "the floor depth of influence_and_floor_depths")
        return influence, floor_end

    def _floor_plan(self, batch, idx, t_stop, floor_end):
        """``(t_start, floor_end, (band_depth, base))`` of rays ``idx`` (:func:`~prismap.grid._floor_sampling.floor_plan`)
        from their floor depths ``floor_end``; ``(0, None, None)``, every cell cast and counted once, when it is None."""
        if floor_end is None:
            return np.zeros(t_stop.size), None, None
        levels = batch.levels if idx is None else batch.levels.subset(idx)
        t_start, band_depth = floor_plan(floor_end, levels, self.voxel_size_m, self.floor_rays)
        return t_start, floor_end, (band_depth, levels.base)


def _per_ray(depth, n, model, what):
    """``depth`` as (n,) float64, else raise naming the model and ``what`` returned it."""
    depth = np.asarray(depth, dtype=np.float64)
    if depth.shape != (n,):
        raise PrismapInputError(f"sensor model {model.name!r}: {what} returned shape {depth.shape}; expected ({n},)")
    return depth


def _class_chunks(ray_class, limits):
    """Order of the rays (positions in ``limits``) and the slices of that order a chunk each (:func:`_chunks`):
    with per-ray classes (``ray_class`` (R,) int, or None), the rays by class (stable: image order within a
    class) and no chunk across two classes, so that a conditioned model runs each chunk with one class's model
    and tables."""
    if ray_class is None:
        return slice(None), _chunks(limits)
    order = np.argsort(ray_class, kind="stable")
    bounds = np.flatnonzero(np.diff(ray_class[order])) + 1
    parts = []
    for lo, hi in zip(np.concatenate(([0], bounds)), np.concatenate((bounds, [order.size]))):
        parts += [slice(lo + part.start, lo + part.stop) for part in _chunks(limits[order[lo:hi]])]
    return order, parts


def _chunks(limits):
    """Slices of consecutive rays of at most :data:`RAYS_PER_CHUNK` rays and :data:`CELLS_PER_CHUNK` voxel
    visits (a ray of more visits is a chunk of its own)."""
    n = limits.size
    if n and int(limits.sum()) <= CELLS_PER_CHUNK:  # few visits in all: split by ray count only
        return [slice(b, min(b + RAYS_PER_CHUNK, n)) for b in range(0, n, RAYS_PER_CHUNK)]
    total = np.cumsum(limits)
    parts, begin = [], 0
    while begin < n:
        base = total[begin - 1] if begin else 0
        end = int(np.searchsorted(total, base + CELLS_PER_CHUNK, side="right"))
        end = min(max(end, begin + 1), begin + RAYS_PER_CHUNK, n)
        parts.append(slice(begin, end))
        begin = end
    return parts


def _cast_hit_miss(accumulator, origin, rays, t_stop, exclusive, model, voxel_size):
    """Ray mode for a model with ``hit_miss_increments``: the increments are added while casting, one kernel
    call per accumulator size (it stops when the accumulator needs to grow). Per-ray classes do not apply."""
    l_hit, l_miss = model.hit_miss_increments()
    z_hit = _hit_depths(t_stop, exclusive)
    done = 0
    while done < rays.shape[0]:
        n, blocks = _kernels_traverse.cast_hit_miss(
            _accumulator.kernel_arrays(accumulator),
            origin,
            rays[done:],
            t_stop[done:],
            exclusive[done:],
            z_hit[done:],
            l_hit,
            l_miss,
            voxel_size,
        )
        done += n
        if done < rays.shape[0]:
            _accumulator.grow(accumulator, blocks)


class ProjectiveIntegrator(Integrator):
    """Projective integration: visit the voxels of the frustum (up to where the measurements stop influencing),
    give each the ray of the pixel its centre projects to, one update each. Needs the batch's :class:`ImageProjection`.

    The key box is walked in lines along the image rows (``_kernels_project.project_part``), in
    :data:`PROJECTIVE_PARTS` parts of the lines; :data:`PROJECTIVE_THREADS` threads take the parts in turn and run
    each part's cells, grouped by ray (the rays in error-class order), through the model. This thread registers
    every part's voxels in the accumulator and adds their increments, in part order (``_accumulator.scatter_keys``),
    and walks queued parts itself while the next one in order is unfinished (:class:`~prismap.grid._shared_jobs.SharedJobs`):
    the accumulator has one writer and its blocks the order of a walk in one thread. A voxel is visited once per
    frame, so the map depends neither on the parts nor on the threads. A hit/miss model's increments are computed in
    the walking threads from the cells' intervals, without grouping by ray or a model call."""

    name = "projective"

    def _integrate(self, accumulator, batch, groups):
        image = batch.image
        if image is None:
            raise PrismapInputError(
                "projective mode needs the batch's image geometry (`RayBatch.image`: "
                "prismap.camera.disparity_batch(..., projective=True))"
            )
        n = len(batch)
        origin, rays, voxel = batch.origin_w, batch.rays_w, self.voxel_size_m
        t_stop = np.empty(n)
        exclusive = np.empty(n, dtype=np.bool_)
        group_of_ray = np.zeros(n, dtype=np.int64)
        for g, (model, members) in enumerate(groups):
            idx = slice(None) if members is None else members  # one group: views, no copies
            t_stop[idx], exclusive[idx] = self.stop_depths(model, batch, members)
            group_of_ray[idx] = g
        key_min, shape, n_casting = _kernels_project.frustum_box(origin, rays, t_stop, voxel)
        if n_casting == 0:
            return
        box = float(np.prod(shape.astype(np.float64)))
        self._check_work(box, f"the frustum's key box of {shape[0]} x {shape[1]} x {shape[2]} voxels")
        stops = _kernels_project.stop_image(image.ray_index, t_stop)
        projection = Projection(
            key_min,
            shape,
            origin,
            image.R_cam_world,
            image.focal_px,
            image.cx_px,
            image.cy_px,
            float(image.subsample),
            image.ray_index,
            rays,
            exclusive,
            stops,
            _kernels_project.tile_stops(stops),
            voxel,
        )
        hit_miss = _hit_miss_rule(groups)
        if hit_miss is not None:
            z_hit = _hit_depths(t_stop, exclusive)
        capacity = 1.05 * _frustum_voxels(t_stop, image.focal_px, image.subsample, voxel) + 4096
        _accumulator.expect(accumulator, capacity / (BLOCK_FILL * accumulator.block_voxels))
        n_lines = int(_kernels_project.walk_lines(image.R_cam_world, shape))
        cuts = np.linspace(0, n_lines, min(PROJECTIVE_PARTS, n_lines) + 1).astype(np.int64)
        max_cells = _accumulator.frame_budget_bytes() // 32  # 32 bytes per kept cell
        part_capacity = int(min(box, capacity) / (cuts.size - 1)) + 4096
        ray_key = np.zeros(n, np.int64) if batch.ray_class is None else batch.ray_class.astype(np.int64) + 1

        def part(start, stop):
            keys, ray_of_cell, t_in, t_out, m = _kernels_project.project_part(
                projection, start, stop, part_capacity, max_cells
            )
            if m > keys.shape[0]:  # over the bound: counted only
                return keys, None, m
            cells = (ray_of_cell[:m], t_in[:m], t_out[:m])
            if hit_miss is not None:
                return keys[:m], _hit_miss_increments(*cells, z_hit, *hit_miss), m
            return keys[:m], self._part_increments(batch, groups, group_of_ray, ray_key, *cells), m

        with SharedJobs(PROJECTIVE_THREADS) as parts:
            for start, stop in zip(cuts[:-1], cuts[1:]):
                parts.submit(part, start, stop)
            cells = 0
            while parts:
                keys, increment, m = parts.next_result()
                cells += m
                if cells > max_cells:
                    raise PrismapInputError(
                        f"the frame projects onto at least {cells} voxels, more than {max_cells} (docs/errors.md) "
                        f"at `voxel_size_m`={self.voxel_size_m:g}: lower `max_range_m` (now {self.max_range_m:g} m) "
                        "or raise the voxel size"
                    )
                if m:
                    _accumulator.scatter_keys(accumulator, keys, increment)

    def _part_increments(self, batch, groups, group_of_ray, ray_key, ray_of_cell, t_in, t_out):
        """The model's increments of one part's cells ((C,) float64, in the walk's order): the cells go through
        the model grouped by ray (per-ray state, a table's nodes shared), the rays by ``ray_key`` (R,) (class + 1),
        one call per noise group, on the rays some voxel uses (models cost per ray too)."""
        increment = np.empty(ray_of_cell.size)
        if ray_of_cell.size == 0:  # a part that sees nothing: no model call
            return increment
        order, t_in, t_out, used, local = _kernels_project.group_by_ray(ray_of_cell, len(batch), t_in, t_out, ray_key)
        if len(groups) == 1:  # no pose noise: the loop below with every used ray in the group, minus its copies
            increment[order] = self.cell_increments(groups[0][0], batch, used, local, t_in, t_out)
            return increment
        group_of_used = group_of_ray[used]
        group_of_cell = group_of_used[local]
        for g, (model, _) in enumerate(groups):
            in_group = group_of_used == g
            mine = np.flatnonzero(group_of_cell == g)
            if in_group.any():
                rank = np.cumsum(in_group) - 1  # index of each used ray among the group's used rays
                increment[order[mine]] = self.cell_increments(
                    model, batch, used[in_group], rank[local[mine]], t_in[mine], t_out[mine]
                )
        return increment


def _hit_miss_rule(groups):
    """``(l_hit, l_miss)`` when every group's model states hit/miss increments (applied without a model call),
    else None (the cell path)."""
    if all(model.hit_miss_increments() is not None for model, _ in groups):
        return groups[0][0].hit_miss_increments()
    return None


def _hit_depths(t_stop, exclusive):
    """Each ray's hit depth for the hit/miss rule: its stop depth, inf for a ray cut at max range (it ends in
    misses)."""
    return np.where(exclusive, np.inf, t_stop)


def _hit_miss_increments(ray_of_cell, t_in, t_out, z_hit, l_hit, l_miss):
    """Hit/miss increments ((C,) float64) of cells ``[t_in, t_out)`` on rays ``ray_of_cell``: ``l_hit`` where the
    cell holds its ray's ``z_hit``, ``l_miss`` where it ends at or before it, 0 beyond (the rule of
    ``sensor_models._kernels_classic.hitmiss_cells``), without grouping the cells by ray."""
    z = z_hit[ray_of_cell]
    return np.where(t_out <= z, l_miss, np.where(t_in <= z, l_hit, 0.0))


def _frustum_voxels(t_stop, focal_px, subsample, voxel_size):
    """About how many voxel centres lie in the frustum of the pixel rays up to their stop depths plus a voxel:
    a pixel of side ``subsample / focal_px`` at unit depth sweeps ``(t + voxel)^3 subsample^2 / (3 focal_px^2)``
    cubic metres up to depth ``t + voxel`` (the rays' cells reach up to a voxel beyond the stop)."""
    t = t_stop[t_stop > 0]
    return float(np.sum((t + voxel_size) ** 3)) * subsample**2 / (3.0 * focal_px**2 * voxel_size**3)


_INTEGRATORS = {cls.name: cls for cls in (RayIntegrator, ProjectiveIntegrator)}
INTEGRATOR_NAMES = tuple(_INTEGRATORS)
"""Names accepted by :func:`make_integrator` (the grid's ``mode``)."""


def make_integrator(name: str, **config: Any) -> Integrator:
    """The integrator called ``name`` (``"ray"`` or ``"projective"``), built from ``config`` (see :class:`Integrator`)."""
    try:
        cls = _INTEGRATORS[name]
    except (KeyError, TypeError):
        raise PrismapInputError(f"`mode` must be one of {list(_INTEGRATORS)}; got {name!r}") from None
    return cls(**config)
