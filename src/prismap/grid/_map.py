"""The occupancy map: an unbounded sparse grid of hashed voxel blocks holding log-odds and counts."""

from __future__ import annotations

from copy import deepcopy

import numpy as np
import numpy.typing as npt
from scipy.special import expit

from prismap._validate import as_float_array, check_classes, check_positive, check_probability
from prismap.errors import PrismapInputError
from prismap.grid import _accumulator, _kernels_accumulate, _kernels_hash
from prismap.grid._floor_sampling import FLOOR_RAYS, MAX_BAND
from prismap.grid._fusion import MapReading
from prismap.grid._integrators import make_integrator
from prismap.grid._kernel_args import MapStore
from prismap.grid._keys import BLOCK_BITS, KEY_LIMIT, check_keys, key_range_text, key_to_center, point_to_key
from prismap.grid._logodds import LOG_ODDS_STEP, Q_DTYPE, Q_MAX, Q_MIN, from_fixed, logit, to_fixed
from prismap.grid._policies import policy_code, policy_name
from prismap.grid._ray_batch import MEASUREMENT_KINDS, RayBatch
from prismap.grid._sensor_model import SensorModel
from prismap.grid._slice import horizontal_slice
from prismap.grid._storage import BlockTable
from prismap.grid._traverse import crossed_voxels

FREE, OCCUPIED, UNKNOWN = 0, 1, -1
"""Voxel states returned by :meth:`OccupancyMap.state`."""

OCTOMAP_CLAMP = (0.1192, 0.971)
"""OctoMap's default clamping thresholds (probabilities)."""


def _probability(log):
    """Probability of float log-odds (float64; no overflow warning at large |log|)."""
    return expit(np.asarray(log, dtype=np.float64))


