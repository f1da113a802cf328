"""Camera factories (KITTI, Middlebury), rectification (thesis eq. 3.4-3.6), rays and eq. 3.8."""

import cv2
import numpy as np
import pytest

from prismap import PrismapInputError
from prismap.camera import StereoCamera, rectify_stereo, warp_pair

# KITTI odometry sequence 00, calib.txt (P2 and P3 rows, as published).
KITTI_P2 = np.array(
    [[718.856, 0.0, 607.1928, 45.38225], [0.0, 718.856, 185.2157, -0.1130887], [0.0, 0.0, 1.0, 0.003779761]]
)
KITTI_P3 = np.array(
    [[718.856, 0.0, 607.1928, -337.2877], [0.0, 718.856, 185.2157, 2.369057], [0.0, 0.0, 1.0, 0.004915215]]
)


def _rotation(rx, ry, rz):
    return cv2.Rodrigues(np.array([rx, ry, rz], dtype=np.float64))[0]


def _pose(R_world_cam, centre):
    T = np.eye(4)
    T[:3, :3] = R_world_cam
    T[:3, 3] = centre
    return T


def _project(K, T_world_cam, points_w):
    R = T_world_cam[:3, :3].T
    p = (K @ (R @ (points_w - T_world_cam[:3, 3]).T)).T
    return p[:, :2] / p[:, 2:]


def _apply(H, pixels):
    p = np.c_[pixels, np.ones(len(pixels))] @ H.T
    return p[:, :2] / p[:, 2:]


# A deliberately imperfect rig: different intrinsics, small different rotations, a baseline with y/z parts.
K_L = np.array([[700.0, 0.0, 318.0], [0.0, 700.0, 242.0], [0.0, 0.0, 1.0]])
K_R = np.array([[712.0, 0.0, 326.0], [0.0, 712.0, 236.0], [0.0, 0.0, 1.0]])
T_L = _pose(_rotation(0.02, -0.03, 0.01), np.array([0.3, -0.1, 0.2]))
T_R = _pose(_rotation(-0.015, 0.025, -0.02), np.array([0.3, -0.1, 0.2]) + np.array([0.12, 0.004, -0.003]))


def _scene_points(n=200, seed=0):
    rng = np.random.default_rng(seed)
    points_cam = np.c_[rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(2, 20, n)]
    return points_cam @ T_L[:3, :3].T + T_L[:3, 3]


def test_kitti_baseline_uses_the_difference_and_the_exact_translation():
    cam = StereoCamera.from_kitti_projections(KITTI_P2, KITTI_P3, width=1241, height=376)
    # t_i = K^-1 P_i[:, 3]; baseline = t2x - t3x (0.533 m for the KITTI colour pair).
    t2 = (45.38225 - 607.1928 * 0.003779761) / 718.856
    t3 = (-337.2877 - 607.1928 * 0.004915215) / 718.856
    assert cam.baseline_m == pytest.approx(t2 - t3, rel=1e-12)
    assert cam.baseline_m == pytest.approx((45.38225 + 337.2877) / 718.856, abs=2e-3)
    assert (cam.focal_px, cam.cx_px, cam.cy_px, cam.doffs_px) == (718.856, 607.1928, 185.2157, 0.0)
    assert (cam.width, cam.height) == (1241, 376)


def test_kitti_projections_reproduce_the_disparity_of_a_point():
    K = np.array([[700.0, 0.0, 600.0], [0.0, 700.0, 180.0], [0.0, 0.0, 1.0]])
    t2, t3 = np.array([0.06, 0.0, 0.0]), np.array([-0.47, 0.0, 0.0])
    P2, P3 = K @ np.c_[np.eye(3), t2], K @ np.c_[np.eye(3), t3]
    cam = StereoCamera.from_kitti_projections(P2, P3)
    point = np.array([1.0, -0.5, 12.0, 1.0])
    (u2, _, w2), (u3, _, w3) = P2 @ point, P3 @ point
    disparity = u2 / w2 - u3 / w3
    assert cam.baseline_m == pytest.approx(0.53)
    assert cam.depth_from_disparity(disparity) == pytest.approx(12.0)


