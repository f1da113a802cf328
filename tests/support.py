"""Test support shared by several test files: a hand-written hit/miss model, synthetic frames and
sequences, and map comparison. Imported as ``from support import ...`` (pytest puts tests/ on sys.path)."""

import numpy as np

from prismap import sim
from prismap.camera import StereoCamera
from prismap.gmm import GaussianMixture
from prismap.io import write_sequence
from prismap.pipeline import MappingConfig
from prismap.sensor_models import InverseSensorModel

L_HIT = np.log(0.7 / 0.3)
L_MISS = np.log(0.4 / 0.6)


def logit(p):
    return np.log(p / (1 - p))


class HitMissModel(InverseSensorModel):
    """OctoMap's hit/miss model on one ray, written here so the grid is tested without `sensor_models`.

    ``p_hit`` in the cell whose depth interval contains the measured depth, ``p_miss`` before it.
    """

    name = "test-hitmiss"
    default_policy = "occupied-wins"

    def __init__(self, focal_baseline, *, doffs_px=0.0, p0=0.5, extra_noise_px=0.0):
        self.focal_baseline, self.doffs_px, self.p0 = focal_baseline, doffs_px, p0
        self.extra_noise_px = extra_noise_px

    def depth(self, disparity_px):
        return self.focal_baseline / (np.asarray(disparity_px) + self.doffs_px)

    def cell_posteriors(self, disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m):
        z = self.depth(disparity_px)[ray_of_cell]
        hit = (depth_start_m <= z) & (z < depth_end_m)
        post = np.where(hit, 0.7, np.where(depth_end_m <= z, 0.4, self.p0))
        return post, logit(post) - logit(self.p0)

    def influence_depth(self, disparity_px, ray_norm):
        return self.depth(disparity_px)

    def with_extra_noise(self, sigma_px):
        return HitMissModel(self.focal_baseline, doffs_px=self.doffs_px, p0=self.p0, extra_noise_px=sigma_px)


FB = 10.0  # focal * baseline of the hand-made rays: disparity = FB / depth