class OccupancyMap:
    """Sparse voxel map of fixed-point log-odds and per-voxel observation counts.

    Voxels live in hashed blocks (4^3 in 3-D; 8x8x1 in 2-D) created when first observed, with keys inside
    :data:`~prismap.grid.KEY_LIMIT` on every axis. A voxel stores its full log-odds ``l`` (``logit(p0)``
    before any update) in int64 units of ``2**-20`` (order-free sums, see ``prismap.grid._logodds``) and
    how many frames observed it (uint16, saturating at 65535). A voxel no frame observed is *unknown*,
    whatever its probability.

    Parameters
    ----------
    voxel_size_m : float, metres, > 0
    p0 : float in (0, 1)
        Prior occupancy of a voxel: the environment's occupancy ratio at this voxel size
        (SENSOR_MODELS.md section 5); it must equal the sensor model's ``p0``.
    ndim : {3, 2}
        A 2-D map is the same engine with one layer of voxels (z key 0); its points and rays are
        (N, 2) arrays in the x-y plane.
    clamp : (float, float) or None
        Probabilities ``(p_min, p_max)`` to clamp each voxel to after every update, e.g.
        :data:`OCTOMAP_CLAMP`. Off by default: clamping makes the map depend on the order of frames,
        which breaks parallel integration and exact merging.
    occupied_threshold, free_threshold : float in (0, 1)
        A known voxel is occupied if ``P >= occupied_threshold``, free if ``P < free_threshold``,
        unknown in between. Both default to 0.5 (OctoMap's rule).
    fusion : PersistentFailure, FailureMixture, FailureClamp or None
        How a voxel's stored log-odds and count read as a probability (every query of ``P``): None is the
        independent sum, ``sigmoid(l)``; a :class:`~prismap.grid.PersistentFailure` reads them under a matcher
        failure state that persists across views; a :class:`~prismap.grid.FailureMixture` averages the sum with
        ``p0`` by the failure rate and a :class:`~prismap.grid.FailureClamp` clamps it, each to that state's
        one-view bound (docs/SENSOR_MODELS.md section 9). Stored sums and merges do not depend on it.
    """

    def __init__(
        self,
        voxel_size_m: float,
        *,
        p0: float,
        ndim: int = 3,
        clamp: tuple[float, float] | None = None,
        occupied_threshold: float = 0.5,
        free_threshold: float = 0.5,
        fusion: MapReading | None = None,
    ) -> None:
        self.voxel_size_m = check_positive(voxel_size_m, "voxel_size_m")
        self.p0 = check_probability(p0, "p0")
        if ndim not in BLOCK_BITS:
            raise PrismapInputError(f"`ndim` must be 2 or 3; got {ndim!r}")
        self.ndim = int(ndim)
        if clamp is not None:
            lo, hi = (check_probability(c, "clamp") for c in clamp)
            if not lo < self.p0 < hi:
                raise PrismapInputError(f"`clamp` must satisfy p_min < p0 < p_max; got {clamp!r} with p0={self.p0}")
            clamp = (lo, hi)
        self.clamp = clamp
        if fusion is not None and not isinstance(fusion, MapReading):
            raise PrismapInputError(f"`fusion` must be a MapReading or None; got {type(fusion).__name__}")
        self.fusion = fusion
        self.occupied_threshold = check_probability(occupied_threshold, "occupied_threshold")
        self.free_threshold = check_probability(free_threshold, "free_threshold")
        if self.free_threshold > self.occupied_threshold:
            raise PrismapInputError(
                f"`free_threshold` ({free_threshold}) must not exceed `occupied_threshold` ({occupied_threshold})"
            )
        self.prior_q = int(to_fixed(logit(self.p0)))
        self.prior_log = float(from_fixed(self.prior_q))
        self.policies = ()
        self.n_frames = 0
        voxels = 1 << sum(BLOCK_BITS[self.ndim])
        self._store = BlockTable(BLOCK_BITS[self.ndim], {"log": ((voxels,), Q_DTYPE), "count": ((voxels,), np.uint16)})
        self._accumulator = _accumulator.new_accumulator(self._store.bits)

    # ----------------------------------------------------------------------------------- integration
    def integrate(
        self,
        batch: RayBatch,
        model: SensorModel,
        *,
        mode: str = "ray",
        policy: str | None = None,
        max_range_m: float = np.inf,
        floor_rays: int = FLOOR_RAYS,
    ) -> None:
        """Integrate one frame's measurements.

        Parameters
        ----------
        batch : RayBatch
            The frame's measurements along rays from one origin: disparities or ranges (``batch.kind``), with
            optional per-ray extra noise, error class and voxel overhang (a camera's disparity image becomes
            one with :func:`prismap.camera.disparity_batch`). Rays with a non-finite measurement are skipped.
        model : InverseSensorModel
            Built for this map: its ``p0`` and ``voxel_size_m`` (when it has them) must equal the map's, and
            it must take the batch's kind of measurement (its ``measurements``).
        mode : {"ray", "projective"}
            ``ray`` casts every ray through the grid (the cells at a ray's failure floor sampled, ``floor_rays``);
            ``projective`` visits the voxels of the frustum (up to
            where the measurements stop influencing), projects each centre into the batch's image
            (``batch.image``) and updates it once from the ray of the pixel it lands on.
        policy : str or None
            Per-frame policy (``mean``, ``max-abs``, ``occupied-wins``, ``max``, ``sum``, see
            :data:`~prismap.grid.POLICIES`); None = the model's ``default_policy``.
        max_range_m : float, metres, > 0
            Distance along a ray beyond which nothing is updated. A ray whose measurement lies
            beyond it only clears free space up to it, excluding the voxel that contains the
            max-range point (as OctoMap does).
        floor_rays : int >= 0, default :data:`~prismap.grid.FLOOR_RAYS`
            Ray mode with a batch that has ``levels`` and a model with ``influence_and_floor_depths``: the cells at their ray's
            failure floor are cast by a nested subsample of the rays, at least this many rays a voxel each way, each
            counted for the rays it stands for (:mod:`prismap.grid._floor_sampling`); 0 = every ray casts every
            cell.

        Notes
        -----
        The integrators (:func:`~prismap.grid.make_integrator`) say how rays become voxel updates.
        Several rays of the frame that cross one voxel give it ONE update, combined by ``policy``. A batch's
        extra noise (pose uncertainty) groups its rays by ``sigma`` (geometric bins), and each group uses
        ``model.with_extra_noise(sigma)``.
        """
        if not isinstance(batch, RayBatch):
            raise PrismapInputError(f"`batch` must be a RayBatch; got {type(batch).__name__}")
        self._integrate(self._checked(batch), model, mode, policy, max_range_m, floor_rays)

    def integrate_rays(
        self,
        origin_w: npt.ArrayLike,
        rays_w: npt.ArrayLike,
        measurement: npt.ArrayLike,
        model: SensorModel,
        *,
        kind: str = "disparity",
        mode: str = "ray",
        policy: str | None = None,
        max_range_m: float = np.inf,
        extra_noise_px: npt.ArrayLike | None = None,
        ray_class: npt.ArrayLike | None = None,
        voxel_overhang_m: npt.ArrayLike | None = None,
    ) -> None:
        """Integrate one frame given as arrays: :meth:`integrate` of their :class:`RayBatch` (ray mode).

        Parameters
        ----------
        origin_w : (3,) or (2,) float, metres, world frame
            The sensor's origin.
        rays_w : (R, 3) or (R, 2) float, world frame
            The point at ray parameter ``t`` is ``origin_w + t * rays_w``; the norm is the ray's ``|r| >= 1``
            (a camera's rays ``(x/z, y/z, 1)`` rotated into the world; unit vectors for ranges).
        measurement : (R,) float, NaN = invalid (skipped)
            Disparity (pixels) or range (metres), as ``kind`` says.
        model : InverseSensorModel
        kind : {"disparity", "range"}
        mode : {"ray"}
            ``projective`` needs the image geometry a batch carries: :meth:`integrate`.
        policy, max_range_m : see :meth:`integrate`
        extra_noise_px : (R,) float, pixels, or None
            Extra disparity noise per ray (pose uncertainty, :func:`prismap.camera.pose_noise_px`).
        ray_class : (R,) int or None
            Error-model class of each ray (-1 = no class), passed to the model's ``cell_posteriors`` and
            ``influence_depth`` as the keyword ``ray_class`` (only when given). Hit/miss models ignore it.
        voxel_overhang_m : (R,) float, metres along the ray, >= 0, or None
            How far before its surface a voxel each ray crosses can still hold part of that surface
            (:func:`prismap.camera.voxel_overhang_m`), passed to models that ``takes_voxel_overhang`` (PRISM).
        """
        self.integrate(
            RayBatch(origin_w, rays_w, measurement, None, extra_noise_px, ray_class, None, voxel_overhang_m, kind),
            model,
            mode=mode,
            policy=policy,
            max_range_m=max_range_m,
        )

    def _checked(self, batch):
        """``batch`` with its arrays checked against the map, its ray norms computed and its invalid rays dropped."""
        if batch.kind not in MEASUREMENT_KINDS:
            raise PrismapInputError(f"`kind` must be one of {list(MEASUREMENT_KINDS)}; got {batch.kind!r}")
        origin = self._points(batch.origin_w, "origin_w", single=True)
        rays = self._points(batch.rays_w, "rays_w", as_direction=True)
        n = rays.shape[0]
        measurement = as_float_array(batch.measurement, "measurement", shape=(n,))
        ray_norm = np.sqrt(np.einsum("ri,ri->r", rays, rays))
        valid = np.isfinite(measurement) & np.isfinite(ray_norm)  # a non-finite ray has a non-finite norm
        if np.any(ray_norm[valid] < 1.0 - 1e-9):
            raise PrismapInputError(
                "`rays_w` must have norm >= 1 (camera rays (x/z, y/z, 1) rotated into the world, or unit vectors)"
            )
        noise = None
        if batch.extra_noise_px is not None:
            noise = as_float_array(batch.extra_noise_px, "extra_noise_px", shape=(n,))
            if not np.all(noise[valid] >= 0) or not np.all(np.isfinite(noise[valid])):
                raise PrismapInputError("`extra_noise_px` must be finite and >= 0 at every valid ray")
        classes = None if batch.ray_class is None else check_classes(batch.ray_class, "ray_class", (n,))
        overhang = None
        if batch.voxel_overhang_m is not None:
            overhang = as_float_array(batch.voxel_overhang_m, "voxel_overhang_m", shape=(n,))
            if not np.all(overhang[valid] >= 0) or not np.all(np.isfinite(overhang[valid])):
                raise PrismapInputError("`voxel_overhang_m` must be finite and >= 0 at every valid ray")
        levels = batch.levels
        if levels is not None and (
            np.shape(levels.level) != (n,) or (n and not 0 <= np.min(levels.level) <= np.max(levels.level) <= MAX_BAND)
        ):
            raise PrismapInputError(f"`levels.level` must be ({n},) integers in [0, {MAX_BAND}]")
        checked = RayBatch(
            origin, rays, measurement, ray_norm, noise, classes, batch.image, overhang, batch.kind, levels
        )
        return checked if valid.all() else checked.subset(valid)  # a dense frame skips these copies

    def _integrate(self, batch, model, mode, policy, max_range_m, floor_rays):
        """One frame: the model checked against the map, the integrator of ``mode``, one update per voxel."""
        self._check_model(model)
        measurement = getattr(model, "measurement", "disparity")
        if measurement != batch.kind:
            raise PrismapInputError(
                f"sensor model {getattr(model, 'name', type(model).__name__)!r} takes {measurement} "
                f"measurements; the batch holds {batch.kind} measurements"
            )
        code = policy_code(policy, model)
        max_range = check_positive(max_range_m, "max_range_m") if np.isfinite(max_range_m) else np.inf
        origin_key = np.abs(np.floor(batch.origin_w / self.voxel_size_m)).max()
        reach = (KEY_LIMIT - 2 - origin_key) * self.voxel_size_m
        if reach <= 0:
            raise PrismapInputError(
                f"`origin_w` {batch.origin_w.tolist()} lies outside the map's key range "
                f"{key_range_text(self.voxel_size_m)}"
            )
        prior = self._map_log_odds if model.takes_map_prior else None
        sampling = {"floor_rays": floor_rays} if mode == "ray" else {}
        integrator = make_integrator(
            mode, voxel_size_m=self.voxel_size_m, max_range_m=max_range, reach_m=reach, map_log_odds=prior, **sampling
        )
        self._accumulator.clear()
        integrator.integrate(self._accumulator, batch, model)
        self._apply_accumulator(code)
        name = policy_name(policy, model)
        if name not in self.policies:
            self.policies = (*self.policies, name)
        self.n_frames += 1

    def _check_model(self, model):
        """Refuse a sensor model built for another prior or voxel size (models without them are not checked)."""
        for attr, mine in (("p0", self.p0), ("voxel_size_m", self.voxel_size_m)):
            theirs = getattr(model, attr, None)
            if theirs is not None and not np.isclose(float(theirs), mine, rtol=1e-9, atol=0.0):
                raise PrismapInputError(
                    f"sensor model {getattr(model, 'name', type(model).__name__)!r} was built with {attr}={theirs!r} "
                    f"but the map has {attr}={mine!r}: build the model with the map's {attr}"
                )

    def _map_log_odds(self, rows):
        """Log-odds (float64) of the voxels of frame accumulator rows ``rows``; ``logit(p0)`` where the map has none."""
        q = _kernels_accumulate.map_log_of_rows(
            self._kernel_store(),
            _accumulator.kernel_arrays(self._accumulator),
            np.ascontiguousarray(rows, dtype=np.int64),
            np.int64(self.prior_q),
        )
        return from_fixed(q)

    def merge(self, other: OccupancyMap) -> OccupancyMap:
        """Add another map of the same grid into this one (in place); returns ``self``.

        Voxels known to both get ``l1 + l2 - logit(p0)`` (the sum of both maps' evidence; clamped if
        this map clamps) and the sum of the counts; voxels known to one map keep its value. With
        clamping off, integrating frames 1..n into one map equals merging maps of any split of them up
        bit for bit (fixed-point log-odds: integer sums do not depend on their order).
        """
        if not isinstance(other, OccupancyMap):
            raise PrismapInputError(f"can only merge an OccupancyMap; got {type(other).__name__}")
        for attr in ("voxel_size_m", "p0", "ndim", "fusion"):
            if getattr(self, attr) != getattr(other, attr):
                raise PrismapInputError(
                    f"cannot merge maps of different grids or readings: {attr} {getattr(self, attr)!r} != "
                    f"{getattr(other, attr)!r}"
                )
        store, theirs = self._store, other._store
        store.reserve(store.count_absent(theirs.block_keys, len(theirs)))
        lo, hi = self._clamp_q()
        _kernels_accumulate.merge_blocks(self._kernel_store(), other._kernel_store(), lo, hi, self.prior_q)
        self.policies = (*self.policies, *(p for p in other.policies if p not in self.policies))
        self.n_frames += other.n_frames
        return self

    def set_voxels(self, keys: npt.ArrayLike, log_odds: npt.ArrayLike, counts: npt.ArrayLike) -> None:
        """Overwrite the log-odds and counts of the given voxels (the map file reader uses this).

        Parameters
        ----------
        keys : (N, 3) int, voxel keys (z key 0 in a 2-D map)
        log_odds : (N,) float, log-odds (stored rounded to the nearest ``2**-20``)
        counts : (N,) int in [1, 65535], frames that observed each voxel
        """
        keys = self._keys(keys)
        log = as_float_array(log_odds, "log_odds", shape=(keys.shape[0],), allow_nan=False)
        if log.size and np.abs(log).max() > Q_MAX * LOG_ODDS_STEP:
            raise PrismapInputError(
                f"`log_odds` must lie within +-{Q_MAX * LOG_ODDS_STEP:.6g}; got up to {np.abs(log).max():.6g}"
            )
        count = np.asarray(counts)
        if (
            count.shape != (keys.shape[0],)
            or not np.issubdtype(count.dtype, np.integer)
            or (count.size and (count.min() < 1 or count.max() > 65535))
        ):
            raise PrismapInputError(
                f"`counts` must be ({keys.shape[0]},) integers in [1, 65535]; got shape {count.shape}, dtype {count.dtype}"
            )
        store = self._store
        store.reserve(_kernels_hash.count_new_blocks(store.table, store.block_keys, keys, store.bits))
        _kernels_accumulate.set_voxels(self._kernel_store(), keys, to_fixed(log), count.astype(np.uint16), self.prior_q)

    def copy(self) -> OccupancyMap:
        """An independent copy of the map (through its pickled state, :meth:`__getstate__`)."""
        return deepcopy(self)

    def __getstate__(self) -> dict:
        """Everything but the frame accumulator, one frame's scratch space (made anew on unpickling): a map
        pickles (to and from Dask workers) as its own fixed-point blocks, int64 log-odds sums and uint16 counts,
        without spare capacity (:class:`~prismap.grid._storage.BlockTable`), and unpickles bit for bit."""
        return {**self.__dict__, "_accumulator": None}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state, _accumulator=_accumulator.new_accumulator(state["_store"].bits))

    # --------------------------------------------------------------------------------------- queries
    @property
    def n_known(self) -> int:
        """Number of voxels observed at least once."""
        return int(np.count_nonzero(self._store.payload["count"][: len(self._store)]))

    def nbytes(self) -> int:
        """Bytes of memory the map's storage holds (allocated, including spare capacity)."""
        return self._store.nbytes()

    def lookup_keys(self, keys: npt.ArrayLike) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.uint16]]:
        """Log-odds and observation count at each key.

        Parameters
        ----------
        keys : (N, 3) int, voxel keys

        Returns
        -------
        log_odds : (N,) float64, multiples of ``2**-20``; ``logit(p0)`` (so rounded) where never observed
        counts : (N,) uint16, 0 = unknown
        """
        keys = self._keys(keys)
        q, count = _kernels_accumulate.lookup(self._kernel_store(), keys, np.int64(self.prior_q))
        return from_fixed(q), count

    def probability_at_keys(self, keys: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """(N,) float64 occupancy probability at each key (``p0`` where unknown)."""
        return self._read(*self.lookup_keys(keys))

    def state_at_keys(self, keys: npt.ArrayLike) -> npt.NDArray[np.int8]:
        """(N,) int8 state at each key: :data:`FREE`, :data:`OCCUPIED` or :data:`UNKNOWN`."""
        log, count = self.lookup_keys(keys)
        return self._states(log, count)

    def probability(self, points_w: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """(N,) float64 occupancy probability at world points ((N, 3), or (N, 2) in a 2-D map), metres."""
        return self.probability_at_keys(self.point_keys(points_w))

    def state(self, points_w: npt.ArrayLike) -> npt.NDArray[np.int8]:
        """(N,) int8 state (:data:`FREE`, :data:`OCCUPIED`, :data:`UNKNOWN`) at world points, metres."""
        return self.state_at_keys(self.point_keys(points_w))

    def point_keys(self, points_w: npt.ArrayLike) -> npt.NDArray[np.int32]:
        """(N, 3) int32 keys of world points ((N, 3), or (N, 2) in a 2-D map: z key 0)."""
        points = self._points(points_w, "points_w")
        return self._keys(point_to_key(points, self.voxel_size_m))

    def known_voxels(self) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.float64], npt.NDArray[np.uint16]]:
        """Every observed voxel.

        Returns
        -------
        keys : (N, 3) int32, voxel keys
        log_odds : (N,) float64, multiples of ``2**-20``
        counts : (N,) uint16, >= 1
        """
        store = self._store
        n = len(store)
        count = store.payload["count"][:n]
        known = count > 0
        keys = store.voxel_keys()[known].astype(np.int32)
        return keys, from_fixed(store.payload["log"][:n][known]), count[known]

    def known_probabilities(
        self,
    ) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.uint16]]:
        """Every observed voxel with its occupancy probability (read under the map's ``fusion``; one pass over the
        storage, no second look-up).

        Returns
        -------
        keys : (N, 3) int32, voxel keys
        probability : (N,) float64
        log_odds : (N,) float64, multiples of ``2**-20``
        counts : (N,) uint16, >= 1
        """
        keys, log, counts = self.known_voxels()
        return keys, self._read(log, counts), log, counts

    def occupied_voxels(self) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Voxels in the occupied state.

        Returns
        -------
        keys : (N, 3) int32, voxel keys
        centers_w : (N, 3) float64, metres, world frame (z = 0.5 voxel in a 2-D map)
        probability : (N,) float64
        """
        keys, log, count = self.known_voxels()
        mine = self._states(log, count) == OCCUPIED
        keys = keys[mine]
        return keys, key_to_center(keys, self.voxel_size_m), self._read(log[mine], count[mine])

    def bounding_box(
        self, *, occupied_only: bool = False
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None:
        """Axis-aligned box of the known (or occupied) voxels: ``(min_w, max_w)`` (3,) metres, or None if empty."""
        keys = self.occupied_voxels()[0] if occupied_only else self.known_voxels()[0]
        if keys.shape[0] == 0:
            return None
        return keys.min(axis=0) * self.voxel_size_m, (keys.max(axis=0) + 1.0) * self.voxel_size_m

    def slice_image(
        self, *, layer: int | None = None, z_range_m: tuple[float, float] | None = None
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """A horizontal slice as an image of occupancy probabilities, NaN = unknown.

        Parameters
        ----------
        layer : int or None
            z key of the layer (0 for a 2-D map, the default there).
        z_range_m : (float, float) or None, metres
            Alternatively, every layer whose voxels overlap ``[z_min, z_max)``; a column then takes the
            largest probability among its known voxels (an obstacle anywhere in the range blocks it).

        Returns
        -------
        image : (H, W) float64, row = y key - y0, column = x key - x0; NaN where unknown
        extent_m : (4,) float64, ``(x_min, x_max, y_min, y_max)`` of the image's outer edges, metres
            (``imshow(image, origin="lower", extent=extent_m)``).
        """
        return horizontal_slice(self, layer, z_range_m)

    def first_occupied(
        self, origin_w: npt.ArrayLike, directions_w: npt.ArrayLike, *, max_range_m: float
    ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.int32], npt.NDArray[np.float64]]:
        """First occupied voxel along each ray; unknown voxels are passed through.

        Parameters
        ----------
        origin_w : (3,) float, metres, world frame ((2,) in a 2-D map)
        directions_w : (N, 3) float, world frame, non-zero (need not be unit)
        max_range_m : float, metres, > 0, distance searched along each ray

        Returns
        -------
        hit : (N,) bool
        keys : (N, 3) int32, the voxel hit (0 where no hit)
        distance_m : (N,) float64, metres from the origin to where the ray enters it (NaN where no hit)
        """
        origin = self._points(origin_w, "origin_w", single=True)
        directions = self._points(directions_w, "directions_w", as_direction=True)
        norm = np.sqrt((directions**2).sum(axis=1))
        if not np.all(norm > 0) or not np.all(np.isfinite(directions)):
            raise PrismapInputError("`directions_w` must be finite and non-zero")
        reach = check_positive(max_range_m, "max_range_m")
        unit = directions / norm[:, None]
        ray, keys, t_in, _ = crossed_voxels(origin, unit, np.full(unit.shape[0], reach), self.voxel_size_m)
        occupied = self.state_at_keys(keys) == OCCUPIED
        hit = np.zeros(unit.shape[0], dtype=bool)
        out_keys = np.zeros((unit.shape[0], 3), dtype=np.int32)
        distance = np.full(unit.shape[0], np.nan)
        ray, keys, t_in = ray[occupied], keys[occupied], t_in[occupied]
        first = np.unique(ray, return_index=True)[1]  # cells come in ray order, nearest first
        hit[ray[first]] = True
        out_keys[ray[first]] = keys[first]
        distance[ray[first]] = t_in[first]
        return hit, out_keys, distance

    # ------------------------------------------------------------------------------------- internals
    def _read(self, log, count):
        """``P(occupied)`` of stored log-odds and counts under the map's ``fusion``."""
        if self.fusion is None:
            return _probability(log)
        return self.fusion.probability(log, count, self.p0)

    def _states(self, log, count):
        prob = self._read(log, count)
        state = np.full(prob.shape, UNKNOWN, dtype=np.int8)
        known = count > 0
        state[known & (prob >= self.occupied_threshold)] = OCCUPIED
        state[known & (prob < self.free_threshold)] = FREE
        return state

    def _clamp_q(self):
        """Clamping bounds in fixed-point units (int64), the stored range ``[Q_MIN, Q_MAX]`` when clamping is off."""
        if self.clamp is None:
            return Q_MIN, Q_MAX
        return int(to_fixed(logit(self.clamp[0]))), int(to_fixed(logit(self.clamp[1])))

    def _kernel_store(self):
        """The map's storage as the kernels take it (:class:`~prismap.grid._kernel_args.MapStore`); reserving room
        replaces its arrays, so take it again after that."""
        return self._store.arrays(MapStore)

    def _apply_accumulator(self, code):
        acc, store = self._accumulator, self._store
        store.reserve(store.count_absent(acc.block_keys, len(acc)))
        lo, hi = self._clamp_q()
        _kernels_accumulate.apply_frame(
            self._kernel_store(), _accumulator.kernel_arrays(acc), code, lo, hi, self.prior_q
        )

    def _points(self, value, name, *, single=False, as_direction=False):
        """(N, 3) (or (3,) if ``single``) float64 world coordinates; a 2-D map takes (.., 2) and pads z."""
        shape = (self.ndim,) if single else (None, self.ndim)
        array = as_float_array(value, name, shape=shape, allow_nan=as_direction and not single)
        if single and not np.all(np.isfinite(array)):
            raise PrismapInputError(f"`{name}` must be finite; got {array.tolist()}")
        if self.ndim == 2:
            pad = 0.0 if as_direction else 0.5 * self.voxel_size_m
            array = np.concatenate([array, np.full((*array.shape[:-1], 1), pad)], axis=-1)
        return np.ascontiguousarray(array)

    def _keys(self, keys):
        keys = check_keys(keys, self.voxel_size_m)
        if self.ndim == 2 and np.any(keys[:, 2] != 0):
            raise PrismapInputError("a 2-D map has one layer: `keys` must have z key 0")
        return keys

    def __repr__(self):
        return (
            f"OccupancyMap(voxel_size_m={self.voxel_size_m}, p0={self.p0}, ndim={self.ndim}, "
            f"clamp={self.clamp}, fusion={self.fusion}, known={self.n_known}, frames={self.n_frames})"
        )