def test_kitti_bad_projections():
    with pytest.raises(PrismapInputError, match=r"`P2` must have shape \(3, 4\); got \(3, 3\)"):
        StereoCamera.from_kitti_projections(KITTI_P2[:, :3], KITTI_P3)
    with pytest.raises(PrismapInputError, match="right camera"):
        StereoCamera.from_kitti_projections(KITTI_P3, KITTI_P2)
    other = KITTI_P3.copy()
    other[0, 0] = other[1, 1] = 700.0
    with pytest.raises(PrismapInputError, match="share the focal length"):
        StereoCamera.from_kitti_projections(KITTI_P2, other)


MOTORCYCLE_FIELDS = {
    "cam0": [[3979.911, 0, 1244.772], [0, 3979.911, 1019.507], [0, 0, 1]],
    "cam1": [[3979.911, 0, 1369.115], [0, 3979.911, 1019.507], [0, 0, 1]],
    "doffs": 124.343,
    "baseline": 193.001,
    "width": 2964,
    "height": 1988,
    "ndisp": 270,
}


def test_middlebury_calib_fields():
    cam = StereoCamera.from_middlebury_calib(MOTORCYCLE_FIELDS)
    assert cam == StereoCamera(3979.911, 1244.772, 1019.507, 0.193001, doffs_px=124.343, width=2964, height=1988)


def test_middlebury_calib_errors_name_source_and_field():
    fields = dict(MOTORCYCLE_FIELDS)
    del fields["doffs"]
    with pytest.raises(PrismapInputError, match=r"scene/calib.txt: missing field\(s\) \['doffs'\]"):
        StereoCamera.from_middlebury_calib(fields, source="scene/calib.txt")
    with pytest.raises(PrismapInputError, match="calib: `baseline_m` must be a finite number > 0"):
        StereoCamera.from_middlebury_calib(dict(MOTORCYCLE_FIELDS, baseline=0))
    with pytest.raises(PrismapInputError, match="share f and cy"):
        StereoCamera.from_middlebury_calib(dict(MOTORCYCLE_FIELDS, cam1=np.diag([4000.0, 4000.0, 1.0])))


def test_rectification_aligns_rows_and_preserves_depth():
    rect = rectify_stereo(K_L, T_L, K_R, T_R, width=640, height=480)
    points_w = _scene_points()
    left = _apply(rect.H_left, _project(K_L, T_L, points_w))
    right = _apply(rect.H_right, _project(K_R, T_R, points_w))
    np.testing.assert_allclose(left[:, 1], right[:, 1], atol=0.01)
    # The rectified views are exactly the cameras Kn Rn [I | -C] (eq. 3.5) ...
    np.testing.assert_allclose(left, _project(rect.camera.K, rect.T_world_cam, points_w), atol=1e-6)
    # ... so the disparity triangulates (eq. 3.8) to the point's depth in the rectified frame.
    depth = (points_w - rect.T_world_cam[:3, 3]) @ rect.T_world_cam[:3, 2]
    np.testing.assert_allclose(rect.camera.depth_from_disparity(left[:, 0] - right[:, 0]), depth, rtol=1e-9)
    assert rect.camera.baseline_m == pytest.approx(np.linalg.norm([0.12, 0.004, -0.003]))
    assert rect.camera.focal_px == pytest.approx(706.0)
    assert (rect.camera.cx_px, rect.camera.cy_px, rect.camera.doffs_px) == (322.0, 239.0, 0.0)


