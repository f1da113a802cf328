"""A map as one ``sensor_msgs/PointCloud2`` of voxel centres with their probability, in an MCAP file or a
ROS 2 bag, for Foxglove and RViz (written with ``rosbags``).

The cloud is unorganised (``height = 1``), little-endian, dense, with the fields ``x``, ``y``, ``z`` (voxel
centres, metres, the map's world frame) and ``probability`` (P(occupied)), all float32, 16 bytes a point.
"""

from __future__ import annotations

import os
import shutil
import sqlite3
import tempfile
from pathlib import Path

import numpy as np

from prismap._files import atomic_path, make_parents, remove_if_empty
from prismap._validate import check_probability
from prismap.errors import PrismapInputError
from prismap.grid import OccupancyMap, key_to_center
from prismap.io._rosbag import require_rosbags

POINT_FIELDS = ("x", "y", "z", "probability")
_FLOAT32 = 7  # sensor_msgs/PointField.FLOAT32
_STORAGES = ("mcap", "sqlite3")


def write_pointcloud2(
    grid: OccupancyMap,
    path: str | os.PathLike[str],
    *,
    storage: str | None = None,
    frame_id: str = "map",
    topic: str = "/prismap/map",
    min_probability: float | None = None,
    stamp_ns: int = 0,
) -> int:
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
    created = make_parents(path)
    staging = None
    done = False
    try:
        staging = Path(tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp"))
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
        done = True
    except (OSError, sqlite3.Error) as exc:
        raise PrismapInputError(f"{path}: cannot write ({getattr(exc, 'strerror', None) or exc})") from None
    finally:
        if staging is not None:
            shutil.rmtree(staging, ignore_errors=True)
        if not done:
            remove_if_empty(created)
    return len(points)


def _points(grid, min_probability):
    """(N,) structured float32 array of the voxel centres (metres, world frame) and their probability."""
    keys, probability, _, _ = grid.known_probabilities()
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
    fields = [
        types["sensor_msgs/msg/PointField"](name=name, offset=4 * i, datatype=_FLOAT32, count=1)
        for i, name in enumerate(POINT_FIELDS)
    ]
    return types["sensor_msgs/msg/PointCloud2"](
        header=types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id),
        height=1,
        width=len(points),
        fields=fields,
        is_bigendian=False,
        point_step=points.itemsize,
        row_step=points.nbytes,
        data=points.view(np.uint8).ravel(),
        is_dense=True,
    )


_FIELD_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
"""sensor_msgs/PointField datatypes as numpy type codes."""


def pointcloud2_xyz(msg, where):
    """The finite ``x, y, z`` points of a ``sensor_msgs/PointCloud2`` message: (N, 3) float64, metres, its frame.

    Reads any layout: the fields' offsets and datatypes, ``point_step``, ``row_step`` and the byte order;
    points with a NaN or infinite coordinate (an organised cloud's no-returns) are dropped.

    Raises
    ------
    PrismapInputError
        ``x``, ``y`` or ``z`` is missing or not a number type, or the data is shorter than its size says;
        the message names ``where`` (topic and stamp).
    """
    fields = {field.name: field for field in msg.fields}
    missing = [name for name in "xyz" if name not in fields]
    if missing:
        raise PrismapInputError(f"{where}: PointCloud2 has no field(s) {missing}; it has {sorted(fields)}")
    order = ">" if msg.is_bigendian else "<"
    n_rows, n_cols, step, row_step = int(msg.height), int(msg.width), int(msg.point_step), int(msg.row_step)
    data = np.asarray(msg.data, dtype=np.uint8)
    needed = (n_rows - 1) * row_step + n_cols * step if n_rows and n_cols else 0
    if data.size < needed:
        raise PrismapInputError(
            f"{where}: PointCloud2 data holds {data.size} bytes; {n_rows}x{n_cols} points of "
            f"{step} bytes in rows of {row_step} need more"
        )
    columns = []
    for name in "xyz":
        field = fields[name]
        if field.datatype not in _FIELD_TYPES or field.offset + np.dtype(_FIELD_TYPES[field.datatype]).itemsize > step:
            raise PrismapInputError(
                f"{where}: PointCloud2 field {name!r} has datatype {field.datatype} at offset "
                f"{field.offset}; expected a number type inside the {step}-byte point"
            )
        dtype = np.dtype(order + _FIELD_TYPES[field.datatype])
        rows = [np.ndarray((n_cols,), dtype, data, r * row_step + field.offset, (step,)) for r in range(n_rows)]
        columns.append(np.concatenate(rows).astype(np.float64) if rows else np.empty(0))
    points = np.stack(columns, axis=1)
    return points[np.isfinite(points).all(axis=1)]
