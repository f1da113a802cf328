"""Cross-frame error correlation: errors fixed to the world repeat, independent errors do not, and the pairing
agrees with a brute-force loop over pixels."""

import numpy as np
import pytest

from prismap.camera import StereoCamera
from prismap.characterise import frame_error_correlation
from prismap.errors import PrismapInputError
from prismap.io import StereoFrame

CAMERA = StereoCamera(72.0, 47.5, 35.5, 0.5, width=96, height=72)
DEPTH_M = 10.0
PIXEL_M = DEPTH_M / CAMERA.focal_px
"""A sideways step of this many metres moves a point of the plane at ``DEPTH_M`` by exactly one pixel."""


def _pose(x_m):
    pose = np.eye(4)
    pose[0, 3] = x_m
    return pose


def _frames(n, depth_of_column=None):
    """``n`` frames stepping one pixel sideways in front of a plane at ``DEPTH_M`` (or per-column depths)."""
    depth = np.full((CAMERA.height, CAMERA.width), DEPTH_M)
    if depth_of_column is not None:
        depth = np.broadcast_to(depth_of_column, depth.shape).copy()
    truth = CAMERA.disparity_from_depth(depth).astype(np.float32)
    image = np.zeros((CAMERA.height, CAMERA.width), np.uint8)
    return [StereoFrame(image, image, CAMERA, truth, _pose(k * PIXEL_M), f"f{k}") for k in range(n)]


def _world_x(frame):
    """World x (metres) of the surface point each pixel of ``frame`` sees."""
    depth = CAMERA.depth_from_disparity(frame.disparity_gt)
    return CAMERA.pixel_rays()[..., 0] * depth + frame.T_world_cam[0, 3]


def test_errors_fixed_to_the_world_repeat_exactly():
    frames = _frames(4)
    # the error is a property of the surface point: e(X), gross on one stripe of the plane
    disparities = []
    for frame in frames:
        x = _world_x(frame)
        error = 0.4 * np.sin(2.0 * x) + np.where(np.abs(x - 1.0) < 0.5, 4.0, 0.0)
        disparities.append(frame.disparity_gt - error)
    result = frame_error_correlation(frames, disparities, CAMERA, lag=1, step=1, limit_px=1.0)
    # every pixel but the column leaving the image is seen again, one pixel further left
    assert result.n_pairs == 3 * CAMERA.height * (CAMERA.width - 1)
    assert result.correlation == pytest.approx(1.0, abs=1e-9)
    assert result.gross_repeat == pytest.approx(1.0)
    assert 0 < result.gross_rate < 0.2


def test_independent_errors_do_not_repeat():
    frames = _frames(6)
    rng = np.random.default_rng(3)
    disparities = []
    for frame in frames:
        error = rng.normal(0.0, 0.3, frame.disparity_gt.shape)
        gross = rng.random(error.shape) < 0.1
        disparities.append(frame.disparity_gt - np.where(gross, 5.0, error))
    result = frame_error_correlation(frames, disparities, CAMERA, lag=2, step=1)
    n = result.n_pairs
    assert n == 4 * CAMERA.height * (CAMERA.width - 2)
    assert abs(result.correlation) < 4 / np.sqrt(n)  # 4 standard errors of a zero correlation
    se = np.sqrt(0.1 * 0.9 / (0.1 * n))
    assert result.gross_repeat == pytest.approx(0.1, abs=4 * se)
    assert result.gross_rate == pytest.approx(0.1, abs=0.02)


def _brute_force(frames, disparities, lag, step, tolerance):
    """Pixel by pixel: triangulate at the true depth, move to the later camera, project, check the depth."""
    pairs = []
    f, cx, cy = CAMERA.focal_px, CAMERA.cx_px, CAMERA.cy_px
    for i in range(len(frames) - lag):
        a, b = frames[i], frames[i + lag]
        for v in range(0, CAMERA.height, step):
            for u in range(0, CAMERA.width, step):
                e_i = float(a.disparity_gt[v, u]) - float(disparities[i][v, u])
                if not np.isfinite(e_i):
                    continue
                z = CAMERA.focal_baseline / (float(a.disparity_gt[v, u]) + CAMERA.doffs_px)
                world = a.T_world_cam @ np.array([(u - cx) / f * z, (v - cy) / f * z, z, 1.0])
                x, y, z_b, _ = np.linalg.solve(b.T_world_cam, world)
                col, row = round(f * x / z_b + cx), round(f * y / z_b + cy)
                if not (0 <= col < CAMERA.width and 0 <= row < CAMERA.height):
                    continue
                seen = CAMERA.focal_baseline / (float(b.disparity_gt[row, col]) + CAMERA.doffs_px)
                e_j = float(b.disparity_gt[row, col]) - float(disparities[i + lag][row, col])
                if abs(seen - z_b) <= tolerance * z_b and np.isfinite(e_j):
                    pairs.append((e_i, e_j))
    return np.array(pairs)


def test_pairing_matches_brute_force_with_an_occluding_step():
    # near columns (5 m) in front of the far plane: points behind them are hidden from the later frame
    depth = np.where(np.arange(CAMERA.width) % 24 < 6, 5.0, DEPTH_M)
    frames = _frames(3, depth)
    rng = np.random.default_rng(7)
    disparities = []
    for frame in frames:
        d = frame.disparity_gt - rng.normal(0.0, 0.5, frame.disparity_gt.shape)
        d[rng.random(d.shape) < 0.05] = np.nan
        disparities.append(d)
    pairs = _brute_force(frames, disparities, lag=1, step=3, tolerance=0.02)
    result = frame_error_correlation(frames, disparities, CAMERA, lag=1, step=3, limit_px=3.0, gross_px=1.0)
    assert result.n_pairs == len(pairs)
    small = (np.abs(pairs) <= 3.0).all(axis=1)
    assert result.correlation == pytest.approx(np.corrcoef(pairs[small].T)[0, 1], abs=1e-12)
    assert result.gross_rate == pytest.approx(np.mean(np.abs(pairs[:, 1]) > 1.0))
    assert result.gross_repeat == pytest.approx(np.mean(np.abs(pairs[np.abs(pairs[:, 0]) > 1.0, 1]) > 1.0))


def test_bad_input_is_named():
    frames = _frames(2)
    disparities = [f.disparity_gt for f in frames]
    with pytest.raises(PrismapInputError, match="`lag` 2 needs more than 2 frames"):
        frame_error_correlation(frames, disparities, CAMERA, lag=2)
    with pytest.raises(PrismapInputError, match="one image per frame"):
        frame_error_correlation(frames, disparities[:1], CAMERA)
    with pytest.raises(PrismapInputError, match="frame 1: disparity .*differ in shape"):
        frame_error_correlation(frames, [disparities[0], disparities[1][:, :10]], CAMERA)
    posed = [frames[0], StereoFrame(frames[1].left, frames[1].right, CAMERA, frames[1].disparity_gt, None, "nopose")]
    with pytest.raises(PrismapInputError, match="frame 1 \\(nopose\\): needs `disparity_gt` and `T_world_cam`"):
        frame_error_correlation(posed, disparities, CAMERA)
    with pytest.raises(PrismapInputError, match="lag"):
        frame_error_correlation(frames, disparities, CAMERA, lag=0)
