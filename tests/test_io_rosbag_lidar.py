"""A LiDAR in a ROS bag as ground truth: bags written here with rosbags hold images, camera_info, /tf_static and
PointCloud2 scans of a board in front of a wall, taken 30 ms after each image from a moving camera; the
projected disparities equal the exact ones pixel by pixel, points hidden from the camera are dropped, the motion
between scan and image is compensated, and bad input fails naming the problem without writing anything."""

import numpy as np
import pytest
from scipy import ndimage
from test_io_rosbag import LEFT, RIGHT, BagWriter, projections, stamp

from prismap.cli import main
from prismap.errors import PrismapInputError
from prismap.io import read_bag
from support import CAMERA

LIDAR_TOPIC = "/velodyne_points"
SCAN_DELAY_NS = 30_000_000
"""Each scan is stamped 30 ms after its image."""
SPEED_M_S = 8.0
"""The camera drives sideways: 0.24 m between an image and its scan, several pixels at the board."""
WALL_Z, BOARD_Z, BOARD_HALF = 20.0, 5.0, 1.0
T_CAM_LIDAR = np.array([[1.0, 0, 0, 0.4], [0, 1.0, 0, -0.3], [0, 0, 1.0, -0.2], [0, 0, 0, 1]])
"""The LiDAR 0.4 m right of, 0.3 m above and 0.2 m behind the left camera: it sees behind the board's edge."""


def pose_at(t_ns):
    """The left camera's pose: sideways along world x at SPEED_M_S, looking along world z."""
    T = np.eye(4)
    T[0, 3] = SPEED_M_S * (t_ns - stamp(0)) * 1e-9
    return T


def first_hit(origin, directions):
    """Where rays first meet the board or the wall (world frame, metres)."""
    t_board = (BOARD_Z - origin[2]) / directions[:, 2]
    at_board = origin + t_board[:, None] * directions
    on_board = (np.abs(at_board[:, 0]) <= BOARD_HALF) & (np.abs(at_board[:, 1]) <= BOARD_HALF)
    t_wall = (WALL_Z - origin[2]) / directions[:, 2]
    return np.where(on_board[:, None], at_board, origin + t_wall[:, None] * directions)


def exact_disparity(T_world_cam):
    rays = CAMERA.pixel_rays().reshape(-1, 3)
    depth = first_hit(T_world_cam[:3, 3], rays)[:, 2] - T_world_cam[2, 3]
    return CAMERA.disparity_from_depth(depth).reshape(CAMERA.height, CAMERA.width)


def scan_points(t_ns):
    """A 16-ring scan at ``t_ns`` in the LiDAR's frame."""
    T_world_lidar = pose_at(t_ns) @ T_CAM_LIDAR
    elevation = np.deg2rad(np.linspace(-25.0, 25.0, 16))[:, None]
    azimuth = np.deg2rad(np.linspace(-40.0, 40.0, 300))[None, :]
    directions = np.stack(
        [np.cos(elevation) * np.sin(azimuth), np.sin(elevation) + 0 * azimuth, np.cos(elevation) * np.cos(azimuth)],
        axis=-1,
    ).reshape(-1, 3)
    world = first_hit(T_world_lidar[:3, 3], directions)
    return (world - T_world_lidar[:3, 3]) @ T_world_lidar[:3, :3]


