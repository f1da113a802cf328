"""ROS bags in (``prismap.io.read_bag``, ``prismap map --bag``): bags written here with rosbags' own writers in
ROS 1, ROS 2 sqlite3 and ROS 2 MCAP storage hold a short ``prismap.sim`` sequence, are read back frame by frame
against the values written, map to the KITTI-layout sequence's map, and bad bags fail with the topic named."""

import dataclasses

import cv2
import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from scipy.spatial.transform import Rotation

from prismap import sim
from prismap.cli import main
from prismap.errors import PrismapInputError
from prismap.io import load_map, read_bag, read_sequence, write_sequence
from prismap.pipeline import map_sequence
from support import CAMERA, assert_same_map, config

STORAGES = ("rosbag1", "sqlite3", "mcap")
T0_NS = 1_700_000_000_000_000_000
DT_NS = 100_000_000
LEFT, RIGHT = "/stereo/left/image_raw", "/stereo/right/image_raw"
T_BASE_CAM = np.array([[0.0, 0.0, 1.0, 0.1], [-1.0, 0.0, 0.0, 0.05], [0.0, -1.0, 0.0, 0.3], [0, 0, 0, 1]])


class BagWriter:
    """One bag of any of the three storages, with message builders that hide ROS 1 / ROS 2 spelling."""

    def __init__(self, path, storage):
        self.ros1 = storage == "rosbag1"
        self.ts = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        if self.ros1:  # rosbags' Noetic store lacks tf2_msgs: the message is one line, registered here
            self.ts.register(
                get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
            )
        if self.ros1:
            self.writer = Writer1(path)
        else:
            plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
            self.writer = Writer2(path, version=9, storage_plugin=plugin)
        self.connections = {}

    def __enter__(self):
        self.writer.open()
        return self

    def __exit__(self, *exc):
        self.writer.close()

    def T(self, name):
        return self.ts.types[name]

    def write(self, topic, msg, stamp_ns, *, publisher=None):
        """Write ``msg``; a ROS 1 bag gets one connection per ``publisher`` (callerid) of a topic."""
        key = (topic, publisher if self.ros1 else None)
        if key not in self.connections:
            extra = {"callerid": publisher} if key[1] else {}
            self.connections[key] = self.writer.add_connection(topic, msg.__msgtype__, typestore=self.ts, **extra)
        serialize = self.ts.serialize_ros1 if self.ros1 else self.ts.serialize_cdr
        self.writer.write(self.connections[key], stamp_ns, serialize(msg, msg.__msgtype__))

    def header(self, stamp_ns, frame_id):
        time = self.T("builtin_interfaces/msg/Time")(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
        extra = {"seq": 0} if self.ros1 else {}
        return self.T("std_msgs/msg/Header")(stamp=time, frame_id=frame_id, **extra)

    def image(self, stamp_ns, array, encoding, frame_id="left"):
        array = np.ascontiguousarray(array)
        height, width = array.shape[:2]
        step = array.nbytes // height
        return self.T("sensor_msgs/msg/Image")(
            header=self.header(stamp_ns, frame_id),
            height=height,
            width=width,
            encoding=encoding,
            is_bigendian=0,
            step=step,
            data=array.view(np.uint8).ravel(),
        )

    def camera_info(self, stamp_ns, K, P, *, D=(), R=None, size=(96, 72)):
        roi = self.T("sensor_msgs/msg/RegionOfInterest")(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        matrices = {
            "d": np.asarray(D, float),
            "k": np.asarray(K, float).ravel(),
            "r": np.eye(3).ravel() if R is None else np.asarray(R, float).ravel(),
            "p": np.asarray(P, float).ravel(),
        }
        if self.ros1:
            matrices = {name.upper(): value for name, value in matrices.items()}
        return self.T("sensor_msgs/msg/CameraInfo")(
            header=self.header(stamp_ns, "left"),
            height=size[1],
            width=size[0],
            distortion_model="plumb_bob",
            binning_x=0,
            binning_y=0,
            roi=roi,
            **matrices,
        )

    def pose(self, T):
        point = self.T("geometry_msgs/msg/Point")(x=T[0, 3], y=T[1, 3], z=T[2, 3])
        x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
        return self.T("geometry_msgs/msg/Pose")(
            position=point, orientation=self.T("geometry_msgs/msg/Quaternion")(x=x, y=y, z=z, w=w)
        )

    def odometry(self, stamp_ns, T):
        vector = self.T("geometry_msgs/msg/Vector3")(x=0.0, y=0.0, z=0.0)
        twist = self.T("geometry_msgs/msg/Twist")(linear=vector, angular=vector)
        return self.T("nav_msgs/msg/Odometry")(
            header=self.header(stamp_ns, "odom"),
            child_frame_id="camera",
            pose=self.T("geometry_msgs/msg/PoseWithCovariance")(pose=self.pose(T), covariance=np.zeros(36)),
            twist=self.T("geometry_msgs/msg/TwistWithCovariance")(twist=twist, covariance=np.zeros(36)),
        )

    def tf(self, stamp_ns, parent, child, T):
        pose = self.pose(T)
        translation = self.T("geometry_msgs/msg/Vector3")(x=pose.position.x, y=pose.position.y, z=pose.position.z)
        transform = self.T("geometry_msgs/msg/Transform")(translation=translation, rotation=pose.orientation)
        stamped = self.T("geometry_msgs/msg/TransformStamped")(
            header=self.header(stamp_ns, parent), child_frame_id=child, transform=transform
        )
        return self.T("tf2_msgs/msg/TFMessage")(transforms=[stamped])

    def disparity(self, stamp_ns, disparity):
        roi = self.T("sensor_msgs/msg/RegionOfInterest")(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        values = np.where(np.isfinite(disparity), disparity, -1.0).astype(np.float32)
        fields = {"T" if self.ros1 else "t": CAMERA.baseline_m}
        return self.T("stereo_msgs/msg/DisparityImage")(
            header=self.header(stamp_ns, "left"),
            image=self.image(stamp_ns, values, "32FC1"),
            f=CAMERA.focal_px,
            valid_window=roi,
            min_disparity=0.0,
            max_disparity=255.0,
            delta_d=1 / 16,
            **fields,
        )


def projections(camera):
    """Left and right ``P`` as stereo_image_proc publishes them: right ``P[0, 3] = -fx * baseline``."""
    P = np.hstack([camera.K, np.zeros((3, 1))])
    P_right = P.copy()
    P_right[0, 2] += camera.doffs_px
    P_right[0, 3] = -camera.focal_px * camera.baseline_m
    return P, P_right


def stamp(i):
    return T0_NS + i * DT_NS


def write_bag(
    frames,
    path,
    storage,
    *,
    poses="odom",
    encoding="rgb8",
    compressed=False,
    focal=None,
    drop_right=(),
    right_jitter_ns=0,
    pose_stamps=None,
    truth=True,
):
    """Write ``frames`` (StereoFrames) to a bag; the keyword options break it in the ways the tests need."""
    P, P_right = projections(CAMERA)
    K = CAMERA.K
    if focal is not None:
        P, P_right, K = P.copy(), P_right.copy(), K.copy()
        P[0, 0] = P[1, 1] = K[0, 0] = K[1, 1] = focal
    with BagWriter(path, storage) as bag:
        for topic, proj in (("/stereo/left/camera_info", P), ("/stereo/right/camera_info", P_right)):
            bag.write(topic, bag.camera_info(stamp(0), K, proj), stamp(0))
        if poses == "tf":
            bag.write("/tf_static", bag.tf(stamp(0), "base_link", "camera_optical", T_BASE_CAM), stamp(0))
        for i, frame in enumerate(frames):
            t = stamp(i)
            for topic, image, jitter in ((LEFT, frame.left, 0), (RIGHT, frame.right, right_jitter_ns)):
                if topic == RIGHT and i in drop_right:
                    continue
                if compressed:
                    _ok, png = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
                    msg = bag.T("sensor_msgs/msg/CompressedImage")(
                        header=bag.header(t + jitter, "left"), format="png", data=png.ravel()
                    )
                else:
                    array = image[..., ::-1] if encoding == "bgr8" else image
                    msg = bag.image(t + jitter, array, encoding)
                bag.write(topic, msg, t + jitter)
            if truth is True:
                bag.write("/stereo/disparity", bag.disparity(t, frame.disparity_gt), t)
            elif truth:
                bag.write("/stereo/depth", bag.image(t, depth_image(frame, truth), truth), t)
            for ts in pose_stamps(i) if pose_stamps else [t]:
                T = frame.T_world_cam if pose_stamps is None else pose_at(ts)
                if poses == "odom":
                    bag.write("/odom", bag.odometry(ts, T), ts)
                elif poses == "pose":
                    bag.write(
                        "/pose",
                        bag.T("geometry_msgs/msg/PoseStamped")(header=bag.header(ts, "map"), pose=bag.pose(T)),
                        ts,
                    )
                elif poses == "tf":
                    bag.write(
                        "/tf",
                        bag.tf(ts, "odom", "base_link", T @ np.linalg.inv(T_BASE_CAM)),
                        ts,
                        publisher=f"/localiser{i % 2}",
                    )
    return path


def depth_image(frame, encoding):
    """The frame's ground-truth depth as a 32FC1 (metres, NaN invalid) or 16UC1 (millimetres, 0 invalid) image."""
    depth = CAMERA.depth_from_disparity(frame.disparity_gt)
    if encoding == "32FC1":
        return depth.astype(np.float32)
    return np.where(np.isfinite(depth), np.round(depth * 1000), 0).astype(np.uint16)


def pose_at(t_ns):
    """A smooth camera motion: constant velocity and constant angular rate about a fixed axis."""
    s = (t_ns - T0_NS) * 1e-9
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.array([0.1, 0.8, 0.2]) * s).as_matrix()
    T[:3, 3] = [1.0 + 0.5 * s, -0.2 * s, 0.3]
    return T


def bag_path(tmp_path, storage, name="rec"):
    return tmp_path / (f"{name}.bag" if storage == "rosbag1" else name)


@pytest.fixture(scope="module")
def frames():
    scene = sim.indoor_scene(seed=0)
    return list(scene.frames(CAMERA, sim.indoor_trajectory(3, seed=0), seed=0))


@pytest.fixture(scope="module")
def bags(frames, tmp_path_factory):
    root = tmp_path_factory.mktemp("bags")
    return {storage: write_bag(frames, bag_path(root, storage, storage), storage) for storage in STORAGES}


def open_bag(path, **options):
    options.setdefault("pose_topic", "/odom")
    return read_bag(path, left=LEFT, right=RIGHT, **options)


@pytest.mark.parametrize("storage", STORAGES)
def test_bag_frames_poses_camera_and_pairing_are_the_values_written(bags, frames, storage):
    sequence = open_bag(bags[storage], truth_topic="/stereo/disparity")
    assert len(sequence) == len(frames) and sequence.names == ["000000.png", "000001.png", "000002.png"]
    assert sequence.camera == CAMERA
    np.testing.assert_array_equal(sequence.stamps_ns, [stamp(i) for i in range(len(frames))])
    for got, want in zip(sequence, frames):
        np.testing.assert_array_equal(got.left, want.left)
        np.testing.assert_array_equal(got.right, want.right)
        np.testing.assert_allclose(got.T_world_cam, want.T_world_cam, atol=1e-12)
        np.testing.assert_array_equal(np.isnan(got.disparity_gt), np.isnan(want.disparity_gt))
        np.testing.assert_array_equal(
            got.disparity_gt[~np.isnan(got.disparity_gt)], want.disparity_gt[~np.isnan(want.disparity_gt)]
        )


@pytest.mark.parametrize("storage", STORAGES)
def test_bag_maps_to_the_same_map_as_the_kitti_layout(bags, frames, tmp_path, storage):
    kitti = write_sequence(frames, tmp_path / "seq") and read_sequence(tmp_path / "seq")
    settings = config(disparity_source="matcher")
    expected = map_sequence(kitti, settings, progress=False)
    got = map_sequence(open_bag(bags[storage]), settings, progress=False)
    assert expected.n_known > 100
    assert_same_map(got, expected, atol=1e-6)


def test_cli_map_bag_writes_the_kitti_sequences_map(bags, frames, tmp_path):
    write_sequence(frames, tmp_path / "seq")
    common = ["--voxel", "0.2", "--max-range", "8", "--model", "hitmiss", "--matcher-param", "num_disparities=16"]
    assert main(["map", "--sequence", str(tmp_path / "seq"), *common, "--out", str(tmp_path / "a.npz")]) == 0
    assert (
        main(
            [
                "map",
                "--bag",
                str(bags["mcap"]),
                "--left",
                LEFT,
                "--right",
                RIGHT,
                "--tf-frames",
                "odom:camera",
                *common,
                "--out",
                str(tmp_path / "b.npz"),
            ]
        )
        == 2
    )  # the bag has /odom, not /tf
    assert not (tmp_path / "b.npz").exists()
    assert (
        main(
            [
                "map",
                "--bag",
                str(bags["mcap"]),
                "--left",
                LEFT,
                "--right",
                RIGHT,
                "--pose-topic",
                "/odom",
                *common,
                "--out",
                str(tmp_path / "b.npz"),
            ]
        )
        == 0
    )
    assert_same_map(load_map(tmp_path / "b.npz"), load_map(tmp_path / "a.npz"), atol=1e-6)


@pytest.mark.parametrize("storage", ["sqlite3", "rosbag1"])  # ROS 1: /tf from two publishers, two connections
def test_tf_chain_with_a_static_edge_gives_the_camera_pose(frames, tmp_path, storage):
    path = write_bag(frames, bag_path(tmp_path, storage, "tf"), storage, poses="tf", truth=False)
    sequence = open_bag(path, pose_topic=None, tf_frames=("odom", "camera_optical"))
    np.testing.assert_allclose(sequence.poses, [f.T_world_cam for f in frames], atol=1e-9)
    inverse = open_bag(path, pose_topic=None, tf_frames=("camera_optical", "odom"))  # the chain walked upwards
    np.testing.assert_allclose(inverse.poses, [np.linalg.inv(f.T_world_cam) for f in frames], atol=1e-9)


def test_poses_between_samples_are_interpolated_with_slerp(frames, tmp_path):
    path = write_bag(
        frames,
        tmp_path / "interp.bag",
        "rosbag1",
        truth=False,
        pose_stamps=lambda i: [stamp(i) - 37_000_000, stamp(i) + 63_000_000],
    )
    sequence = open_bag(path)
    for i, pose in enumerate(sequence.poses):
        np.testing.assert_allclose(pose, pose_at(stamp(i)), atol=1e-12)  # linear motion, constant rate: exact


@pytest.mark.parametrize("encoding", ["32FC1", "16UC1"])
def test_depth_truth_and_pose_stamped_topics(frames, tmp_path, encoding):
    path = write_bag(frames, tmp_path / "depth", "mcap", poses="pose", truth=encoding)
    sequence = open_bag(path, pose_topic="/pose", truth_topic="/stereo/depth")
    np.testing.assert_allclose(sequence.poses, [f.T_world_cam for f in frames], atol=1e-12)
    for got, want in zip(sequence, frames):
        depth = depth_image(want, encoding).astype(np.float64) * (1.0 if encoding == "32FC1" else 1e-3)
        expected = CAMERA.disparity_from_depth(np.where(depth > 0, depth, np.nan))
        assert np.isfinite(expected).sum() > 1000
        np.testing.assert_allclose(got.disparity_gt, expected, rtol=1e-6, equal_nan=True)
        if encoding == "32FC1":
            np.testing.assert_allclose(got.disparity_gt, want.disparity_gt, rtol=1e-5, equal_nan=True)


def test_bgr8_mono8_and_compressed_images_arrive_as_written(frames, tmp_path):
    bgr = open_bag(write_bag(frames, tmp_path / "bgr", "mcap", encoding="bgr8", truth=False))
    np.testing.assert_array_equal(bgr[1].left, frames[1].left)
    compressed = open_bag(write_bag(frames, tmp_path / "png", "mcap", compressed=True, truth=False))
    np.testing.assert_array_equal(compressed[2].right, frames[2].right)
    grey = [dataclasses.replace(f, left=f.left[..., 0].copy(), right=f.right[..., 0].copy()) for f in frames]
    mono = open_bag(write_bag(grey, tmp_path / "mono", "mcap", encoding="mono8", truth=False))
    np.testing.assert_array_equal(mono[0].left, grey[0].left)
    assert mono[0].left.shape == (CAMERA.height, CAMERA.width)


def test_raw_images_are_rectified_with_K_D_R(frames, tmp_path):
    """A raw camera rotated by R: its image is the rectified one warped by K R^T P^-1; reading undoes it."""
    R = Rotation.from_rotvec([0.0, 0.03, 0.01]).as_matrix()
    P, P_right = projections(CAMERA)
    H = CAMERA.K @ R.T @ np.linalg.inv(P[:, :3])
    size = (CAMERA.width, CAMERA.height)
    texture = cv2.GaussianBlur(frames[0].left, (0, 0), 2.0)
    with BagWriter(tmp_path / "raw", "mcap") as bag:
        for side, proj in (("left", P), ("right", P_right)):
            bag.write(
                f"/cam/{side}/camera_info", bag.camera_info(stamp(0), CAMERA.K, proj, D=[0, 0, 0, 0, 0], R=R), stamp(0)
            )
            bag.write(
                f"/cam/{side}/image_raw", bag.image(stamp(0), cv2.warpPerspective(texture, H, size), "rgb8"), stamp(0)
            )
    sequence = read_bag(tmp_path / "raw", left="/cam/left/image_raw", right="/cam/right/image_raw")
    assert sequence.poses is None
    rectified = sequence[0].left.astype(float)
    inner = (slice(12, -12), slice(12, -12))
    assert np.abs(rectified[inner] - texture[inner]).mean() < 2.0
    assert np.abs(cv2.warpPerspective(texture, H, size)[inner].astype(float) - texture[inner]).mean() > 4.0
    as_rectified = read_bag(tmp_path / "raw", left="/cam/left/image_raw", right="/cam/right/image_raw", rectified=True)
    np.testing.assert_array_equal(as_rectified[0].left, cv2.warpPerspective(texture, H, size))


def truncated(path, tmp_path):
    """A copy of the bag's storage file cut in half."""
    source = path if path.is_file() else next(p for p in path.iterdir() if p.suffix in (".mcap", ".db3"))
    target = tmp_path / f"cut{source.suffix}"
    data = source.read_bytes()
    target.write_bytes(data[: len(data) // 2])
    return target


@pytest.mark.parametrize("storage", STORAGES)
def test_truncated_bag_is_refused_by_name(bags, tmp_path, storage):
    cut = truncated(bags[storage], tmp_path)
    with pytest.raises(PrismapInputError, match=rf"{cut.name}: not a readable ROS bag \(truncated or damaged\?\)"):
        open_bag(cut)
    out = tmp_path / "map.npz"
    assert (
        main(
            [
                "map",
                "--bag",
                str(cut),
                "--left",
                LEFT,
                "--right",
                RIGHT,
                "--pose-topic",
                "/odom",
                "--voxel",
                "0.2",
                "--model",
                "hitmiss",
                "--out",
                str(out),
            ]
        )
        == 2
    )
    assert not out.exists()


BAD_BAGS = {
    "missing topic": ({}, {"pose_topic": "/odometry"}, r"topic /odometry not in the bag"),
    "encoding": ({"encoding": "16UC1"}, {}, r"topic /stereo/left/image_raw: image encoding '16UC1' .* not supported"),
    "zero focal": ({"focal": 0.0}, {}, r"topic /stereo/left/camera_info: camera_info has a zero .*focal length"),
    "no pose": (
        {"pose_stamps": lambda i: [stamp(0) + 1, stamp(2) + 9] if i == 0 else []},
        {},
        r"/odom: no pose within 0.25 s around the image stamp 1700000000.000000000 s",
    ),
    "pose gap": (
        {"pose_stamps": lambda i: [stamp(0) - 1, stamp(2) + 1] if i == 0 else []},
        {"max_pose_gap_s": 0.1},
        r"/odom: no pose within 0.1 s around the image stamp 1700000000.000000000",
    ),
    "unpaired": (
        {"drop_right": (1,)},
        {},
        (
            r"topic /stereo/left/image_raw: the message at stamp 1700000000.100000000 s has no partner on "
            r"/stereo/right/image_raw"
        ),
    ),
    "late right": ({"right_jitter_ns": 7_000_000}, {}, r"no partner on /stereo/right/image_raw within 0.005 s"),
}


@pytest.mark.parametrize("case", sorted(BAD_BAGS))
def test_bad_bags_are_refused_naming_the_topic_and_write_nothing(frames, tmp_path, case):
    writing, reading, message = BAD_BAGS[case]
    path = write_bag(frames, tmp_path / "bad.bag", "rosbag1", truth=False, **writing)
    with pytest.raises(PrismapInputError, match=message):
        open_bag(path, **reading)
    out = tmp_path / "map.npz"
    argv = [
        "map",
        "--bag",
        str(path),
        "--left",
        LEFT,
        "--right",
        RIGHT,
        "--pose-topic",
        reading.get("pose_topic", "/odom"),
        "--voxel",
        "0.2",
        "--model",
        "hitmiss",
        "--out",
        str(out),
    ]
    if "max_pose_gap_s" in reading:
        argv += ["--pose-gap", str(reading["max_pose_gap_s"])]
    assert main(argv) == 2
    assert not out.exists()


def test_late_right_images_pair_within_a_wider_tolerance(frames, tmp_path):
    path = write_bag(frames, tmp_path / "late", "sqlite3", right_jitter_ns=7_000_000, truth=False)
    sequence = open_bag(path, pair_tolerance_s=0.01)
    np.testing.assert_array_equal(sequence[2].right, frames[2].right)


def test_cli_characterise_bag_fits_the_ground_truth_topic_like_the_library(bags, frames, tmp_path):
    from prismap.characterise import characterise_matcher, write_error_model
    from prismap.stereo import make_matcher

    argv = [
        "characterise",
        "--bag",
        str(bags["sqlite3"]),
        "--left",
        LEFT,
        "--right",
        RIGHT,
        "--matcher",
        "bm",
        "--max-components",
        "1",
        "--out",
        str(tmp_path / "cli"),
    ]
    assert main(argv) == 2  # without --truth-topic there is nothing to characterise against
    assert main([*argv, "--truth-topic", "/stereo/disparity"]) == 0
    largest = max(np.nanmax(f.disparity_gt) for f in frames)
    matcher = make_matcher("bm", num_disparities=16 * int(np.ceil((largest + 1) / 16)))
    result = characterise_matcher(frames, matcher, max_components=1, dataset=str(bags["sqlite3"]))
    write_error_model(result.model, tmp_path / "lib.json")
    assert (tmp_path / "cli" / "error_model.json").read_text() == (tmp_path / "lib.json").read_text()


@pytest.mark.parametrize(
    "extra, message",
    [
        ([], "--bag: mapping needs poses; give --pose-topic TOPIC or --tf-frames WORLD:CAMERA"),
        (["--tf-frames", "odom"], "--tf-frames 'odom': expected WORLD:CAMERA frame ids"),
        (["--pose-topic", "/odom", "--workers", "1"], "--bag runs here, without checkpoints"),
        (["--pose-topic", "/odom", "--sequence", "seq"], "give exactly one of --sequence DIR and --bag PATH"),
        (
            ["--pose-topic", "/odom", "--pair-tolerance", "0"],
            "--pair-tolerance must lie in (0, 86400] seconds; got 0.0",
        ),
    ],
)
def test_cli_map_bag_option_errors(bags, tmp_path, capsys, extra, message):
    out = tmp_path / "map.npz"
    assert (
        main(
            [
                "map",
                "--bag",
                str(bags["rosbag1"]),
                "--left",
                LEFT,
                "--right",
                RIGHT,
                "--voxel",
                "0.2",
                "--model",
                "hitmiss",
                "--out",
                str(out),
                *extra,
            ]
        )
        == 2
    )
    assert message in capsys.readouterr().err
    assert not out.exists()
