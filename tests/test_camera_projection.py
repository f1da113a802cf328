"""Points into the image: LiDAR points hidden from the camera are dropped, the rest give the exact disparity
pixel by pixel; another frame's dense points fitted at pixel centres give the exact disparity of a plane."""

import numpy as np
import pytest

from prismap.camera import StereoCamera, fitted_disparity, visible_points
from prismap.errors import PrismapInputError
from prismap.io import points_to_disparity

CAMERA = StereoCamera(100.0, 79.5, 59.5, 0.5, width=160, height=120)
WALL_Z = 20.0
BOX_Z = 5.0
BOX_HALF = 1.0
"""A wall at z = 20 m facing the camera and a square board (2 m across) at z = 5 m in front of it."""


def _first_hit(origin, directions):
    """Where rays from ``origin`` first meet the board or the wall (camera frame, metres)."""
    t_box = (BOX_Z - origin[2]) / directions[:, 2]
    at_box = origin + t_box[:, None] * directions
    on_box = (np.abs(at_box[:, 0]) <= BOX_HALF) & (np.abs(at_box[:, 1]) <= BOX_HALF) & (t_box > 0)
    t_wall = (WALL_Z - origin[2]) / directions[:, 2]
    return np.where(on_box[:, None], at_box, origin + t_wall[:, None] * directions)


def _exact_disparity():
    """The camera's true disparity at every pixel centre."""
    rays = CAMERA.pixel_rays().reshape(-1, 3)
    depth = _first_hit(np.zeros(3), rays)[:, 2]
    return CAMERA.disparity_from_depth(depth).reshape(CAMERA.height, CAMERA.width)


def _lidar_scan(origin):
    """A sparse scan from ``origin``: 16 beams of 400 points, fanned like a spinning LiDAR's front sector."""
    elevation = np.deg2rad(np.linspace(-20.0, 20.0, 16))[:, None]
    azimuth = np.deg2rad(np.linspace(-45.0, 45.0, 400))[None, :]
    directions = np.stack(
        [np.cos(elevation) * np.sin(azimuth), np.sin(elevation) + 0 * azimuth, np.cos(elevation) * np.cos(azimuth)],
        axis=-1,
    ).reshape(-1, 3)
    return _first_hit(np.asarray(origin, float), directions)


def _hidden_from_camera(points):
    """Points a camera ray meets something nearer before reaching."""
    depth_seen = _first_hit(np.zeros(3), points / np.linalg.norm(points, axis=1, keepdims=True))
    return np.linalg.norm(depth_seen, axis=1) < np.linalg.norm(points, axis=1) - 1e-6


def test_lidar_points_give_exact_disparities_and_hidden_ones_are_dropped():
    scan = _lidar_scan([1.5, 0.0, 0.0])  # a LiDAR 1.5 m to the camera's right sees the wall behind the board's edge
    hidden = _hidden_from_camera(scan)
    assert hidden.sum() > 50  # the scene has occlusions to handle
    exact = _exact_disparity()
    projected = points_to_disparity(scan, CAMERA, occlusion_window_px=2)
    kept = np.isfinite(projected)
    assert kept.sum() > 2000
    np.testing.assert_allclose(projected[kept], exact[kept], rtol=0, atol=1e-4)
    # every hidden point's pixel holds something nearer or nothing
    u, v = CAMERA.project(scan[hidden])
    col, row = np.floor(u + 0.5).astype(int), np.floor(v + 0.5).astype(int)
    inside = (col >= 0) & (col < CAMERA.width) & (row >= 0) & (row < CAMERA.height)
    hidden_disparity = CAMERA.disparity_from_depth(scan[hidden][inside, 2])
    at = projected[row[inside], col[inside]]
    assert not np.any(np.isclose(at, hidden_disparity, atol=1e-4))


def test_without_the_occlusion_window_hidden_points_pass_as_truth():
    scan = _lidar_scan([1.5, 0.0, 0.0])
    exact = _exact_disparity()
    projected = points_to_disparity(scan, CAMERA, occlusion_window_px=0)
    kept = np.isfinite(projected)
    wrong = kept & (np.abs(projected - exact) > 1.0)
    assert wrong.sum() > 10  # the per-pixel z-buffer alone lets wall points through the gaps between board points


def test_visible_points_keeps_a_grazing_surface_and_drops_a_jump():
    # a road seen at a grazing angle: disparity falls 0.5 px per row, so a depth margin would drop it
    rows = np.arange(40)
    disparity = 30.0 - 0.5 * rows
    keep = visible_points(disparity, rows, np.zeros_like(rows), (40, 5), occlusion_window_px=2)
    assert keep.all()
    behind = visible_points(np.array([30.0, 20.0]), np.array([5, 6]), np.array([2, 2]), (10, 5), occlusion_window_px=1)
    assert behind.tolist() == [True, False]
    with pytest.raises(PrismapInputError, match="occlusion_window_px"):
        visible_points(disparity, rows, rows * 0, (40, 5), occlusion_window_px=-1)


def test_fitted_disparity_of_another_frames_points_is_exact_on_a_plane():
    # a tilted plane z = 8 + 0.2 x + 0.3 y, seen from a camera 0.4 m to the right and 0.3 m ahead
    rays = CAMERA.pixel_rays().reshape(-1, 3)
    offset = np.array([0.4, 0.0, 0.3])
    normal, h = np.array([-0.2, -0.3, 1.0]), 8.0  # n . P = h
    t = (h - normal @ offset) / (rays @ normal)
    points_other = offset + t[:, None] * rays  # the other camera's pixels' surface points, this camera's frame
    fitted = fitted_disparity(points_other, CAMERA, (CAMERA.height, CAMERA.width))
    t_here = h / (rays @ normal)
    exact = CAMERA.disparity_from_depth(t_here).reshape(CAMERA.height, CAMERA.width)
    ok = np.isfinite(fitted)
    assert ok.mean() > 0.8
    np.testing.assert_allclose(fitted[ok], exact[ok], atol=1e-6)
    # rounding each point to its nearest pixel instead errs by the gradient times the offset
    nearest = points_to_disparity(points_other, CAMERA)
    both = ok & np.isfinite(nearest)
    assert np.max(np.abs(nearest[both] - exact[both])) > 0.01