def planes_frame(width=640, height=480):
    """A 640x480 depth frame of planes at 1-10 m: floor, back wall, left wall, a slanted box face.

    Returns ``camera, T_world_cam, depth (H, W) float64 metres``.
    """
    camera = StereoCamera(525.0, 319.5, 239.5, 0.1, width=width, height=height)
    rays = camera.pixel_rays()
    with np.errstate(divide="ignore", invalid="ignore"):
        candidates = [
            np.where(rays[..., 1] > 0, 1.5 / rays[..., 1], np.inf),  # floor 1.5 m below the camera
            np.full(rays.shape[:2], 9.7),  # back wall
            np.where(rays[..., 0] < 0, -2.93 / rays[..., 0], np.inf),  # left wall
            np.where(np.abs(rays[..., 0] - 0.2) < 0.1, 4.0 + 2.0 * rays[..., 0], np.inf),  # slanted box face
        ]
    depth = np.clip(np.minimum.reduce(candidates), 1.0, 10.0)
    angle = np.deg2rad(20.0)
    pose = np.eye(4)
    pose[:3, :3] = [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
    pose[:3, 3] = [1.234, -0.517, 2.071]
    return camera, pose, depth


def world_points(camera, pose, depth):
    points_cam = camera.pixel_rays(depth.shape) * depth[..., None]
    return np.ascontiguousarray(points_cam.reshape(-1, 3) @ pose[:3, :3].T + pose[:3, 3])


CAMERA = StereoCamera(72.0, 47.5, 35.5, 0.1, width=96, height=72)
VOXEL = 0.2
MIXTURE = GaussianMixture([0.8, 0.2], [0.05, -0.3], [0.4, 2.5])


def synthetic_sequence(path, n_frames=6, *, camera=CAMERA, seed=0, truth=True):
    """Write ``n_frames`` of the seeded indoor scene (with disp/, and occupancy.npz at VOXEL) to ``path``."""
    scene = sim.indoor_scene(seed=seed)
    frames = list(scene.frames(camera, sim.indoor_trajectory(n_frames, seed=seed), seed=seed))
    occupancy = scene.ground_truth(frames, VOXEL, max_depth_m=8.0) if truth else None
    write_sequence(frames, path, occupancy=occupancy)
    return path


def config(**changes):
    options = dict(
        model="convolution",
        voxel_size_m=VOXEL,
        p0=0.05,
        error_model=MIXTURE,
        disparity_source="sequence",
        matcher_params={"num_disparities": 16},
        max_range_m=8.0,
    )
    options.update(changes)
    return MappingConfig(**options)


def assert_same_map(a, b, *, atol=0.0):
    keys_a, log_a, count_a = a.known_voxels()
    keys_b, log_b, count_b = b.known_voxels()
    order_a, order_b = np.lexsort(keys_a.T), np.lexsort(keys_b.T)
    np.testing.assert_array_equal(keys_a[order_a], keys_b[order_b])
    np.testing.assert_array_equal(count_a[order_a], count_b[order_b])
    np.testing.assert_allclose(log_a[order_a], log_b[order_b], rtol=0, atol=atol)
    assert a.n_frames == b.n_frames and a.p0 == b.p0 and a.voxel_size_m == b.voxel_size_m


def kitti_line(name, matrix):
    """One ``name: numbers`` line of a KITTI calibration file."""
    return f"{name}: " + " ".join(f"{v:.12e}" for v in np.ravel(matrix)) + "\n"


def kitti_projection(focal_px, cx_px, cy_px, t):
    """``K [I | t]`` of a rectified KITTI camera, t in metres of rectified camera 0."""
    K = np.array([[focal_px, 0, cx_px], [0, focal_px, cy_px], [0, 0, 1.0]])
    return K @ np.hstack([np.eye(3), np.asarray(t, float)[:, None]])


def shifted_pair(rng, height, width, disparity_px):
    """A random-texture RGB pair whose right view is the left shifted by a whole ``disparity_px``.

    Returns ``left, right (H, W, 3) uint8, disparity_gt (H, W) float32`` with NaN in the first
    ``disparity_px`` columns, whose match falls outside the right image.
    """
    left = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    right = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    right[:, : width - disparity_px] = left[:, disparity_px:]
    truth = np.full((height, width), float(disparity_px), np.float32)
    truth[:, :disparity_px] = np.nan
    return left, right, truth


def write_kitti_stereo(root, pairs, *, year=2015, focal_px=20.0, baseline_m=0.54, disparities=("noc",)):
    """Write a KITTI stereo 2012 or 2015 training folder of ``pairs`` ``(left, right, disparity_gt)``.

    Frame ``i`` is ``NNNNNN_10.png`` (with a ``_11`` image that has no ground truth, as in KITTI); 2012
    stores grey images (the mean of the RGB channels), 2015 colour ones. Calibration per frame, principal
    point at the image centre. Returns ``root``.
    """
    import cv2

    from prismap.io import write_disparity_png

    left_dir, right_dir, disp = (
        ("image_0", "image_1", "disp_{}") if year == 2012 else ("image_2", "image_3", "disp_{}_0")
    )
    for index, (left, right, truth) in enumerate(pairs):
        height, width = truth.shape
        for folder, image in ((left_dir, left), (right_dir, right)):
            (root / folder).mkdir(parents=True, exist_ok=True)
            image = image.mean(axis=2).astype(np.uint8) if year == 2012 else cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
            for suffix in ("_10", "_11"):
                cv2.imwrite(str(root / folder / f"{index:06d}{suffix}.png"), image)
        for kind in disparities:
            write_disparity_png(root / disp.format(kind) / f"{index:06d}_10.png", truth, "disparity")
        P_left = kitti_projection(focal_px, (width - 1) / 2, (height - 1) / 2, [0.06, 0, 0])
        P_right = kitti_projection(focal_px, (width - 1) / 2, (height - 1) / 2, [0.06 - baseline_m, 0, 0])
        if year == 2012:
            folder, text = "calib", kitti_line("P0", P_left) + kitti_line("P1", P_right)
        else:
            folder = "calib_cam_to_cam"
            text = (
                "calib_time: 09-Jan-2012 13:57:47\n"
                + kitti_line("R_rect_00", np.eye(3))
                + kitti_line("P_rect_02", P_left)
                + kitti_line("P_rect_03", P_right)
            )
        (root / folder).mkdir(parents=True, exist_ok=True)
        (root / folder / f"{index:06d}.txt").write_text(text)
    return root


def conditioned_error_model(matcher="sgbm", feature="edge_distance_px", edges=(2.5, 10.0)):
    """A three-class :class:`ErrorModel` on one feature, each class with a distinct mixture around MIXTURE."""
    from prismap.characterise import ClassModel, ErrorClasses, ErrorModel
    from prismap.gmm import MixtureFit

    def fit(mixture):
        return MixtureFit(mixture, -1.0, 1.0, 1.0, 100.0, mixture.n_components, True)

    mixtures = (
        GaussianMixture([0.6, 0.4], [0.0, -1.0], [0.8, 4.0]),
        GaussianMixture([0.9, 0.1], [0.05, -0.3], [0.3, 2.0]),
        GaussianMixture([1.0], [0.0], [0.1]),
    )
    bounds = (-np.inf, *edges, np.inf)
    classes = ErrorClasses((feature,), [[lo] for lo in bounds[:-1]], [[hi] for hi in bounds[1:]])
    class_models = tuple(
        ClassModel((fit(m),), m.n_components, share, {"n_errors": 100}) for m, share in zip(mixtures, (0.2, 0.5, 0.3))
    )
    return ErrorModel(
        matcher,
        {},
        "test",
        1 / 32,
        (fit(MIXTURE),),
        2,
        classes=classes,
        class_models=class_models,
        feature_settings={"edge_threshold_px": 1.0, "texture_window_px": 7},
    )
