"""The map's log-odds in fixed point, so that sums of frames do not depend on their order.

A voxel stores ``q = round(l / LOG_ODDS_STEP)`` as int64 (as Bonxai stores its log-odds in integers).
Each frame adds one rounded integer per voxel, and a merge adds two maps' integers; integer addition is
associative, so integrating frames 1..n in one map and merging maps of any split of them (sequential,
or Dask with any number of workers and any chunking) give bit-identical maps. Float log-odds could not:
their sum depends on the order of the additions.

The step is ``2**-20`` (below float32's resolution at ``|l| >= 8``). A saturating sum is not associative
(``clamp(clamp(a + b) + c) != clamp(a + clamp(b + c))``), and PRISM drives near-camera voxels past any
small bound in one frame, so the bound is far away: one frame's step is bounded to ``+-STEP_MAX``
(``2**20`` log-odds) before it is added, and sums saturate only at ``+-2**53`` units (``2**33`` log-odds,
8.6e9), where float64 stops holding every integer. Sums are exact and order-free below that: 8192 frames
of the largest step in one voxel, far beyond any model's evidence (PRISM's strongest increments are a few
thousand per frame). Probabilities saturate only when read. Clamping (order-dependent by nature) is the
user's explicit choice.
"""

import numpy as np

LOG_ODDS_STEP = 2.0**-20
"""Log-odds of one fixed-point unit."""

Q_MIN, Q_MAX = -(2**53), 2**53
"""Saturation bounds of the stored int64 sums (symmetric): every integer up to them is exact in float64, and a
merge's ``q1 + q2 - q0`` of two bounded sums cannot overflow int64 before it is bounded."""
Q_DTYPE = np.int64
"""The stored integers' type."""
STEP_MAX = 2**40
"""Largest fixed-point step one frame adds to a voxel (``2**20`` log-odds), so that ``2**13`` frames of it
fit below :data:`Q_MAX`."""


def logit(p):
    """``ln(p / (1 - p))``."""
    return np.log(p) - np.log1p(-p)


def to_fixed(log_odds):
    """int64 fixed-point units of float log-odds (rounded to nearest, saturated)."""
    scaled = np.rint(np.asarray(log_odds, dtype=np.float64) / LOG_ODDS_STEP)
    return np.clip(scaled, Q_MIN, Q_MAX).astype(np.int64)


def from_fixed(q):
    """float64 log-odds of fixed-point units (exact)."""
    return np.asarray(q, dtype=np.float64) * LOG_ODDS_STEP