def pointcloud(bag, t_ns, points, frame_id="velodyne"):
    """An unorganised PointCloud2 with x, y, z, intensity (float32, 16 bytes a point)."""
    record = np.zeros(len(points), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
    record["x"], record["y"], record["z"] = points.T
    field = bag.T("sensor_msgs/msg/PointField")
    fields = [field(name=name, offset=4 * i, datatype=7, count=1) for i, name in enumerate(record.dtype.names)]
    return bag.T("sensor_msgs/msg/PointCloud2")(
        header=bag.header(t_ns, frame_id),
        height=1,
        width=len(record),
        fields=fields,
        is_bigendian=False,
        point_step=16,
        row_step=16 * len(record),
        data=record.view(np.uint8).ravel(),
        is_dense=True,
    )


def write_lidar_bag(path, storage, *, n_frames=3, tf_static=True, scan=scan_points):
    """Images (all grey), camera_info, odometry every 10 ms, /tf_static left -> velodyne, a scan after each image."""
    P, P_right = projections(CAMERA)
    image = np.full((CAMERA.height, CAMERA.width, 3), 128, np.uint8)
    with BagWriter(path, storage) as bag:
        for topic, proj in (("/stereo/left/camera_info", P), ("/stereo/right/camera_info", P_right)):
            bag.write(topic, bag.camera_info(stamp(0), CAMERA.K, proj), stamp(0))
        if tf_static:
            bag.write("/tf_static", bag.tf(stamp(0), "left", "velodyne", T_CAM_LIDAR), stamp(0))
        for t in range(stamp(0) - 50_000_000, stamp(n_frames) + 50_000_000, 10_000_000):
            bag.write("/odom", bag.odometry(t, pose_at(t)), t)
        for i in range(n_frames):
            for topic in (LEFT, RIGHT):
                bag.write(topic, bag.image(stamp(i), image, "rgb8"), stamp(i))
            t = stamp(i) + SCAN_DELAY_NS
            bag.write(LIDAR_TOPIC, pointcloud(bag, t, scan(t)), t)
    return path


@pytest.fixture(scope="module")
def lidar_bag(tmp_path_factory):
    return write_lidar_bag(tmp_path_factory.mktemp("lidar") / "rec", "mcap")


def test_projected_lidar_disparities_are_exact_pixel_by_pixel_with_occlusions(lidar_bag):
    bag = read_bag(lidar_bag, left=LEFT, right=RIGHT, pose_topic="/odom", lidar_topic=LIDAR_TOPIC)
    for index in range(len(bag)):
        frame = bag[index]
        exact = exact_disparity(pose_at(stamp(index)))
        kept = np.isfinite(frame.disparity_gt)
        assert kept.sum() > 300
        # a pixel at the board's silhouette may hold a board point although its centre sees the wall
        edge = ndimage.maximum_filter(exact, size=3) != ndimage.minimum_filter(exact, size=3)
        np.testing.assert_allclose(frame.disparity_gt[kept & ~edge], exact[kept & ~edge], atol=2e-3)
        at_edge = kept & edge & ~np.isclose(frame.disparity_gt, exact, atol=2e-3)
        np.testing.assert_allclose(
            frame.disparity_gt[at_edge], ndimage.maximum_filter(exact, size=3)[at_edge], atol=2e-3
        )  # the board's, never a hidden wall point's
        on_board = exact > CAMERA.disparity_from_depth(WALL_Z) + 0.5
        assert (kept & on_board & ~edge).sum() > 20 and (kept & ~on_board & ~edge).sum() > 20


def test_without_motion_compensation_the_scan_misses_the_image(lidar_bag):
    # no pose source: the scan is placed where the camera was 30 ms later, 0.24 m off
    bag = read_bag(lidar_bag, left=LEFT, right=RIGHT, lidar_topic=LIDAR_TOPIC)
    frame = bag[1]
    exact = exact_disparity(pose_at(stamp(1)))
    kept = np.isfinite(frame.disparity_gt)
    assert np.mean(np.abs(frame.disparity_gt[kept] - exact[kept]) > 1.0) > 0.01


def test_extrinsics_given_instead_of_tf_static(tmp_path):
    path = write_lidar_bag(tmp_path / "rec", "sqlite3", n_frames=1, tf_static=False)
    with pytest.raises(
        PrismapInputError,
        match="no transform from the LiDAR frame 'velodyne' to the camera frame 'left'.*--lidar-extrinsics",
    ):
        read_bag(path, left=LEFT, right=RIGHT, pose_topic="/odom", lidar_topic=LIDAR_TOPIC)
    frame = read_bag(
        path, left=LEFT, right=RIGHT, pose_topic="/odom", lidar_topic=LIDAR_TOPIC, T_cam_lidar=T_CAM_LIDAR
    )[0]
    exact = exact_disparity(pose_at(stamp(0)))
    edge = ndimage.maximum_filter(exact, size=3) != ndimage.minimum_filter(exact, size=3)
    kept = np.isfinite(frame.disparity_gt) & ~edge
    np.testing.assert_allclose(frame.disparity_gt[kept], exact[kept], atol=2e-3)


def test_stamps_too_far_apart_and_scans_outside_the_image_are_refused(lidar_bag, tmp_path):
    with pytest.raises(PrismapInputError, match=f"no partner on {LIDAR_TOPIC} within 0.01 s"):
        read_bag(lidar_bag, left=LEFT, right=RIGHT, lidar_topic=LIDAR_TOPIC, scan_tolerance_s=0.01)
    behind = write_lidar_bag(tmp_path / "behind", "mcap", n_frames=1, scan=lambda t: scan_points(t) * [1, 1, -1])
    bag = read_bag(behind, left=LEFT, right=RIGHT, pose_topic="/odom", lidar_topic=LIDAR_TOPIC)
    with pytest.raises(PrismapInputError, match="none of the scan's .* points lies in front of the camera"):
        bag[0]


def test_cli_characterise_with_a_bad_lidar_bag_exits_2_and_writes_nothing(tmp_path, capsys):
    path = write_lidar_bag(tmp_path / "rec", "mcap", n_frames=2, tf_static=False)
    out = tmp_path / "model"
    argv = [
        "characterise",
        "--bag",
        str(path),
        "--left",
        LEFT,
        "--right",
        RIGHT,
        "--lidar-topic",
        LIDAR_TOPIC,
        "--matcher",
        "sgbm",
        "--plain",
        "--out",
        str(out),
    ]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no transform from the LiDAR frame" in err
    assert not out.exists() or not any(out.iterdir())
    extrinsics = tmp_path / "T_cam_lidar.txt"
    extrinsics.write_text("1 0 0 0.4 0 1 0 -0.3 0 0 1\n")
    assert main(argv + ["--lidar-extrinsics", str(extrinsics)]) == 2
    assert "12 number" in capsys.readouterr().err
