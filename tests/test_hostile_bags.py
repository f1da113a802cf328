"""Hostile input, round two (issue 25): ROS bags, through the real ``prismap`` in a subprocess under the
address-space limit of ``test_hostile``: exit 2, one line naming the topic or option, nothing left behind."""

import cv2
import numpy as np
import pytest
from test_hostile import _png_bomb, expand, refused_line
from test_io_rosbag import LEFT, RIGHT, BagWriter, frames, projections, stamp, write_bag  # noqa: F401 (a fixture)

from support import CAMERA

MAP_BAG = ["map", "--bag", "BAG", "--left", LEFT, "--right", RIGHT, "--pose-topic", "/odom", "--voxel", "0.1"]


@pytest.fixture(scope="module")
def bag(frames, tmp_path_factory):  # noqa: F811
    return write_bag(frames, tmp_path_factory.mktemp("bag25") / "rec.bag", "rosbag1")


def _hostile_bag(path, frames, *, image=None, info_size=(96, 72), D=()):  # noqa: F811
    """A ROS 1 bag of ``frames`` as CompressedImage PNGs (``image(frame)`` bytes instead, when given), with
    camera_info of ``info_size`` and distortion ``D``, and odometry poses."""
    P, P_right = projections(CAMERA)
    with BagWriter(path, "rosbag1") as bag:
        for topic, proj in (("/stereo/left/camera_info", P), ("/stereo/right/camera_info", P_right)):
            bag.write(topic, bag.camera_info(stamp(0), CAMERA.K, proj, D=D, size=info_size), stamp(0))
        for i, frame in enumerate(frames):
            for topic, pixels in ((LEFT, frame.left), (RIGHT, frame.right)):
                data = image(frame) if image else cv2.imencode(".png", pixels)[1].tobytes()
                msg = bag.T("sensor_msgs/msg/CompressedImage")(
                    header=bag.header(stamp(i), "left"), format="png", data=np.frombuffer(data, np.uint8)
                )
                bag.write(topic, msg, stamp(i))
            bag.write("/odom", bag.odometry(stamp(i), frame.T_world_cam), stamp(i))
    return path


def _run(argv, tmp_path, bag):
    work = tmp_path / "work"
    work.mkdir(exist_ok=True)
    return refused_line(expand(argv, None, WORK=work, BAG=bag), tmp_path, work)


@pytest.mark.parametrize("value", ["inf", "1e300", "nan"])
def test_a_pairing_tolerance_beyond_a_day_is_one_line(bag, tmp_path, value):
    """Item 13: inf overflowed converting to nanoseconds (a traceback)."""
    line = _run([*MAP_BAG, "--pair-tolerance", value, "--out", "WORK/o.npz"], tmp_path, bag)
    assert "--pair-tolerance must lie in (0, 86400] seconds; got" in line


def test_compressed_png_bombs_are_refused_from_their_header(frames, tmp_path):  # noqa: F811
    """Item 8: 20000x20000 PNGs in CompressedImages (camera_info 0x0) reached SGBM, which crashed (exit 139)."""
    bag = _hostile_bag(tmp_path / "bomb.bag", frames, image=lambda f: _png_bomb(20000, 20000), info_size=(0, 0))
    line = _run([*MAP_BAG, "--out", "WORK/o.npz"], tmp_path, bag)
    assert "declares 20000x20000 pixels, more than the limit of 134217728 pixels (MAX_IMAGE_PIXELS)" in line
    assert f"topic {LEFT}" in line


def test_camera_info_of_0x0_images_is_refused(frames, tmp_path):  # noqa: F811
    bag = _hostile_bag(tmp_path / "zero.bag", frames, info_size=(0, 0))
    line = _run([*MAP_BAG, "--out", "WORK/o.npz"], tmp_path, bag)
    assert "camera_info is for 0x0 images; the images are 96x72" in line


def test_nan_distortion_is_refused_naming_the_field(frames, tmp_path):  # noqa: F811
    """Item 3: NaN distortion coefficients gave an empty map, exit 0."""
    bag = _hostile_bag(tmp_path / "nan.bag", frames, D=(float("nan"), 0.0, 0.0, 0.0, 0.0))
    line = _run([*MAP_BAG, "--rectified", "no", "--out", "WORK/o.npz"], tmp_path, bag)
    assert "camera_info field D holds non-finite values" in line


def test_a_compressed_image_of_another_format_is_refused(frames, tmp_path):  # noqa: F811
    bag = _hostile_bag(tmp_path / "bmp.bag", frames, image=lambda f: cv2.imencode(".bmp", f.left)[1].tobytes())
    line = _run([*MAP_BAG, "--out", "WORK/o.npz"], tmp_path, bag)
    assert "compressed image is neither PNG nor JPEG" in line


def test_a_malformed_ros2_metadata_yaml_is_one_line(tmp_path):
    """Item 16: the YAML parser's message spans 8 lines."""
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: [1\n  storage_identifier: mcap\n")
    line = _run([*MAP_BAG, "--out", "WORK/o.npz"], tmp_path, bag)
    assert f"{bag}: not a readable ROS bag" in line and "metadata.yaml" in line
