import numpy as np
import pytest

from prismap import PrismapInputError
from prismap.camera import StereoCamera

CAM = StereoCamera(focal_px=615.0, cx_px=320.0, cy_px=240.0, baseline_m=0.1, width=640, height=480)


def test_depth_disparity_round_trip_and_invalid():
    z = np.array([0.5, 1.0, 10.0, 100.0])
    np.testing.assert_allclose(CAM.depth_from_disparity(CAM.disparity_from_depth(z)), z, rtol=1e-12)
    assert np.isnan(CAM.depth_from_disparity(np.array([0.0, -1.0, np.nan]))).all()


def test_doffs_enters_depth():
    cam = StereoCamera(994.978, 311.193, 254.877, 0.193001, doffs_px=31.086)
    assert cam.depth_from_disparity(10.0) == pytest.approx(994.978 * 0.193001 / 41.086)


def test_triangulated_points_project_back_to_their_pixels():
    rng = np.random.default_rng(0)
    disparity = rng.uniform(5, 60, size=(480, 640))
    disparity[10, 20] = np.nan
    points = CAM.triangulate(disparity)
    assert np.isnan(points[10, 20]).all()
    v, u = 123, 456
    x, y, z = points[v, u]
    assert CAM.focal_px * x / z + CAM.cx_px == pytest.approx(u)
    assert CAM.focal_px * y / z + CAM.cy_px == pytest.approx(v)
    assert z == pytest.approx(CAM.focal_baseline / disparity[v, u])


def test_project_inverts_pixel_rays_and_is_nan_behind_the_camera():
    depth = np.random.default_rng(1).uniform(0.5, 50.0, size=(480, 640, 1))
    u, v = CAM.project(CAM.pixel_rays() * depth)
    np.testing.assert_allclose(u, np.broadcast_to(np.arange(640.0), (480, 640)), atol=1e-9)
    np.testing.assert_allclose(v, np.broadcast_to(np.arange(480.0)[:, None], (480, 640)), atol=1e-9)
    u, v = CAM.project(np.array([[1.0, 2.0, 0.0], [1.0, 2.0, -3.0], [0.615, -1.23, 2.0]]))
    assert np.isnan(u[:2]).all() and np.isnan(v[:2]).all()
    assert (u[2], v[2]) == pytest.approx((320.0 + 615.0 * 0.615 / 2.0, 240.0 - 615.0 * 1.23 / 2.0))


def test_bad_camera_parameters():
    with pytest.raises(PrismapInputError, match="baseline_m"):
        StereoCamera(600, 320, 240, 0.0)
    with pytest.raises(PrismapInputError, match="`disparity_px` must be 2-D"):
        CAM.triangulate(np.zeros((4, 4, 3)))


def test_depth_and_disparity_have_one_owner_for_cameras_and_sensor_models():
    from prismap._depth import depth_from_disparity, disparity_from_depth
    from prismap.sensor_models import make_sensor_model

    d = np.array([94.0, 3.0, -2.0, 0.0, np.nan])
    np.testing.assert_array_equal(depth_from_disparity(d, 96.0, 2.0), [1.0, 19.2, np.nan, 48.0, np.nan])
    np.testing.assert_array_equal(depth_from_disparity(d, 96.0, 2.0, invalid=np.inf), [1.0, 19.2, np.inf, 48.0, np.inf])
    np.testing.assert_array_equal(disparity_from_depth([1.0, 48.0, 0.0], 96.0, 2.0), [94.0, 0.0, np.nan])
    model = make_sensor_model("hitmiss", focal_baseline=96.0, doffs_px=2.0, voxel_size_m=0.1, p0=0.5)
    np.testing.assert_array_equal(model.influence_depth(d[:3], np.ones(3)), [1.0, 19.2, np.inf])
