"""PRISM, the principled inverse sensor model (SENSOR_MODELS.md section 5): exact, direct and tabulated.

Under its assumptions (independent cells with a Poisson surface rate, the pixel sees the first surface,
disparity errors from one Gaussian mixture, a far measurement when nothing lies before ``z_max``) the
posterior of a cell ``[a, c]`` is ``P = (p_c C(a) + C(c) - C(a)) / Z``. Everything is computed from
``log C`` and ``log D = log(Z - C)`` so that nothing underflows.

References
----------
E. Kaufman, T. Lee, Z. Ai, "Bayesian occupancy grid mapping via an exact inverse sensor model", ACC 2016.
L. Matthies, S. Shafer, "Error modeling in stereo navigation", IEEE J. Robotics and Automation, 1987.
"""

from __future__ import annotations

import dataclasses
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from prismap._validate import as_float_array, check_positive, check_real
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.sensor_models import (
    _kernels_direct,
    _kernels_failure,
    _kernels_lookup,
    _kernels_pack,
)
from prismap.sensor_models._base import register_model
from prismap.sensor_models._failure import failure_floor, log_failure_posterior
from prismap.sensor_models._kernel_args import (
    Cells,
    ClassRuns,
    Geometry,
    Mixture,
    MixtureSet,
    TableSpec,
    mixture_set,
)
from prismap.sensor_models._kernels_pack import _LENGTH, _LOG_Z, _LOG_Z_1, _LOG_Z_2, _OFFSET
from prismap.sensor_models._params import RayModel
from prismap.sensor_models._prism_cache import _KEY_L_SPAN, _LAMBDA_STEP, TableCache, ray_tables
from prismap.sensor_models._prism_discrete import log_mean_likelihood
from prismap.sensor_models._prism_map_prior import map_prior_cells
from prismap.sensor_models._prism_reach import floor_depths, has_floor, influence_depths
from prismap.sensor_models._prism_spacing import (
    _COARSE_BELOW,
    _TABLE_STEP,
    coarse_ratio,
    spacing_profile,
)
from prismap.sensor_models._table_store import model_fingerprint, table_store

INFLUENCE_EPSILON = 1e-3
"""Default log-odds bound beyond the influence depth: every later cell has ``|increment| < epsilon``."""

TABLE_TOLERANCE = {"abs": 5e-3, "rel": 1e-3, "large": 50.0, "large_rel": 2e-2, "posterior": 5e-4}
"""Error bound of ``method="table"`` against ``method="direct"`` (disparities on the ``disparity_step_px`` grid,
any ray norm): ``|inc_table - inc_direct| <= abs + rel |inc_direct|`` where ``|inc_direct| <= large``
(posterior within e^-50 of 0 or 1), ``<= large_rel |inc_direct|`` beyond, and ``|P_table - P_direct| <=
posterior``. It includes the cut at the influence depth (``influence_epsilon``) and the rate term (a ray's
``lambda_z`` up to half a ``_LAMBDA_STEP`` from its table's in log). A map voxel's increment from one frame (policy
``mean`` or ``max-abs``) is then within the bound at the largest direct increment of its cells. Checked by
``tests/test_sensor_models_prism.py``, rays half-way between rate keys included (where the worst cells use under
half of each term), cells in a table's first two intervals, and whole frames in ray and projective mode. Not covered:
a cell whose ``1 - P`` is below about e^-30 because it spans the whole likelihood peak and ends past the influence
depth (a narrow one-Gaussian error at short range, or a cell tens of metres long): its ``D(c)`` then comes from the
table's four back intervals or its end's tail bound (e^-40 of ``C``; ``"direct"`` cuts its tail there too), and
the increment (30-50) is off by up to about 7 % (``P`` is 1 in float64 either way)."""

_QUAD_STEP = 0.25  # x-width of one Gauss-Legendre panel (x: one unit per prior e-fold or narrowest sigma)
_WIDE_EFOLDS = 0.5  # a table interval wider than fine (outside gaps) spans at most this many e-folds of the prior
MAX_TABLE_NODES = 1 << 20
"""Most nodes one table may need (32 MiB of float32 rows; see ``PrismModel._check_table_size``)."""
AUTO_TABLE_FLOOR_MB = 64.0
"""Least table cache budget (MiB) of a model with ``table_memory_mb=None``."""
_LAMBDA_SLACK = float(np.expm1(_LAMBDA_STEP / 2))  # relative rate gap a table's influence depth covers
_BUILD_THREADS = min(2, os.cpu_count() or 1)  # threads building one call's missing tables
_CHUNK_CELLS = 4096  # cells per look-up/exp/combine/log round: its 8 scratch arrays (228 KiB) stay in L2