def test_rectification_agrees_with_opencv_up_to_a_roll_about_the_baseline():
    rect = rectify_stereo(K_L, T_L, K_R, T_R)
    # OpenCV wants the right camera's pose in the left camera's frame: X_r = R X_l + t.
    T_right_left = np.linalg.inv(T_R) @ T_L
    R1, R2, P1, P2, *_ = cv2.stereoRectify(
        K_L, np.zeros(5), K_R, np.zeros(5), (640, 480), T_right_left[:3, :3], T_right_left[:3, 3:], alpha=-1
    )
    points_w = _scene_points(seed=1)
    cv_left = _apply(P1[:, :3] @ R1 @ np.linalg.inv(K_L), _project(K_L, T_L, points_w))
    cv_right = _apply(P2[:, :3] @ R2 @ np.linalg.inv(K_R), _project(K_R, T_R, points_w))
    np.testing.assert_allclose(cv_left[:, 1], cv_right[:, 1], atol=0.01)
    # Both put the rectified x axis along the baseline; they differ only by a rotation about it
    # (OpenCV splits the relative rotation half-half, we use the mean optical axis) and in Kn.
    R_ours = rect.T_world_cam[:3, :3].T
    R_cv = R1 @ T_L[:3, :3].T
    np.testing.assert_allclose(R_ours[0], R_cv[0], atol=1e-9)
    roll = R_ours @ R_cv.T
    np.testing.assert_allclose(roll[0], [1, 0, 0], atol=1e-9)
    assert np.degrees(np.arccos(np.clip(roll[1, 1], -1, 1))) < 0.1


def test_warp_pair_moves_a_pixel_where_the_homography_says():
    rect = rectify_stereo(K_L, T_L, K_R, T_R, width=640, height=480)
    image = np.zeros((480, 640), dtype=np.uint8)
    image[200:203, 300:303] = 255
    left_rect, right_rect = warp_pair(image, image, rect)
    assert left_rect.shape == right_rect.shape == (480, 640) and left_rect.dtype == np.uint8
    v, u = np.unravel_index(np.argmax(cv2.GaussianBlur(left_rect.astype(np.float32), (5, 5), 0)), left_rect.shape)
    expected = _apply(rect.H_left, np.array([[301.0, 201.0]]))[0]
    assert abs(u - expected[0]) <= 1 and abs(v - expected[1]) <= 1


def test_rectification_errors():
    with pytest.raises(PrismapInputError, match=r"\+x side"):
        rectify_stereo(K_R, T_R, K_L, T_L)
    with pytest.raises(PrismapInputError, match="centres coincide"):
        rectify_stereo(K_L, T_L, K_R, T_L)
    bad = T_L.copy()
    bad[:3, :3] *= 2
    with pytest.raises(PrismapInputError, match="`T_world_left` must hold a rotation"):
        rectify_stereo(K_L, bad, K_R, T_R)
    with pytest.raises(PrismapInputError, match="`K_right` must be"):
        rectify_stereo(K_L, T_L, -K_R, T_R)
    with pytest.raises(PrismapInputError, match="`left` must be an"):
        warp_pair(np.zeros(5), np.zeros((4, 4)), rectify_stereo(K_L, T_L, K_R, T_R))


def test_rays_and_triangulation_follow_eq_3_8():
    cam = StereoCamera(615.0, 320.0, 240.0, 0.1, width=640, height=480)
    rays = cam.pixel_rays()
    assert rays.shape == (480, 640, 3)
    np.testing.assert_allclose(rays[17, 401], [(401 - 320) / 615, (17 - 240) / 615, 1.0])
    rng = np.random.default_rng(3)
    disparity = rng.uniform(1.0, 64.0, size=(480, 640))
    points = cam.triangulate(disparity)
    u = np.arange(640)[None, :]
    v = np.arange(480)[:, None]
    b, f = cam.baseline_m, cam.focal_px
    # Eq. 3.8 puts the origin midway between the cameras: x_n = (xL - px) b / d - b/2.
    x_n = (u - cam.cx_px) * b / disparity - b / 2
    y_n = (v - cam.cy_px) * b / disparity
    z_n = f * b / disparity
    np.testing.assert_allclose(points[..., 0] - b / 2, x_n, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(points[..., 1], y_n, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(points[..., 2], z_n, rtol=1e-12)
