"""Argument bundles of PRISM's numba kernels: the error mixture, the depth range with its disparity scales, and
the node spacing of a table, each built once by :class:`~prismap.sensor_models.PrismModel` and passed down
unchanged; and a call's cells in runs of one model (:class:`ClassRuns`, from :func:`cell_runs`). numba compiles a
``NamedTuple`` of scalars or of arrays like separate arguments.
"""

from typing import NamedTuple

import numpy as np


class Mixture(NamedTuple):
    """The disparity error mixture ``g(e) = sum_j w_j N(e; mu_j, sigma_j)`` in the form the kernels evaluate.

    Attributes
    ----------
    log_wn : (J,) float64, log(1/pixel)
        ``log(w_j / (sigma_j sqrt(2 pi)))``: each component's log density at its mean.
    means : (J,) float64, pixels, C-contiguous
        ``mu_j``, component means of the error ``e = d_true - d_computed``.
    sigmas : (J,) float64, pixels, C-contiguous
        ``sigma_j > 0``, component standard deviations.
    """

    log_wn: np.ndarray
    means: np.ndarray
    sigmas: np.ndarray


class Geometry(NamedTuple):
    """Where PRISM places surfaces along a ray, and how depth maps to disparity there.

    Attributes
    ----------
    z0 : float, metres of depth
        ``near_m``: no surface before this depth; the prior's survival starts here.
    z_max : float, metres of depth
        ``far_depth_m``: nothing before it gives the far measurement.
    fb : float, pixel metres
        Focal length times baseline: a surface at depth ``z`` has true disparity ``fb / z`` (plus ``doffs``, which
        the kernels carry in each ray's ``shift``).
    ku : float, pixel metres
        ``fb / sigma_min`` (narrowest component's sigma): the likelihood term of the integration coordinate
        ``x(z) = lam z - ku / z``, which grows by one unit per prior e-fold and per narrowest sigma of disparity.
    """

    z0: float
    z_max: float
    fb: float
    ku: float


class MixtureSet(NamedTuple):
    """The error mixtures of several PRISM models, one row each, for a look-up over rays of any of them
    (``_kernels_lookup.prism_table_cells``; a conditioned model's plain and class models).

    Attributes
    ----------
    log_wn, means, sigmas : (K, J) float64
        Row ``k``'s first ``size[k]`` entries are model ``k``'s :class:`Mixture`; the rest is padding, never read.
    size : (K,) int64
        Components of each model.
    ku : (K,) float64, pixel metres
        Each model's :attr:`Geometry.ku` (the other :class:`Geometry` fields are shared).
    """

    log_wn: np.ndarray
    means: np.ndarray
    sigmas: np.ndarray
    size: np.ndarray
    ku: np.ndarray


def mixture_set(mixtures, kus):
    """The :class:`MixtureSet` of :class:`Mixture` s ``mixtures`` and their ``Geometry.ku`` s ``kus``."""
    width = max(mixture.means.size for mixture in mixtures)
    rows = [np.zeros((len(mixtures), width)) for _ in range(3)]
    for k, mixture in enumerate(mixtures):
        for row, column in zip(rows, mixture):
            row[k, : column.size] = column
    size = np.array([mixture.means.size for mixture in mixtures], dtype=np.int64)
    return MixtureSet(*rows, size, np.asarray(kus, dtype=np.float64))


class ClassRuns(NamedTuple):
    """Runs of consecutive cells whose rays share one model of a :class:`MixtureSet`.

    Attributes
    ----------
    first_cell : (n + 1,) int64
        Run ``i`` holds cells ``first_cell[i]`` to ``first_cell[i + 1] - 1``.
    model : (n,) int64
        Each run's row of the :class:`MixtureSet`.
    """

    first_cell: np.ndarray
    model: np.ndarray


