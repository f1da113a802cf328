"""numba kernels of a PRISM table's influence nodes: per level of a ray's success posterior ``rho``, the first node
from which no later cell of the ray moves by ``influence_epsilon`` (docs/SENSOR_MODELS.md, "The influence depth of
a blended ray").

Blended by ``rho``, a cell whose failure-free ratio ``R`` has ``|R - 1|`` and ``|1/R - 1|`` at most ``B`` moves by
at most ``log(1 + rho B)``. A table bounds ``B`` two ways from a cell's start ``a``: for a cell of any length,
``e^{-lam (a - z0)} sup_{t >= a} g(t) / C(a)`` (the march's, ``_kernels_march._march``), and for a cell of at most
``L`` metres of depth, ``e^{lam L} M(a) / C(a)`` with ``M(a) = sup_{t >= a} e^{-lam (t - z0)} g(t)``, far tighter
in front of a distant measurement, where the first bound takes the prior at ``a`` and ``g`` at its peak
(:func:`tight_influence_nodes`).
"""

import math

import numba as nb
import numpy as np

from prismap.sensor_models._kernel_args import Geometry
from prismap.sensor_models._kernels_march import _log_sup_tail

INFLUENCE_LEVELS = 6
"""Influence nodes a table keeps of each bound: level ``k`` of the bound for cells of any length has ``B`` below
``4^k (e^epsilon - 1)`` (a ray with ``rho <= 4^-k``), level ``k`` of the bound for short cells
``e^{-lam L} 4^(k - 1) (e^epsilon - 1)`` (a ray with ``rho e^{lam L} <= 4^(1 - k)``)."""
INFLUENCE_LEVEL_STEP = math.log(4.0)
"""Log of the factor between the bounds of successive influence levels."""


@nb.njit(cache=True, nogil=True)
def level_bounds(log_eps_bound):
    """Bounds on a later cell's ``log |R - 1|`` of each level of the bound for cells of any length (the march's
    ``log_eps_bounds``: ``_kernels_march._march``), from ``log(expm1(epsilon))``."""
    return log_eps_bound + INFLUENCE_LEVEL_STEP * np.arange(INFLUENCE_LEVELS)


@nb.njit(cache=True, nogil=True)
def tight_influence_nodes(z, log_c, log_far, lam, lam_slack, log_eps_bound, shift, geometry, mixture):
    """Per level ``k`` (:data:`INFLUENCE_LEVELS`), the first node ``i`` of a march such that every cell starting at
    ``a >= z[i]`` has ``M(a) / C(a) < 4^(k - 1) (e^epsilon - 1)`` for every rate the table serves; the last node
    when none has.

    ``M`` takes the slowest such rate, ``lam (1 - lam_slack)`` (the largest prior anywhere behind ``a``), and
    ``C`` the table's, lowered by the rate gap as the march's bound is (``C(a)`` of a rate ``lam (1 +- s)`` is at
    least ``min(1 - s, e^{-lam s (a - z0)})`` times it). On the panel ``[z_i, z_i+1]`` ``g`` is at most
    ``_kernels_march._log_sup_tail`` of the panel, the prior at most its value at ``z_i``, and past the last node
    ``g`` at most that of ``[z_n, z_max]`` or the far measurement's; a running maximum from the back makes the
    condition hold at every later node, and each panel takes its far end's rate gap.

    Parameters
    ----------
    z : (n + 1,) float64, metres of depth
        The march's nodes.
    log_c : (n + 1, 3) float64, log
        ``log C`` and its moments at the nodes (column 0 is read).
    log_far, lam, lam_slack, log_eps_bound, shift, geometry, mixture
        As ``_kernels_march.prism_march``'s.

    Returns
    -------
    (INFLUENCE_LEVELS,) int64, node indices
    """
    z0, z_max, fb, ku = geometry
    n = z.size - 1
    lam_lo = lam * (1.0 - lam_slack)
    slack = -math.log1p(-lam_slack)
    excess = np.empty(n + 1)
    suffix = -lam_lo * (z[n] - z0) + max(_log_sup_tail(z[n], shift, geometry, mixture), log_far)
    excess[n] = suffix + lam_slack * lam * (z_max - z0) + slack - log_c[n, 0] - log_eps_bound
    for i in range(n - 1, -1, -1):
        panel = _log_sup_tail(z[i], shift, Geometry(z0, z[i + 1], fb, ku), mixture)
        suffix = max(suffix, -lam_lo * (z[i] - z0) + panel)
        here = suffix + lam_slack * lam * (z[i + 1] - z0) + slack - log_c[i, 0] - log_eps_bound
        excess[i] = max(here, excess[i + 1])
    nodes = np.full(INFLUENCE_LEVELS, n, dtype=np.int64)
    for k in range(INFLUENCE_LEVELS):
        threshold = (k - 1) * INFLUENCE_LEVEL_STEP
        for i in range(n + 1):
            if excess[i] < threshold:
                nodes[k] = i
                break
    return nodes
