"""The map's log-odds in fixed point, so that sums of frames do not depend on their order.

A voxel stores ``q = round(l / LOG_ODDS_STEP)`` as int32 (as Bonxai stores its log-odds in integers).
Each frame adds one rounded integer per voxel, and a merge adds two maps' integers; integer addition is
associative, so integrating frames 1..n in one map and merging maps of any split of them (sequential,
or Dask with any number of workers and any chunking) give bit-identical maps. Float log-odds could not:
their sum depends on the order of the additions.

The step is ``2**-20`` (below float32's resolution at ``|l| >= 8``); values saturate at
``+-2**31 LOG_ODDS_STEP`` (+-2048, probabilities within ``e**-2048`` of 0 or 1). Sums stay exact and
order-free while no voxel saturates; clamping (order-dependent by nature) is the user's explicit choice.
"""

import numpy as np

LOG_ODDS_STEP = 2.0**-20
"""Log-odds of one fixed-point unit."""

Q_MIN, Q_MAX = -(2**31) + 1, 2**31 - 1
"""Saturation bounds of the stored integers (symmetric)."""


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
