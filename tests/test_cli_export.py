"""``prismap export`` and ``prismap.io.write_pointcloud2``: a map with known voxels written to every format and read
back (PointCloud2 with rosbags itself, PLY, OctoMap), bad options refused with exit 2 and nothing written."""

import numpy as np
import octomap
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from prismap.cli import main
from prismap.errors import PrismapInputError
from prismap.grid import OccupancyMap
from prismap.io import read_ply, save_map, write_pointcloud2

VOXEL = 0.25


@pytest.fixture(scope="module")
def grid():
    """40 voxels with log-odds from -3 to 3 (about half occupied), keys on both sides of 0."""
    rng = np.random.default_rng(7)
    keys = np.unique(rng.integers(-30, 30, size=(40, 3)), axis=0)
    log = np.linspace(-3.0, 3.0, len(keys))
    grid = OccupancyMap(VOXEL, p0=0.2)
    grid.set_voxels(keys, log, np.full(len(keys), 3))
    return grid


@pytest.fixture(scope="module")
def map_file(grid, tmp_path_factory):
    path = tmp_path_factory.mktemp("export") / "map.npz"
    save_map(grid, path)
    return path


def read_cloud(path):
    """``(frame_id, topic, (N, 4) float32 x y z probability)`` of the one PointCloud2 in a bag, parsed by its fields."""
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        ((connection, _, raw),) = list(reader.messages())
        msg = reader.deserialize(raw, connection.msgtype)
    assert connection.msgtype == "sensor_msgs/msg/PointCloud2" and msg.height == 1 and not msg.is_bigendian
    dtype = np.dtype(
        {
            "names": [f.name for f in msg.fields],
            "formats": ["<f4"] * len(msg.fields),
            "offsets": [f.offset for f in msg.fields],
            "itemsize": msg.point_step,
        }
    )
    assert [(f.name, f.datatype, f.count) for f in msg.fields] == [(n, 7, 1) for n in ("x", "y", "z", "probability")]
    points = np.frombuffer(msg.data.tobytes(), dtype=dtype, count=msg.width)
    assert msg.row_step == msg.width * msg.point_step
    return msg.header.frame_id, connection.topic, np.stack([points[n] for n in dtype.names], axis=1)


def expected_points(grid, min_probability=0.0):
    keys, _, _ = grid.known_voxels()
    probability = grid.probability_at_keys(keys)
    keep = probability >= min_probability
    return np.column_stack([(keys[keep] + 0.5) * VOXEL, probability[keep]]).astype(np.float32)


def sort_rows(points):
    return points[np.lexsort(points.T[::-1])]


@pytest.mark.parametrize(
    "target, options",
    [
        ("map.mcap", []),
        ("bag_mcap", ["--format", "rosbag2"]),
        ("bag_db3", ["--format", "rosbag2", "--storage", "sqlite3"]),
    ],
)
def test_pointcloud2_reads_back_as_the_maps_known_voxels(grid, map_file, tmp_path, target, options, capsys):
    out = tmp_path / target
    assert main(["export", str(map_file), "--to", str(out), *options]) == 0
    assert f"{grid.n_known} points on /prismap/map (frame map)" in capsys.readouterr().out
    frame_id, topic, points = read_cloud(out)
    assert (frame_id, topic) == ("map", "/prismap/map")
    np.testing.assert_array_equal(sort_rows(points), sort_rows(expected_points(grid)))
    if "sqlite3" in options:
        assert (out / "bag_db3.db3").is_file()


def test_pointcloud2_options_frame_topic_and_threshold(grid, tmp_path):
    count = write_pointcloud2(grid, tmp_path / "occ.mcap", frame_id="odom", topic="/voxels", min_probability=0.5)
    frame_id, topic, points = read_cloud(tmp_path / "occ.mcap")
    want = expected_points(grid, 0.5)
    assert (frame_id, topic, count) == ("odom", "/voxels", len(want)) and 0 < count < grid.n_known
    np.testing.assert_array_equal(sort_rows(points), sort_rows(want))


def test_ply_and_octomap_exports_hold_the_map(grid, map_file, tmp_path):
    assert main(["export", str(map_file), "--to", str(tmp_path / "m.ply")]) == 0
    centers, probability = read_ply(tmp_path / "m.ply")
    _, occupied_centers, occupied_probability = grid.occupied_voxels()
    np.testing.assert_array_equal(centers, occupied_centers.astype(np.float32))
    np.testing.assert_array_equal(probability, occupied_probability.astype(np.float32))
    for suffix in (".ot", ".bt"):
        assert main(["export", str(map_file), "--to", str(tmp_path / f"m{suffix}")]) == 0
    keys, log, _ = grid.known_voxels()
    tree = octomap.OcTree.read(str(tmp_path / "m.ot").encode())
    values = [tree.search((key + 0.5) * VOXEL).getLogOdds() for key in keys]
    np.testing.assert_allclose(values, log, atol=1e-5)
    binary = octomap.OcTree(VOXEL)
    assert binary.readBinary(str(tmp_path / "m.bt").encode())
    occupied = [binary.isNodeOccupied(binary.search((key + 0.5) * VOXEL)) for key in keys]
    np.testing.assert_array_equal(occupied, log > 0)


@pytest.mark.parametrize(
    "target, options, message",
    [
        ("map.xyz", [], "cannot tell the format from the suffix '.xyz'"),
        ("map.ply", ["--format", "mcap"], "--format mcap files end in .mcap"),
        ("bag.mcap", ["--format", "rosbag2"], "a ROS 2 bag is a directory"),
        ("cloud.mcap", ["--min-probability", "1.5"], "min_probability"),
    ],
)
def test_bad_export_options_exit_2_and_write_nothing(map_file, tmp_path, target, options, message, capsys):
    assert main(["export", str(map_file), "--to", str(tmp_path / target), *options]) == 2
    assert message in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_existing_outputs_are_refused_or_replaced_whole(grid, map_file, tmp_path):
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "keep.txt").write_text("mine")
    with pytest.raises(PrismapInputError, match="exists; a ROS 2 bag is written into a new directory"):
        write_pointcloud2(grid, bag)
    assert [p.name for p in bag.iterdir()] == ["keep.txt"]
    target = tmp_path / "old.mcap"
    target.write_bytes(b"old")
    assert main(["export", str(map_file), "--to", str(target)]) == 0
    assert read_cloud(target)[2].shape == (grid.n_known, 4)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "old.mcap"]  # no staging left behind