def cell_runs(ray_class, ray_of_cell):
    """The cells grouped by their ray's class: ``(order, ClassRuns)``, the runs' first cells and classes in the
    order ``order`` puts the cells in (None: as they come). Cells of one class (a ray-mode chunk), or of rays in
    class order with the cells in ray order (a projective part), are runs as they come, found from the rays without
    a pass over the cells; otherwise the cells go in class order (stable: a ray's cells keep their order)."""
    n = ray_of_cell.size
    if not n:
        return None, ClassRuns(np.zeros(1, dtype=np.int64), np.empty(0, dtype=np.int64))
    if ray_class.min() == ray_class.max():
        return None, ClassRuns(np.array([0, n]), ray_class[:1])
    if np.all(ray_class[1:] >= ray_class[:-1]) and np.all(ray_of_cell[1:] >= ray_of_cell[:-1]):
        first_ray = np.concatenate(([0], np.flatnonzero(ray_class[1:] != ray_class[:-1]) + 1))
        first_cell = np.searchsorted(ray_of_cell, first_ray)
        used = np.flatnonzero(np.diff(np.append(first_cell, n)) > 0)  # classes with cells
        return None, ClassRuns(np.append(first_cell[used], n), ray_class[first_ray[used]])
    cell_class = ray_class[ray_of_cell]
    order = np.argsort(cell_class, kind="stable")
    cell_class = cell_class[order]
    first_cell = np.concatenate(([0], np.flatnonzero(cell_class[1:] != cell_class[:-1]) + 1))
    return order, ClassRuns(np.append(first_cell, n), cell_class[first_cell])


class TableSpec(NamedTuple):
    """How a PRISM table spaces its nodes in ``x`` and where it cuts its march (``_kernels_table.prism_table``).

    Attributes
    ----------
    h : float, x units
        Fine node spacing, also the x-width of the march's fine panels (``_prism_spacing._TABLE_STEP``).
    log_eps_bound : float, log
        ``log(expm1(influence_epsilon))``: the influence node is the first past which every cell's increment is
        below ``influence_epsilon`` (log-odds).
    lam_slack : float, dimensionless
        Relative rate gap ``s`` the influence node covers: it holds for every rate in ``[lam (1 - s), lam (1 + s)]``
        (the rays that share the table).
    coarse_ratio : int, fine nodes per coarse node
        Spacing of the coarse front, at least ``coarse_ratio h`` (``_prism_spacing.coarse_ratio``; wider for
        fronts of more than ``_kernels_table.MAX_COARSE`` nodes).
    coarse_below : float, log
        ``log(C/Z)`` below which the coarse front's endpoint asymptotic of ``C`` is used.
    edges : (M + 1,) float64, pixels
        The spacing profile's piece boundaries in the error ``e = d_true - d^``, descending from ``inf`` to
        ``-inf`` (``_prism_spacing.spacing_profile``).
    ratios : (M,) int64, fine nodes per node
        Each piece's spacing, 0 for a gap between error components (two panels span it).
    wide_efolds : float, prior e-folds
        Most e-folds of the prior one interval wider than ``h`` may span (outside gaps).
    log_floor : float, log
        The least floor level of the model's rays (``log(eps)``, :func:`~prismap.sensor_models.failure_floor`, or
        ``log`` of the pass-through chance), ``-inf`` without matcher failures: a table starts where every cell
        before is at its ray's failure floor (``_kernels_failure.table_start``).
    """

    h: float
    log_eps_bound: float
    lam_slack: float
    coarse_ratio: int
    coarse_below: float
    edges: np.ndarray
    ratios: np.ndarray
    wide_efolds: float
    log_floor: float


class RayTables(NamedTuple):
    """Each ray's PRISM table and the cache arrays it indexes (``PrismModel._tables_for``).

    Attributes
    ----------
    table : (R,) int64
        Each ray's row of ``meta``.
    delta : (R,) float64, log
        ``log(lam_ray / lam_table)``: the ray's rate against its table's.
    meta : (K, len(_kernels_pack.META_COLUMNS)) float64
        The tables' metadata, one row per table.
    nodes : (N, _kernels_pack.TABLE_COLUMNS) float32
        The tables' rows, back to back.
    """

    table: np.ndarray
    delta: np.ndarray
    meta: np.ndarray
    nodes: np.ndarray


class Cells(NamedTuple):
    """Cells of rays: stretches of depth, a ray's cells consecutive and nearest first.

    Attributes
    ----------
    ray_of_cell : (C,) int64
        Each cell's ray.
    start, end : (C,) float64, metres of depth
        Each cell's first and last depth.
    """

    ray_of_cell: np.ndarray
    start: np.ndarray
    end: np.ndarray
