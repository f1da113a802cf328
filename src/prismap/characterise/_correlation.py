"""Whether a matcher's error at one surface point repeats from frame to frame.

The map adds each frame's evidence as if the frames' disparity errors were independent (SENSOR_MODELS.md,
section 3). A matcher's errors need not be: a texture or an edge that fools it from one position fools it
again from a metre further on, and then fused frames count one mistake several times. This measures how
much, from frames with ground truth and poses: every ``step``-th pixel of frame ``i`` with a true and a
computed disparity is placed in the world at its TRUE depth (so the pairing does not depend on the error),
projected into frame ``i + lag`` and paired with the pixel it lands on (nearest pixel) when that pixel sees
the same point: its true depth within ``depth_tolerance`` of the point's depth in that frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from prismap._validate import check_integer, check_positive
from prismap.camera import StereoCamera
from prismap.errors import PrismapInputError
from prismap.io._frame import StereoFrame


@dataclass(frozen=True)
class ErrorCorrelation:
    """Agreement of the errors ``e = d_true - d_computed`` of frames ``lag`` apart at the same surface points.

    Attributes
    ----------
    lag : int
        Frames apart (positions in the sequence).
    n_pairs : int
        Surface points seen with a computed disparity in both frames.
    correlation : float
        Pearson correlation of the paired errors, over the pairs with both ``|e| <= limit_px`` (gross errors
        would dominate it); NaN with fewer than 2 such pairs or no spread.
    gross_rate : float
        Share of pairs whose later error is gross (``|e| > gross_px``).
    gross_repeat : float
        Share of pairs whose later error is gross among those whose earlier error is gross (NaN when none
        is): ``gross_rate`` if gross errors struck independently.
    """

    lag: int
    n_pairs: int
    correlation: float
    gross_rate: float
    gross_repeat: float

    def to_dict(self) -> dict[str, Any]:
        """JSON form (NaN as None)."""
        return {
            name: (None if isinstance(value, float) and np.isnan(value) else value)
            for name, value in self.__dict__.items()
        }


def frame_error_correlation(
    frames: Sequence[StereoFrame],
    disparities: Sequence[npt.ArrayLike],
    camera: StereoCamera,
    *,
    lag: int = 1,
    step: int = 2,
    limit_px: float = 3.0,
    gross_px: float = 1.0,
    depth_tolerance: float = 0.02,
) -> ErrorCorrelation:
    """Pair the errors of frames ``lag`` apart at the same surface points (module docstring) and compare them.

    Parameters
    ----------
    frames : sequence of StereoFrame
        In sequence order, each with ``disparity_gt`` (pixels, NaN = unknown) and ``T_world_cam``.
    disparities : sequence of (H, W) float, pixels, NaN = invalid
        The matcher's disparity of each frame.
    camera : StereoCamera
        The frames' rectified camera.
    lag : int, >= 1
    step : int, >= 1
        Pixel step in both directions of the earlier frame.
    limit_px, gross_px : float, pixels, > 0
        Errors within ``+-limit_px`` enter the correlation; beyond ``gross_px`` they are gross.
    depth_tolerance : float, > 0
        Relative depth difference within which the later frame's pixel sees the same point.

    Returns
    -------
    ErrorCorrelation
    """
    frames, disparities = list(frames), list(disparities)
    lag = check_integer(lag, "lag", expected="an integer >= 1", condition=lambda n: n >= 1)
    step = check_integer(step, "step", expected="an integer >= 1", condition=lambda n: n >= 1)
    limit_px, gross_px = check_positive(limit_px, "limit_px"), check_positive(gross_px, "gross_px")
    depth_tolerance = check_positive(depth_tolerance, "depth_tolerance")
    if len(disparities) != len(frames):
        raise PrismapInputError(f"`disparities` must hold one image per frame ({len(frames)}); got {len(disparities)}")
    if len(frames) <= lag:
        raise PrismapInputError(f"`lag` {lag} needs more than {lag} frames; got {len(frames)}")
    truths, computed = [], []
    for index, (frame, disparity) in enumerate(zip(frames, disparities)):
        if frame.disparity_gt is None or frame.T_world_cam is None:
            raise PrismapInputError(
                f"frame {index} ({frame.name or 'unnamed'}): needs `disparity_gt` and `T_world_cam`"
            )
        truth, disparity = np.asarray(frame.disparity_gt, np.float64), np.asarray(disparity, np.float64)
        if disparity.shape != truth.shape:
            raise PrismapInputError(
                f"frame {index}: disparity {disparity.shape} and ground truth {truth.shape} differ in shape"
            )
        truths.append(truth)
        computed.append(disparity)
    earlier, later = [], []
    for i in range(len(frames) - lag):
        e_i, e_j = _pairs(
            truths[i],
            computed[i],
            frames[i].T_world_cam,
            truths[i + lag],
            computed[i + lag],
            frames[i + lag].T_world_cam,
            camera,
            step,
            depth_tolerance,
        )
        earlier.append(e_i)
        later.append(e_j)
    e_i, e_j = np.concatenate(earlier), np.concatenate(later)
    small = (np.abs(e_i) <= limit_px) & (np.abs(e_j) <= limit_px)
    correlation = np.nan
    if small.sum() >= 2 and e_i[small].std() > 0 and e_j[small].std() > 0:
        correlation = float(np.corrcoef(e_i[small], e_j[small])[0, 1])
    gross_i, gross_j = np.abs(e_i) > gross_px, np.abs(e_j) > gross_px
    return ErrorCorrelation(
        lag,
        int(e_i.size),
        correlation,
        float(gross_j.mean()) if e_i.size else np.nan,
        float(gross_j[gross_i].mean()) if gross_i.any() else np.nan,
    )


def _pairs(truth_i, disparity_i, pose_i, truth_j, disparity_j, pose_j, camera, step, depth_tolerance):
    """Errors ``(e_i, e_j)`` of frame i's every ``step``-th pixel and of frame j's pixel seeing the same point."""
    height, width = truth_i.shape
    v, u = np.mgrid[0:height:step, 0:width:step]
    error_i = (truth_i - disparity_i)[v, u]
    depth = camera.depth_from_disparity(truth_i[v, u])
    keep = np.isfinite(error_i) & np.isfinite(depth)
    points_i = camera.pixel_rays((height, width))[v[keep], u[keep]] * depth[keep, None]
    j_from_i = np.linalg.inv(pose_j) @ pose_i
    points_j = points_i @ j_from_i[:3, :3].T + j_from_i[:3, 3]
    col, row = camera.project(points_j)
    inside = np.isfinite(col) & (col > -0.5) & (col < width - 0.5) & (row > -0.5) & (row < height - 0.5)
    col, row = np.rint(col[inside]).astype(np.int64), np.rint(row[inside]).astype(np.int64)
    seen_depth = camera.depth_from_disparity(truth_j[row, col])
    error_j = truth_j[row, col] - disparity_j[row, col]
    same = (np.abs(seen_depth - points_j[inside, 2]) <= depth_tolerance * points_j[inside, 2]) & np.isfinite(error_j)
    return error_i[keep][inside][same], error_j[same]
