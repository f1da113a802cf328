"""Measurements in, voxels out: the camera side's batch of a disparity image, range batches, and the map's checks
of what a batch holds against what its sensor model takes."""

import numpy as np
import pytest

from prismap.camera import disparity_batch, frame_overhang_m, integrate_disparity, pose_noise_px
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.grid import OccupancyMap, RayBatch
from prismap.sensor_models import make_sensor_model
from support import assert_same_map, planes_frame


def _frame():
    camera, pose, depth = planes_frame(80, 60)
    camera = type(camera)(65.0, 39.5, 29.5, 0.1, width=80, height=60)
    disparity = camera.focal_baseline / depth
    disparity[5:9, 10:20] = np.nan
    disparity[0, :4] = -camera.doffs_px - 1.0  # d + doffs <= 0: no depth
    return camera, pose, disparity


def test_disparity_batch_holds_every_subsampled_pixel_rotated_into_the_world():
    camera, pose, disparity = _frame()
    batch = disparity_batch(disparity, camera, pose, subsample=2)
    rays_cam = camera.pixel_rays()[::2, ::2].reshape(-1, 3)
    assert batch.kind == "disparity" and len(batch) == 30 * 40
    np.testing.assert_array_equal(batch.origin_w, pose[:3, 3])
    np.testing.assert_allclose(batch.rays_w, rays_cam @ pose[:3, :3].T, rtol=1e-14, atol=1e-15)
    expected = disparity[::2, ::2].reshape(-1).copy()
    expected[~(expected > 0)] = np.nan
    np.testing.assert_array_equal(batch.measurement, expected)
    assert batch.image is None and batch.voxel_overhang_m is None and batch.extra_noise_px is None


def test_disparity_batch_adds_noise_overhang_classes_and_image_when_asked():
    camera, pose, disparity = _frame()
    cov = np.diag([0.01, 0.02, 0.03])
    classes = np.arange(disparity.size, dtype=np.int64).reshape(disparity.shape) % 3
    batch = disparity_batch(
        disparity,
        camera,
        pose,
        subsample=3,
        pose_covariance=cov,
        ray_class=classes,
        overhang_voxel_m=0.2,
        projective=True,
    )
    rays_cam = camera.pixel_rays()[::3, ::3].reshape(-1, 3)
    np.testing.assert_array_equal(batch.ray_class, classes[::3, ::3].reshape(-1))
    np.testing.assert_array_equal(
        batch.extra_noise_px,
        pose_noise_px(batch.measurement, rays_cam, pose[:3, :3], cov, camera.focal_baseline, camera.doffs_px),
    )
    np.testing.assert_array_equal(
        batch.voxel_overhang_m, frame_overhang_m(disparity, camera, pose[:3, :3], 0.2, 3, rays_cam)
    )
    assert batch.image.subsample == 3 and batch.image.ray_index.shape == (20, 27)
    np.testing.assert_array_equal(batch.image.R_cam_world, pose[:3, :3].T)


def test_integrate_disparity_is_the_map_of_its_batch():
    camera, pose, disparity = _frame()
    model = make_sensor_model(
        "prism",
        focal_baseline=camera.focal_baseline,
        error_model=GaussianMixture.gaussian(0.3),
        voxel_size_m=0.2,
        p0=0.05,
    )
    for mode in ("ray", "projective"):
        direct, batched = OccupancyMap(0.2, p0=0.05), OccupancyMap(0.2, p0=0.05)
        integrate_disparity(direct, disparity, camera, pose, model, mode=mode, max_range_m=8.0, subsample=2)
        batch = disparity_batch(
            disparity, camera, pose, subsample=2, overhang_voxel_m=0.2, projective=mode == "projective"
        )
        batched.integrate(batch, model, mode=mode, max_range_m=8.0)
        assert direct.n_known > 500
        assert_same_map(direct, batched)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"subsample": 0}, "`subsample` must be an integer >= 1"),
        ({"subsample": "a"}, "`subsample` must be an integer >= 1"),
        ({"ray_class": np.zeros((3, 3), dtype=int)}, "`ray_class` must be an integer array of shape"),
    ],
)
def test_disparity_batch_names_bad_arguments(kwargs, message):
    camera, pose, disparity = _frame()
    with pytest.raises(PrismapInputError, match=message):
        disparity_batch(disparity, camera, pose, **kwargs)