PRIORS = ("p0", "map")
"""Values of PRISM's ``prior``: every cell at ``p0``, or each cell at the map's current probability."""

PASS_THROUGH = 0.0
"""PRISM's default chance that a ray crosses an occupied cell without meeting its surface (0: every occupied
cell stops the ray, the model of SENSOR_MODELS.md)."""

SOLID_DEPTH_M = 0.0
"""PRISM's default depth of solid behind every first surface (metres along the ray; 0: a surface is a sheet,
the model of SENSOR_MODELS.md)."""

OVERHANG_FRACTION = 0.25
"""PRISM's default share of the voxel overhang bound counted as occupied. Half the bound is its mean over
plane positions; but a plane through voxel centres then puts the voxel just in front of it exactly on the
boundary, where every frame adds an even chance of occupancy and the fused map grows a false layer in front
of walls. A quarter keeps most of the grazing floor and no such layer (docs/SENSOR_MODELS.md, "Voxel overhang")."""


@register_model
@dataclass(frozen=True, kw_only=True)
class PrismModel(RayModel):
    """PRISM: the exact posterior of a cell given one measured disparity, from a measured error GMM.

    Surfaces along a ray form a Poisson process of rate ``lambda = -ln(1 - p0) / voxel_size_m`` per metre
    of ray (``lambda_z = lambda |r|`` per metre of depth), starting at ``near_m``; the pixel sees the first
    one; ``d^ = f b / z* - doffs - e`` with ``e`` from ``error_model``; nothing before ``far_depth_m``
    gives a far measurement. ``cell_posteriors`` uses ``method``:

    - ``"table"`` (default): ``log(C/Z)`` and ``log(D/Z)`` tabulated per (``d^`` rounded to
      ``disparity_step_px``, ``lambda_z`` on a 10 % grid), cubic Hermite in
      ``x = lambda_z z - f b / (sigma_min z)`` with a second-order Taylor term in ``log lambda_z``, within
      :data:`TABLE_TOLERANCE` of ``"direct"``; tables are cached on the model (each :meth:`with_extra_noise` copy
      has its own; a conditioned model's share one), least recently used ones dropped beyond ``table_memory_mb``.
      The grid, the look-up and what a cell costs: docs/SENSOR_MODELS.md, "The tables".
    - ``"direct"``: quadrature ray by ray (8-point Gauss-Legendre panels of x-width 0.25) with every cell
      boundary a panel edge.

    Parameters
    ----------
    error_model : GaussianMixture
        Disparity error ``e = d_true - d_computed`` of the matcher (pixels).
    p0 : float in (0, 1), default 0.05
        Prior occupancy of a ``voxel_size_m`` cell: the scene's occupancy ratio, NOT 0.5 (see
        :func:`estimate_prior_from_likelihood`, :func:`prior_from_ground_truth`).
    near_m : float, metres, default 0.1
        ``z0``: no surface before this depth. Table size and build time grow like ``1 / near_m`` (the
        likelihood term of ``x``): setting it to the matcher's nearest depth ``f b / max_disparity`` saves
        most of both (0.5 m instead of 0.1 m: 5x fewer nodes).
    far_depth_m : float, metres, default 200
        ``z_max``: beyond it, the far measurement.
    method : {"table", "direct"}
    disparity_step_px : float, pixels, default 1/16
        Table key resolution (OpenCV's sub-pixel step).
    influence_epsilon : float, log-odds, default 1e-3
    table_memory_mb : float or None, MiB, default None
        Table cache budget; the tables one call needs are kept even beyond it. ``None``: the larger of
        :data:`AUTO_TABLE_FLOOR_MB` and :data:`AUTO_TABLE_CALLS` times the tables of the largest call so
        far. The integrators ask for a whole frame's rays at once (``influence_depth``) and then in chunks,
        so the cache then holds two frames' tables: a fixed budget below one frame's tables (tens to
        hundreds of MB on a street, 5-30 KB a table) rebuilds them chunk after chunk. A model whose
        tables could exceed :data:`MAX_TABLE_NODES` nodes (an error sigma far below the matcher's sub-pixel
        step, or a tiny ``near_m``) is refused on construction.
    overhang_fraction : float in [0, 1], default :data:`OVERHANG_FRACTION`
        A map's voxel is occupied when any part of a surface lies in it, and a ray seeing a floor or a
        wall at a grazing angle crosses such voxels before it meets the surface. Given each ray's voxel
        overhang ``o`` (``voxel_overhang_m``: the largest distance before the surface at which a crossed
        voxel can still hold part of the locally planar surface, computed by the grid from the disparity
        image's normals), the cell ``[a, c]`` is evaluated as ``[a, c' = c + overhang_fraction * o / |r|]``:
        the voxel holds part of the surface when the first surface lies within that stretch, and its prior
        is the stretch's (the same event), so ``P Z = p_c' C(a) + C(c') - C(a)`` and the increment is
        ``logit(P) - logit(p_c')``. 0 = the one-dimensional model of SENSOR_MODELS.md.
    pass_through : float in [0, 1), default :data:`PASS_THROUGH`
        The chance ``m`` that a ray crosses an occupied cell without stopping in it (a voxel holds any part
        of a solid: a table's edge, a pole's side). Each cell's likelihood ratio ``R`` becomes
        ``m + (1 - m) R``, so one ray's free evidence is at most ``-log m``; measure it from a ground truth
        with :meth:`prismap.sim.Scene3D.pass_through_ratio` (docs/SENSOR_MODELS.md, "Pass-through").
    solid_depth_m : float >= 0, metres along the ray, default :data:`SOLID_DEPTH_M`
        Surfaces are the faces of solids: behind the first surface the ray stays inside a solid for at least
        this distance, and a voxel holding any part of a solid is occupied. The cell ``[a, c']`` is then
        occupied when a surface lies in ``[a - solid_depth_m / |r|, c']`` (clipped at ``near_m``), which is the
        formula above on that stretch, with that stretch's prior in the increment. Measure it from a ground
        truth (``prismap.experiment``: the depth of solid behind 90 % of the noise-free rays' hits;
        docs/SENSOR_MODELS.md, "Solid depth"). Not with ``prior="map"``.
    prior : {"p0", "map"}, default "p0"
        The prior of the cells of a ray. ``"p0"``: every cell at ``p0`` (the formula above, by ``method``).
        ``"map"``: each cell at the map's current probability of its voxel (Kaufman et al. 2016; the
        grid hands it over as ``map_log_odds`` because :attr:`takes_map_prior`), so a frame's evidence is
        weighed against what earlier frames found. Each ray's cells must then tile it from the camera (ray
        casting; projective integration has no whole rays). The exact discrete posterior
        (:func:`~prismap.sensor_models._prism_map_prior.map_prior_cells`: ``g`` averaged uniformly in disparity over each cell, the
        prior rate beyond the ray's last cell); ``method`` and the tables are not used.
        docs/SENSOR_MODELS.md, "The map as prior".
    """

    name = "prism"
    error_model_use = "mixture"
    default_policy = "mean"
    error_model: GaussianMixture | None = None
    near_m: float = 0.1
    far_depth_m: float = 200.0
    method: str = "table"
    disparity_step_px: float = 1.0 / 16.0
    influence_epsilon: float = INFLUENCE_EPSILON
    table_memory_mb: float | None = None
    overhang_fraction: float = OVERHANG_FRACTION
    pass_through: float = PASS_THROUGH
    prior: str = "p0"
    solid_depth_m: float = SOLID_DEPTH_M
    _cache: "TableCache" = field(default=None, init=False, repr=False, compare=False)
    _widened: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    _table_spec: TableSpec = field(default=None, init=False, repr=False, compare=False)
    _kernel_geometry: Geometry = field(default=None, init=False, repr=False, compare=False)
    _kernel_mixture: Mixture = field(default=None, init=False, repr=False, compare=False)
    _kernel_models: MixtureSet = field(default=None, init=False, repr=False, compare=False)  # _kernel_mixture's set
    _table_tag: int = field(default=0, init=False, repr=False, compare=False)  # its keys' offset in a shared cache
    _store_fingerprint: int = field(default=0, init=False, repr=False, compare=False)  # its tables' in the store

    def __post_init__(self):
        super().__post_init__()
        if not isinstance(self.error_model, GaussianMixture):
            raise PrismapInputError(
                "prism: `error_model` must be a GaussianMixture (fit one with prismap.gmm); "
                f"got {type(self.error_model).__name__}"
            )
        near = check_positive(self.near_m, "near_m")
        far = check_positive(self.far_depth_m, "far_depth_m")
        if far <= near:
            raise PrismapInputError(f"prism: need near_m < far_depth_m; got {near} and {far}")
        if self.method not in ("table", "direct"):
            raise PrismapInputError(f"prism: `method` must be 'table' or 'direct'; got {self.method!r}")
        object.__setattr__(self, "near_m", near)
        object.__setattr__(self, "far_depth_m", far)
        object.__setattr__(self, "disparity_step_px", check_positive(self.disparity_step_px, "disparity_step_px"))
        object.__setattr__(self, "influence_epsilon", check_positive(self.influence_epsilon, "influence_epsilon"))
        object.__setattr__(self, "overhang_fraction", _share(self.overhang_fraction, "overhang_fraction", one=True))
        object.__setattr__(self, "pass_through", _share(self.pass_through, "pass_through", one=False))
        if self.prior not in PRIORS:
            raise PrismapInputError(f"prism: `prior` must be one of {list(PRIORS)}; got {self.prior!r}")
        solid = check_real(self.solid_depth_m, "solid_depth_m", minimum=0.0)
        if solid > 0 and self.prior == "map":
            raise PrismapInputError(f"prism: `solid_depth_m` ({solid:g} m) works with prior='p0' only; got prior='map'")
        object.__setattr__(self, "solid_depth_m", solid)
        if self.table_memory_mb is None:
            budget = None
        else:
            object.__setattr__(self, "table_memory_mb", check_positive(self.table_memory_mb, "table_memory_mb"))
            budget = int(self.table_memory_mb * 2**20)
        object.__setattr__(self, "_cache", TableCache(budget, int(AUTO_TABLE_FLOOR_MB * 2**20)))
        self._check_table_size()
        edges, ratios = spacing_profile(self.error_model)  # how every table of this model spaces its nodes
        spec = TableSpec(
            h=_TABLE_STEP,
            log_eps_bound=float(np.log(np.expm1(self.influence_epsilon))),
            lam_slack=_LAMBDA_SLACK,
            coarse_ratio=coarse_ratio(self.error_model),
            coarse_below=_COARSE_BELOW,
            edges=edges,
            ratios=ratios,
            wide_efolds=_WIDE_EFOLDS,
            log_floor=self._least_floor_level(),
        )
        object.__setattr__(self, "_table_spec", spec)
        m = self.error_model  # the kernels' arguments, made once: a conditioned frame makes hundreds of calls
        log_wn = np.log(m.weights) - np.log(m.sigmas) - 0.5 * np.log(2 * np.pi)
        object.__setattr__(
            self, "_kernel_mixture", Mixture(log_wn, np.ascontiguousarray(m.means), np.ascontiguousarray(m.sigmas))
        )
        object.__setattr__(
            self, "_kernel_geometry", Geometry(self.near_m, self.far_depth_m, self.focal_baseline, self._ku())
        )
        object.__setattr__(self, "_kernel_models", mixture_set([self._kernel_mixture], [self._ku()]))
        key_inputs = (self.rate_per_m, self.doffs_px, self.disparity_step_px, _LAMBDA_STEP, self.far_depth_m)
        fingerprint = model_fingerprint(self._kernel_geometry, spec, self._kernel_mixture, key_inputs, m.to_dict())
        object.__setattr__(self, "_store_fingerprint", fingerprint)

    def _check_table_size(self):
        """Refuse, before any table is built, a model whose tables could exceed :data:`MAX_TABLE_NODES`.

        A table's grid runs in ``x = lambda_z z - f b / (sigma_min z)`` with a node every
        ``_TABLE_STEP`` in ``x``, so it holds at most ``x_span / 0.5`` nodes with
        ``x_span = f b / (sigma_min near_m) + lambda |r| far_depth_m`` (|r| <= 2, a 120 degree view). Without the
        bound an error sigma of 1e-4 px or a sub-millimetre ``near_m`` asks for gigabytes and minutes per table.
        """
        x_span = self._ku() / self.near_m + 2.0 * self.rate_per_m * self.far_depth_m
        max_nodes = x_span / _TABLE_STEP
        if max_nodes > MAX_TABLE_NODES:
            sigma_min = float(self.error_model.sigmas.min())
            smallest = self.focal_baseline / (self.near_m * MAX_TABLE_NODES * _TABLE_STEP)
            raise PrismapInputError(
                f"prism: an error sigma of {sigma_min:.3g} px with near_m {self.near_m:g} m and f*b "
                f"{self.focal_baseline:.4g} px*m allows tables of up to {max_nodes:.3g} nodes, more than "
                f"MAX_TABLE_NODES = {MAX_TABLE_NODES}; sigmas must be >= {smallest:.3g} px here (or raise near_m)"
            )

    def _least_floor_level(self):
        """The least of the rays' floor levels (:meth:`_table_cells`): ``log(eps)`` (:func:`failure_floor`, the least
        failure posterior) or, with a pass-through chance ``m``, ``log m``; ``-inf`` without matcher failures (no
        floor, and tables start at ``near_m``)."""
        eps = failure_floor(self.error_model)
        if self.error_model.failure_weight == 0 or eps <= 0:
            return -np.inf
        return float(self._floor_levels(np.log([eps]))[0])

    def _floor_levels(self, log_fail):
        """Each ray's floor level from its ``log(1 - rho)`` ((R,)): that, or ``log m`` with a pass-through chance
        ``m`` (the thinned ratio at the floor is ``m``; ``_kernels_failure.floor_depth``)."""
        return log_fail if self.pass_through == 0 else np.full(log_fail.size, np.log(self.pass_through))

    # ------------------------------------------------------------------ derived constants
    @property
    def takes_voxel_overhang(self) -> bool:
        """True when ``overhang_fraction > 0``: the grid then computes each ray's voxel overhang."""
        return self.overhang_fraction > 0

    @property
    def takes_map_prior(self) -> bool:
        """True when ``prior == "map"``: the grid then passes each cell's current map log-odds."""
        return self.prior == "map"

    @property
    def rate_per_m(self) -> float:
        """``lambda``: surfaces per metre of ray, from ``p0`` and ``voxel_size_m``."""
        return -np.log1p(-self.p0) / self.voxel_size_m

    def _mixture(self):
        """The error mixture as the kernels take it (made on construction)."""
        return self._kernel_mixture

    def _ku(self):
        return self.focal_baseline / float(self.error_model.sigmas.min())

    def _geometry(self):
        """The depth range and disparity scales as the kernels take them (made on construction)."""
        return self._kernel_geometry

    def _log_far(self, disparity):
        u_max = self.focal_baseline / self.far_depth_m
        return log_mean_likelihood(0.0, u_max, disparity, self.error_model, self.doffs_px)

    # ------------------------------------------------------------------ interface
    def cell_posteriors(
        self,
        disparity_px: npt.ArrayLike,
        ray_norm: npt.ArrayLike,
        ray_of_cell: npt.ArrayLike,
        depth_start_m: npt.ArrayLike,
        depth_end_m: npt.ArrayLike,
        *,
        method: str | None = None,
        voxel_overhang_m: npt.ArrayLike | None = None,
        map_log_odds: npt.ArrayLike | None = None,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Posterior and increment per cell (see :class:`InverseSensorModel`); ``method`` overrides the model's.

        ``voxel_overhang_m`` ((R,) float, metres along each ray, or None = 0): each cell ``[a, c]`` is
        evaluated as ``[a, c + overhang_fraction * overhang / |r|]`` (see the class).
        ``map_log_odds`` ((C,) float, log-odds of each cell's voxel before this frame, or None = every voxel at
        ``p0``): the cells' priors when ``prior == "map"``; refused otherwise.
        """
        method = self.method if method is None else method
        disparity, norm, rays, start, end, stretch, lam = self._prepared(
            disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m, voxel_overhang_m
        )
        if self.prior == "map":
            result, map_rate = map_prior_cells(self, lam, disparity, norm, rays, start, end, stretch, map_log_odds)
            # each cell's prior rate for the failure blend; without a map every cell is at p0: lam's rate
            cell_rate = map_rate if map_log_odds is not None else lam[rays]
            method = "table"
        elif map_log_odds is not None:
            raise PrismapInputError("prism: `map_log_odds` is used only with prior='map'; this model has prior='p0'")
        elif method == "direct":
            order = np.argsort(rays, kind="stable")
            ray_start = np.searchsorted(rays[order], np.arange(disparity.size + 1))
            result = _kernels_direct.prism_direct_cells(
                disparity + self.doffs_px,
                lam,
                self._log_far(disparity),
                order,
                ray_start,
                start,
                end + stretch[rays],
                _QUAD_STEP,
                self.pass_through,
                self._geometry(),
                self._mixture(),
            )
            cell_rate = lam[rays]
        elif method == "table":  # the failure blend, if any, inside the look-up's blocks
            tables = self._tables_for(disparity, norm)
            return self._table_cells(lam, rays, start, end, stretch, tables, self._log_failure(self._ray_log_z(tables)))
        else:
            raise PrismapInputError(f"prism: `method` must be 'table' or 'direct'; got {method!r}")
        if self.error_model.failure_weight == 0:
            return result
        if method == "table":  # prior="map": Z is the tables' marginal under p0
            log_fail, log_ok = self._log_failure(self._ray_log_z(self._tables_for(disparity, norm)))
        else:
            log_z = _kernels_direct.prism_log_evidence(
                disparity + self.doffs_px, lam, self._log_far(disparity), _QUAD_STEP, self._geometry(), self._mixture()
            )
            log_fail, log_ok = log_failure_posterior(self.error_model, log_z)
        return _kernels_failure.blend_ray_cells(
            result[1], rays, start, end + stretch[rays], cell_rate, self.near_m, self.far_depth_m, log_fail, log_ok
        )

    def _prepared(self, disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m, voxel_overhang_m):
        """The validated arrays of :meth:`cell_posteriors` (``disparity, norm, rays, start, end``), each ray's
        ``stretch`` (depth metres added to the end of its cells: its overhang share) and rate ``lam`` (per metre of
        depth); ``start`` moved back by the solid depth."""
        disparity, norm, rays, start, end = self._validated(
            disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m
        )
        stretch = self._stretch(norm, voxel_overhang_m)
        lam = self.rate_per_m * norm
        if self.solid_depth_m > 0:  # the stretch [a - solid / |r|, c'] (cells already before near_m stay as they are)
            start = np.minimum(start, np.maximum(start - self.solid_depth_m / norm[rays], self.near_m))
        return disparity, norm, rays, start, end, stretch, lam

    def _stretch(self, norm, voxel_overhang_m):
        """Each ray's stretch: depth metres added to the end of its cells, its share of its voxel overhang."""
        if voxel_overhang_m is None or self.overhang_fraction == 0:
            return np.zeros(norm.size)
        overhang = as_float_array(voxel_overhang_m, "voxel_overhang_m", shape=(norm.size,), allow_nan=False)
        if overhang.size and overhang.min() < 0:
            raise PrismapInputError(f"prism: `voxel_overhang_m` must be >= 0; got minimum {overhang.min()!r}")
        return self.overhang_fraction * overhang / norm

    def floor_depth(
        self, disparity_px: npt.ArrayLike, ray_norm: npt.ArrayLike, *, voxel_overhang_m: npt.ArrayLike | None = None
    ) -> npt.NDArray[np.float64] | None:
        """Per ray, the depth (metres) up to which a cell ending there is at the ray's failure floor: its increment
        is the floor's, a function of the ray and the cell's length alone, so the grid may sample such cells
        (what :meth:`influence_and_floor_depths` gives beside the influence depth, for ray mode); None when the
        look-up has no floor (``method="direct"``, ``prior="map"``).
        """
        if has_floor(self):
            return self.influence_and_floor_depths(disparity_px, ray_norm, voxel_overhang_m=voxel_overhang_m)[1]
        return None

    def influence_and_floor_depths(
        self, disparity_px: npt.ArrayLike, ray_norm: npt.ArrayLike, *, voxel_overhang_m: npt.ArrayLike | None = None
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64] | None]:
        """:meth:`influence_depth` and :meth:`floor_depth` of the rays from one look-up of their tables (what ray
        mode asks: ``grid.SensorModel``)."""
        disparity = as_float_array(disparity_px, "disparity_px", ndim=1, allow_nan=False)
        norm = as_float_array(ray_norm, "ray_norm", shape=(disparity.size,))
        terms = self._ray_terms(disparity, norm)
        floor = floor_depths(self, terms, self._kernel_models, norm, voxel_overhang_m)
        return influence_depths(self, terms, self._kernel_models, norm, voxel_overhang_m), floor

    def _ray_terms(self, disparity, norm):
        """What the floor and influence depths of the rays take (``_prism_reach``): their tables
        (:meth:`_tables_for`), ``log Z`` (:meth:`_ray_log_z`), failure terms (:meth:`_log_failure`) and model rows (0)."""
        tables = self._tables_for(disparity, norm)
        log_z = self._ray_log_z(tables)
        return tables, log_z, self._log_failure(log_z), np.zeros(disparity.size, dtype=np.int64)

    def _log_failure(self, log_z):
        """``log(1 - rho)`` and ``log(rho)`` of each ray, its failure posterior given its ``Z`` (``log_z``, from its
        table: :meth:`_ray_log_z`; :func:`~prismap.sensor_models.log_failure_posterior`), or two empty arrays when the
        error model has no failures. A cell's ``(posterior, increment)`` is then the Gaussians' PRISM blended with
        its prior by its ray's (:func:`prismap.sensor_models.blend_increments`; docs/SENSOR_MODELS.md, "Matcher
        failures")."""
        if self.error_model.failure_weight == 0:
            return np.empty(0), np.empty(0)
        return log_failure_posterior(self.error_model, log_z)

    @staticmethod
    def _ray_log_z(tables):
        """Each ray's ``log Z`` ((R,) float64) from its table (:meth:`_tables_for`): the table's, moved to the ray's
        rate by the nodes' Taylor term (meta columns ``log_z_1``, ``log_z_2``), as the look-up takes it."""
        table, delta, meta, _ = tables
        return meta[table, _LOG_Z] + delta * (meta[table, _LOG_Z_1] + 0.5 * delta * meta[table, _LOG_Z_2])

    def influence_depth(
        self, disparity_px: npt.ArrayLike, ray_norm: npt.ArrayLike, *, voxel_overhang_m: npt.ArrayLike | None = None
    ) -> npt.NDArray[np.float64]:
        """Depth beyond which every cell's ``|logit(P) - logit(p_c)| < influence_epsilon`` (metres), per ray.

        From the bound ``|increment(a)| <= log(1 + e^{-lambda (a - z0)} sup_{t >= a} g(t) / C(a))``, which
        holds for a cell of any length starting at ``a``; a cell's evaluated stretch starts ``solid_depth_m / |r|``
        before it, so the depth moves back by that much; capped at ``far_depth_m``. 0 for a silent ray, one whose
        failure posterior leaves every cell of at most a voxel's diagonal (plus its stretch; ``voxel_overhang_m`` as
        :meth:`cell_posteriors` takes it) within ``influence_epsilon`` of its prior (``_kernels_failure.silent_rays``;
        docs/SENSOR_MODELS.md, "Silent rays").
        """
        disparity = as_float_array(disparity_px, "disparity_px", ndim=1, allow_nan=False)
        norm = as_float_array(ray_norm, "ray_norm", shape=(disparity.size,))
        return influence_depths(self, self._ray_terms(disparity, norm), self._kernel_models, norm, voxel_overhang_m)

    def with_extra_noise(self, sigma_px: float) -> PrismModel:
        """A copy whose error model is ``error_model.widened(sigma_px)``.

        Copies are memoised per ``sigma_px``, so their tables survive from frame to frame.
        """
        extra = check_positive(sigma_px, "sigma_px")
        if extra not in self._widened:
            self._widened[extra] = dataclasses.replace(self, error_model=self.error_model.widened(extra))
        return self._widened[extra]

    # ------------------------------------------------------------------ tables
    def _table_cells(self, lam, rays, start, end, stretch, tables, log_failure, runs=None, models=None):
        """Tabulated posteriors and increments of the cells ``[start, end + stretch[rays]]`` from the rays'
        ``tables`` (:meth:`_tables_for`; ``_kernels_lookup.prism_table_cells``: table look-ups, vectorised exp,
        combination, vectorised log), blended by the rays' failure posteriors ``log_failure``
        (:meth:`_log_failure`). Each ray's floor depth comes from its floor level (:meth:`_floor_levels`). The
        cells come in ``runs`` of rows of the mixture set ``models`` (``ClassRuns``, ``MixtureSet``: a conditioned
        model's classes in one call); None: all this model's."""
        log_fail, log_ok = log_failure
        log_floor = self._floor_levels(log_fail)
        if runs is None:
            runs, models = ClassRuns(np.array([0, start.size]), np.zeros(1, dtype=np.int64)), self._kernel_models
        return _kernels_lookup.prism_table_cells(
            lam,
            stretch,
            tables,
            Cells(rays, start, end),
            runs,
            _QUAD_STEP,
            _CHUNK_CELLS,
            self.pass_through,
            np.exp(log_ok),
            np.exp(log_fail),
            log_floor,
            self._geometry(),
            models,
        )

    def _tables_for(self, disparity, norm):
        """:func:`~prismap.sensor_models._prism_cache.ray_tables` of the rays (this model's tag on every key)."""
        tag, step = self._table_tag, self.disparity_step_px
        tags = np.full(disparity.size, tag, dtype=np.int64)
        return ray_tables(self._cache, lambda keys: self._build_tables(keys - tag), disparity, norm, tags, step)

    def _build_tables(self, keys):
        """The tables of ``keys`` ((K,) int64, untagged): ``nodes`` (N, ``_kernels_pack.TABLE_COLUMNS``)
        float32 back to back (an array, or a list of arrays read back to back: :meth:`TableCache.rows` copies them
        in) and their ``meta`` rows (K, ``len(_kernels_pack.META_COLUMNS)``), ``offset`` from the first row of
        ``nodes``: read from the table store where it has them (``_table_store``: tables of earlier runs), the others
        built (:meth:`_new_tables`) and handed to the store."""
        keys = np.asarray(keys, dtype=np.int64)
        key_d, key_l = np.divmod(keys, _KEY_L_SPAN)
        disparity = key_d * self.disparity_step_px
        lam = self.rate_per_m * np.exp(_kernels_pack.rate_key_centre(key_l, _LAMBDA_STEP))
        shift = disparity + self.doffs_px
        store = table_store()
        if store is None:
            return self._new_tables(shift, lam, self._log_far(disparity))
        fingerprint = self._store_fingerprint
        found, stored_nodes, stored_meta = store.fetch(fingerprint, keys, lam, shift)
        if found.all():
            return stored_nodes, stored_meta
        new = ~found
        nodes, meta = self._new_tables(shift[new], lam[new], self._log_far(disparity[new]))
        store.add(fingerprint, keys[new], nodes, meta)
        if not found.any():
            return nodes, meta
        meta[:, _OFFSET] += sum(part.shape[0] for part in stored_nodes)
        both = np.empty((keys.size, meta.shape[1]))
        both[found], both[new] = stored_meta, meta
        return [*stored_nodes, *(nodes if isinstance(nodes, list) else [nodes])], both

    def _new_tables(self, shift, lam, log_far):
        """Build the tables of ``(shift, lam, log_far)`` ((K,) each; ``_kernels_pack.prism_tables``), in
        :data:`_BUILD_THREADS` threads for a large batch (``nodes`` then a list of each thread's arrays); as
        :meth:`_build_tables` returns them."""
        geometry, mixture, spec = self._geometry(), self._mixture(), self._table_spec

        def build(share):
            return _kernels_pack.prism_tables(shift[share], lam[share], log_far[share], geometry, spec, mixture)

        n = shift.size
        if n < 2 * _BUILD_THREADS:
            nodes, meta = build(slice(None))
        else:
            # One share of the keys a thread (prism_tables releases the GIL), interleaved: neighbouring keys
            # cost about the same. The calling thread builds the first share.
            others = [_build_pool().submit(build, slice(t, None, _BUILD_THREADS)) for t in range(1, _BUILD_THREADS)]
            shares = [build(slice(0, None, _BUILD_THREADS))] + [share.result() for share in others]
            meta = np.empty((n, shares[0][1].shape[1]))
            first = 0
            for t, (share_nodes, share_meta) in enumerate(shares):
                share_meta[:, _OFFSET] += first
                meta[t::_BUILD_THREADS] = share_meta
                first += share_nodes.shape[0]
            nodes = [share_nodes for share_nodes, _ in shares]  # the cache copies them in; no concatenation
        if n and meta[:, _LENGTH].min() < 2:
            raise PrismapInputError(
                f"prism: near_m={self.near_m} to far_depth_m={self.far_depth_m} is too short to tabulate"
            )
        return nodes, meta


_POOL: dict[int, ThreadPoolExecutor] = {}
_POOL_LOCK = threading.Lock()


def _build_pool():
    """The process's threads that build tables beside the calling thread (one pool per process id: a forked
    worker makes its own), kept for the process's life so that a call per class and frame starts no thread."""
    pid = os.getpid()
    with _POOL_LOCK:  # two walking threads may ask first at once
        if pid not in _POOL:
            _POOL.clear()
            _POOL[pid] = ThreadPoolExecutor(_BUILD_THREADS - 1, thread_name_prefix="prismap-tables")
        return _POOL[pid]


def _share(value, name, *, one):
    """``float(value)`` if it is a number in [0, 1] (``one``) or [0, 1), else raise naming ``name``."""
    number = check_real(value, name, minimum=0.0)
    if number > 1 or (number == 1 and not one):
        raise PrismapInputError(f"prism: `{name}` must lie in [0, 1{']' if one else ')'}; got {value!r}")
    return number
