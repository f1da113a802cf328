"""Depth and disparity of a rectified stereo pair: ``z = f b / (d + doffs)``, the one place it is written."""

import numpy as np


def depth_from_disparity(disparity_px, focal_baseline, doffs_px=0.0, *, invalid=np.nan):
    """Depth ``z = f b / (d + doffs)`` (metres) of each disparity.

    Parameters
    ----------
    disparity_px : array_like, pixels
    focal_baseline : float, pixel-metres
        ``f * b`` of the rig.
    doffs_px : float, pixels
        Disparity offset (Middlebury 2014); 0 for most rigs.
    invalid : float
        The depth where ``d + doffs`` is not a finite number > 0 (no depth): NaN for images, +inf for sensor
        models (a measurement at infinity).

    Returns
    -------
    float64 array of the disparities' shape, metres
    """
    total = np.asarray(disparity_px, dtype=np.float64) + doffs_px
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = focal_baseline / total
    return np.where(np.isfinite(total) & (total > 0), depth, invalid)


def disparity_from_depth(depth_m, focal_baseline, doffs_px=0.0):
    """Disparity ``d = f b / z - doffs`` (pixels) of each depth (metres); NaN where ``z`` is not a finite number > 0."""
    z = np.asarray(depth_m, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        disparity = focal_baseline / z - doffs_px
    return np.where(np.isfinite(z) & (z > 0), disparity, np.nan)