def _scan():
    """Unit rays to points at exactly representable ranges (powers of two)."""
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(400, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    ranges = 2.0 ** rng.integers(-1, 4, size=400).astype(float)
    return directions, ranges


def test_a_range_batch_maps_as_the_disparity_of_a_virtual_camera_would():
    """Hit/miss on ranges r along unit rays against hit/miss on disparities fb / r (exact here: fb and r are
    powers of two), the round trip the LiDAR reference map used to take."""
    directions, ranges = _scan()
    origin = np.array([0.3, -0.2, 0.1])
    of_ranges = make_sensor_model("hitmiss", measurement="range", voxel_size_m=0.1, p0=0.5)
    of_disparity = make_sensor_model("hitmiss", focal_baseline=8.0, voxel_size_m=0.1, p0=0.5)
    maps = [OccupancyMap(0.1, p0=0.5) for _ in range(2)]
    maps[0].integrate_rays(origin, directions, ranges, of_ranges, kind="range", policy="occupied-wins")
    maps[1].integrate_rays(origin, directions, 8.0 / ranges, of_disparity, policy="occupied-wins")
    assert maps[0].n_known > 1000
    assert_same_map(*maps)


def test_range_models_measure_depth_along_the_ray():
    model = make_sensor_model("ideal", measurement="range", voxel_size_m=0.1, p0=0.2)
    norm = np.array([1.0, 2.0])
    np.testing.assert_allclose(model.influence_depth(np.array([3.0, 3.0]), norm), [3.05, 1.525])


def test_the_map_refuses_a_batch_its_model_does_not_take():
    directions, ranges = _scan()
    grid = OccupancyMap(0.1, p0=0.5)
    of_disparity = make_sensor_model("hitmiss", focal_baseline=8.0, voxel_size_m=0.1, p0=0.5)
    with pytest.raises(PrismapInputError, match="'hitmiss' takes disparity measurements; the batch holds range"):
        grid.integrate_rays(np.zeros(3), directions, ranges, of_disparity, kind="range")
    with pytest.raises(PrismapInputError, match=r"`kind` must be one of \['disparity', 'range'\]; got 'depth'"):
        grid.integrate_rays(np.zeros(3), directions, ranges, of_disparity, kind="depth")
    with pytest.raises(PrismapInputError, match="`batch` must be a RayBatch; got tuple"):
        grid.integrate((np.zeros(3), directions, ranges), of_disparity)
    assert grid.n_frames == 0 and grid.n_known == 0


def test_sensor_models_say_which_measurements_they_take():
    with pytest.raises(PrismapInputError, match=r"prism: `measurement` must be one of \['disparity'\]; got 'range'"):
        make_sensor_model("prism", measurement="range", error_model=GaussianMixture.gaussian(0.3), voxel_size_m=0.1)
    with pytest.raises(PrismapInputError, match="`focal_baseline` must be"):
        make_sensor_model("hitmiss", voxel_size_m=0.1, p0=0.5)
    assert make_sensor_model("hitmiss", measurement="range", voxel_size_m=0.1, p0=0.5).focal_baseline is None


def test_a_batch_subset_keeps_its_kind():
    batch = RayBatch(np.zeros(3), np.eye(3), np.array([1.0, np.nan, 2.0]), np.ones(3), kind="range")
    sub = batch.subset(np.array([True, False, True]))
    assert sub.kind == "range" and sub.measurement.tolist() == [1.0, 2.0]


def test_integrators_projectors_and_models_come_from_their_factories():
    from prismap.grid import PROJECTOR_NAMES, ImageProjection, make_integrator, make_projector

    projector = make_projector(
        "pinhole",
        R_cam_world=np.eye(3),
        focal_px=50.0,
        cx_px=3.0,
        cy_px=2.0,
        subsample=1,
        ray_index=np.zeros((4, 6), dtype=np.int32),
    )
    assert PROJECTOR_NAMES == ("pinhole",) and isinstance(projector, ImageProjection) and projector.focal_px == 50.0
    with pytest.raises(PrismapInputError, match=r"`projector` must be one of \['pinhole'\]; got 'fisheye'"):
        make_projector("fisheye")
    assert make_integrator("projective", voxel_size_m=0.1).name == "projective"
