"""A map as one ``sensor_msgs/PointCloud2`` of voxel centres with their probability, in an MCAP file or a
ROS 2 bag, for Foxglove and RViz (written with ``rosbags``).

The cloud is unorganised (``height = 1``), little-endian, dense, with the fields ``x``, ``y``, ``z`` (voxel
centres, metres, the map's world frame) and ``probability`` (P(occupied)), all float32, 16 bytes a point.
"""

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from prismap._files import atomic_path
from prismap._validate import check_probability
from prismap.errors import PrismapInputError
from prismap.grid import OccupancyMap, key_to_center
from prismap.io._rosbag import require_rosbags

POINT_FIELDS = ("x", "y", "z", "probability")
_FLOAT32 = 7  # sensor_msgs/PointField.FLOAT32
_STORAGES = ("mcap", "sqlite3")


def write_pointcloud2(grid, path, *, storage=None, frame_id="map", topic="/prismap/map", min_probability=None,
                      stamp_ns=0):
    """Write the known voxels of ``grid`` as one PointCloud2 message, all or nothing.

    Parameters
    ----------
    grid : OccupancyMap
    path : str or Path
        A ``.mcap`` file (replaced atomically if it exists), or a ROS 2 bag directory (which must not exist;
        it appears whole or not at all).
    storage : {"mcap", "sqlite3"} or None
        Storage of a bag directory (default ``"mcap"``); a ``.mcap`` path is always MCAP.
    frame_id : str
        ``header.frame_id`` of the cloud: the frame the map's world coordinates are in.
    topic : str
    min_probability : float in [0, 1] or None
        Keep only voxels with P(occupied) >= this (e.g. 0.5 for the occupied ones); None keeps every known voxel.
    stamp_ns : int, nanoseconds
        Header stamp and log time (0: RViz then uses the latest transform).

    Returns
    -------
    int
        Number of points written.
    """
    require_rosbags()
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    if not isinstance(grid, OccupancyMap):
        raise PrismapInputError(f"`grid` must be an OccupancyMap; got {type(grid).__name__}")
    path = Path(path)
    single_file = path.suffix == ".mcap"
    storage = "mcap" if storage is None or single_file else storage
    if storage not in _STORAGES:
        raise PrismapInputError(f"`storage` must be one of {_STORAGES}; got {storage!r}")
    if not single_file and path.exists():
        raise PrismapInputError(f"{path}: exists; a ROS 2 bag is written into a new directory")
    if not frame_id or not topic.startswith("/"):
        raise PrismapInputError(f"`frame_id` must be non-empty and `topic` start with '/'; got {frame_id!r}, {topic!r}")
    points = _points(grid, min_probability)
    typestore = get_typestore(Stores.ROS2_HUMBLE)
    message = _message(typestore, points, frame_id, stamp_ns)
    path.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp"))
    try:
        bag = staging / path.stem
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        with Writer(bag, version=9, storage_plugin=plugin) as writer:
            connection = writer.add_connection(topic, message.__msgtype__, typestore=typestore)
            writer.write(connection, int(stamp_ns), typestore.serialize_cdr(message, message.__msgtype__))
        if single_file:
            with atomic_path(path) as tmp:
                os.replace(bag / f"{bag.name}.mcap", tmp)
        else:
            os.rename(bag, path)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return len(points)


def _points(grid, min_probability):
    """(N,) structured float32 array of the voxel centres (metres, world frame) and their probability."""
    keys, _, _ = grid.known_voxels()
    probability = grid.probability_at_keys(keys)
    if min_probability is not None:
        keep = probability >= check_probability(min_probability, "min_probability", open_interval=False)
        keys, probability = keys[keep], probability[keep]
    points = np.empty(len(keys), dtype=[(name, "<f4") for name in POINT_FIELDS])
    centers = key_to_center(keys, grid.voxel_size_m)
    points["x"], points["y"], points["z"] = centers.T
    points["probability"] = probability
    return points


def _message(typestore, points, frame_id, stamp_ns):
    types = typestore.types
    stamp = types["builtin_interfaces/msg/Time"](sec=int(stamp_ns) // 10**9, nanosec=int(stamp_ns) % 10**9)
    fields = [types["sensor_msgs/msg/PointField"](name=name, offset=4 * i, datatype=_FLOAT32, count=1)
              for i, name in enumerate(POINT_FIELDS)]
    return types["sensor_msgs/msg/PointCloud2"](
        header=types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id), height=1, width=len(points),
        fields=fields, is_bigendian=False, point_step=points.itemsize, row_step=points.nbytes,
        data=points.view(np.uint8).ravel(), is_dense=True)
