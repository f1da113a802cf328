"""Stereo sequences recorded in ROS bags (ROS 1 ``.bag``; ROS 2 sqlite3 or MCAP), read with ``rosbags``.

A bag becomes a :class:`BagSequence`, which ``prismap map`` and ``prismap characterise`` consume exactly
like a KITTI-layout :class:`~prismap.io.Sequence`: same attributes, same :class:`StereoFrame` items.

- Images: ``sensor_msgs/Image`` (``mono8``, ``bgr8``, ``rgb8``) or ``sensor_msgs/CompressedImage``
  (anything OpenCV decodes to 8 bits); colour arrives as RGB.
- Rig: the first message of each ``sensor_msgs/CameraInfo`` topic (default ``<image namespace>/camera_info``).
  The camera is read from the rectified projections ``P`` as ``stereo_image_proc`` publishes them: the
  right ``P[0, 3] = -fx * baseline``. Raw images (``rectified=False``) are first remapped with
  ``K``, ``D``, ``R`` and ``P`` (``cv2.initUndistortRectifyMap``, as ``image_proc`` does).
- Poses ``T_world_cam`` of the left camera at each left image stamp: from ``nav_msgs/Odometry`` or
  ``geometry_msgs/PoseStamped`` (the pose of the left camera itself), or from ``/tf`` + ``/tf_static``
  (the chain WORLD -> ... -> CAMERA composed edge by edge). Each is interpolated between the two samples
  around the stamp (linear in position, slerp in rotation) and refused when those are more than
  ``max_pose_gap_s`` apart or the stamp lies outside the samples.
- Pairing: each left image takes the right image whose header stamp is nearest, within ``pair_tolerance_s``;
  an image left without a partner is an error (a bag is not silently thinned).
- Ground truth (optional, for ``characterise``): a ``stereo_msgs/DisparityImage`` topic (pixels, values
  below ``min_disparity`` invalid) or a depth ``sensor_msgs/Image`` (``32FC1`` metres or ``16UC1``
  millimetres, 0 invalid), stamped like the left images; or a LiDAR's ``sensor_msgs/PointCloud2`` scans
  (thesis fig. 3.16): each left image takes the scan nearest in time (within ``scan_tolerance_s``), moved
  into the left camera by the LiDAR-to-camera transform (given, or from ``/tf_static`` between the scan's
  and the left CameraInfo's frame ids) and, with a pose source, by the camera's motion between the scan's
  stamp and the image's; then projected with occlusion handling (:func:`prismap.io.points_to_disparity`).
"""

from __future__ import annotations

import contextlib
import os
import sqlite3
import struct
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from prismap.errors import PrismapInputError
from prismap.io._frame import StereoFrame, frame_index
from prismap.io._rosbag_messages import _ENCODINGS, _decode, _pixels, _rig
from prismap.io._rosbag_poses import _interpolate, _pair, _pose_series, _seconds, _stamp_ns, _tf_poses

PAIR_TOLERANCE_S = 0.005
"""Default largest absolute stamp difference of a left and a right image of one frame, seconds."""


MAX_POSE_GAP_S = 0.25
"""Default largest spacing of the two pose samples an image stamp is interpolated between, seconds."""


IMAGE = "sensor_msgs/msg/Image"


COMPRESSED = "sensor_msgs/msg/CompressedImage"


CAMERA_INFO = "sensor_msgs/msg/CameraInfo"


DISPARITY = "stereo_msgs/msg/DisparityImage"


ODOMETRY = "nav_msgs/msg/Odometry"


POSE_STAMPED = "geometry_msgs/msg/PoseStamped"


TF = "tf2_msgs/msg/TFMessage"


POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"


SCAN_TOLERANCE_S = 0.05
"""Default largest absolute stamp difference of a left image and the LiDAR scan that is its ground truth, seconds."""


LIDAR_OCCLUSION_WINDOW_PX = 2
"""Half-width of the window in which a nearer LiDAR point hides a farther one (see ``points_to_disparity``)."""


_DEPTH_ENCODINGS = {"32FC1": (np.float32, 1.0), "16UC1": (np.uint16, 1e-3)}


_DAMAGE = (struct.error, EOFError, KeyError, IndexError, ValueError, OSError, sqlite3.DatabaseError)
"""What rosbags raises, besides its own errors, for a file cut short."""


def read_bag(path: str | os.PathLike[str], **options: Any) -> BagSequence:
    """Open a stereo recording in a ROS bag as a sequence (see the module docstring).

    The keyword arguments are :class:`BagSequence`'s, all keyword-only.

    Parameters
    ----------
    path : str or Path
        A ROS 1 ``.bag`` file, a ROS 2 bag directory (sqlite3 or MCAP), or a bare ``.mcap`` / ``.db3`` file.
    left, right : str
        Image topics (``sensor_msgs/Image`` or ``CompressedImage``) of the left (reference) and right camera.
    left_info, right_info : str or None
        ``sensor_msgs/CameraInfo`` topics; default ``<namespace of the image topic>/camera_info``.
    pose_topic : str or None
        ``nav_msgs/Odometry`` or ``geometry_msgs/PoseStamped`` topic with the left camera's pose.
    tf_frames : (str, str) or None
        ``(WORLD, CAMERA)`` frame ids looked up in ``/tf`` and ``/tf_static`` instead of ``pose_topic``.
        Without either, frames have no pose (enough for ``characterise``).
    truth_topic : str or None
        Ground-truth ``stereo_msgs/DisparityImage`` or depth image topic, giving ``disparity_gt``.
    lidar_topic : str or None
        ``sensor_msgs/PointCloud2`` scans giving ``disparity_gt`` instead (module docstring).
    T_cam_lidar : (4, 4) float or None
        LiDAR -> left camera transform; None = from ``/tf_static``.
    scan_tolerance_s : float, seconds
        Largest absolute stamp difference of an image and its scan.
    rectified : bool or None
        Whether the images are already rectified. None: yes when both image topics contain ``image_rect``
        or the calibration needs no remapping (``D = 0``, ``R = I``, ``K = P[:, :3]``), else no.
    pair_tolerance_s, max_pose_gap_s : float, seconds
        Left-right pairing tolerance and the pose interpolation gap (module docstring).

    Returns
    -------
    BagSequence

    Raises
    ------
    PrismapInputError
        The bag is missing or unreadable (e.g. truncated); a topic is missing or of the wrong type; an image
        encoding is unsupported; a camera_info has a zero focal length or is not a rectified stereo pair; an
        image has no partner or no pose within the tolerances; no LiDAR-to-camera transform; a scan too far
        in time from its image, or with no point in the image. The message names the topic (and stamp).
    """
    return BagSequence(path, **options)


class BagSequence:
    """A stereo recording opened by :func:`read_bag`; images are read from the bag on access.

    Attributes
    ----------
    path : Path
    camera : StereoCamera
        The rectified pair, with the image size.
    poses : (N, 4, 4) float64 or None
        ``T_world_cam`` of the left camera at each frame's left stamp, metres; None without a pose source.
    stamps_ns : (N,) int64, nanoseconds
        Header stamps of the left images, increasing.
    names : list of str
        ``NNNNNN.png`` by frame index, as :func:`~prismap.io.write_sequence` would name the frames.
    pose_path, ground_truth : None
        A bag has no pose file and no ground-truth occupancy (attributes of :class:`~prismap.io.Sequence`).
    """

    pose_path = None
    ground_truth = None

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        left: str,
        right: str,
        left_info: str | None = None,
        right_info: str | None = None,
        pose_topic: str | None = None,
        tf_frames: tuple[str, str] | None = None,
        truth_topic: str | None = None,
        rectified: bool | None = None,
        pair_tolerance_s: float = PAIR_TOLERANCE_S,
        max_pose_gap_s: float = MAX_POSE_GAP_S,
        lidar_topic: str | None = None,
        T_cam_lidar: npt.ArrayLike | None = None,
        scan_tolerance_s: float = SCAN_TOLERANCE_S,
    ) -> None:
        self.path = Path(path)
        self._access = None
        if pose_topic is not None and tf_frames is not None:
            raise PrismapInputError("give a pose topic or tf frames (WORLD:CAMERA), not both")
        if truth_topic is not None and lidar_topic is not None:
            raise PrismapInputError("give a ground-truth topic or a LiDAR topic, not both")
        left_info = left_info or _info_topic(left)
        right_info = right_info or _info_topic(right)
        with _open(self.path) as reader:
            connections = _connections(reader, self.path)
            wanted = {
                left: (IMAGE, COMPRESSED),
                right: (IMAGE, COMPRESSED),
                left_info: (CAMERA_INFO,),
                right_info: (CAMERA_INFO,),
            }
            if pose_topic is not None:
                wanted[pose_topic] = (ODOMETRY, POSE_STAMPED)
            if truth_topic is not None:
                wanted[truth_topic] = (DISPARITY, IMAGE)
            if tf_frames is not None:
                wanted["/tf"] = (TF,)
            if lidar_topic is not None:
                wanted[lidar_topic] = (POINTCLOUD2,)
            for topic, types in wanted.items():
                _check_topic(connections, topic, types, self.path)
            static = "/tf_static" in connections and (tf_frames or (lidar_topic and T_cam_lidar is None))
            topics = list(wanted) + (["/tf_static"] if static else [])
            messages = _scan(reader, [c for t in topics for c in connections[t]], self.path)
        self._topics = {"left": left, "right": right, "truth": truth_topic or lidar_topic}
        self._types = {topic: connections[topic][0].msgtype for topic in topics}
        self._left, self._right = messages[left], messages[right]
        if not self._left:
            raise PrismapInputError(f"{self.path}: topic {left} has no images")
        self._check_encodings(messages, left, right, truth_topic)
        left_index, right_index = _pair(self._left, self._right, left, right, pair_tolerance_s)
        self._left = [self._left[i] for i in left_index]
        self._right = [self._right[i] for i in right_index]
        self.stamps_ns = np.array([stamp for stamp, _, _ in self._left], dtype=np.int64)
        self.names = [f"{i:06d}.png" for i in range(len(self._left))]
        shape = next(meta.shape for _, _, meta in messages[left] if meta.shape is not None)
        self.camera, self._maps = _rig(
            messages[left_info],
            messages[right_info],
            left_info,
            right_info,
            shape,
            rectified if rectified is not None else _named_rectified(left, right),
        )
        self._truth = None
        if truth_topic is not None:
            truth = messages[truth_topic]
            index, _ = _pair(self._left, truth, left, truth_topic, pair_tolerance_s, both=False)
            self._truth = [truth[i] for i in index]
        self.poses = None
        if pose_topic is not None:
            series = _pose_series(messages[pose_topic], pose_topic)
            self.poses = _interpolate(series, self.stamps_ns, max_pose_gap_s, pose_topic)
        elif tf_frames is not None:
            self.poses = _tf_poses(
                messages["/tf"], messages.get("/tf_static", []), tf_frames, self.stamps_ns, max_pose_gap_s
            )
        self._lidar = None
        if lidar_topic is not None:
            camera_frame = messages[left_info][0][2].header.frame_id
            self._lidar = _lidar_setup(
                messages, lidar_topic, T_cam_lidar, camera_frame, self._left, left, scan_tolerance_s
            )
            self._truth = self._lidar.scans
            if self.poses is not None:  # the camera's motion between each scan and its image
                scan_stamps = np.array([stamp for stamp, _, _ in self._truth], dtype=np.int64)
                if pose_topic is not None:
                    at_scan = _interpolate(series, scan_stamps, max_pose_gap_s, pose_topic)
                else:
                    at_scan = _tf_poses(
                        messages["/tf"], messages.get("/tf_static", []), tf_frames, scan_stamps, max_pose_gap_s
                    )
                self._lidar = replace(self._lidar, image_from_scan=np.linalg.inv(self.poses) @ at_scan)

    def _check_encodings(self, messages, left, right, truth_topic):
        checks = [(left, _ENCODINGS), (right, _ENCODINGS)]
        if truth_topic is not None:
            checks.append((truth_topic, {"32FC1": None} if self._types[truth_topic] == DISPARITY else _DEPTH_ENCODINGS))
        for topic, encodings in checks:
            for stamp, _, meta in messages[topic]:
                if meta.encoding is not None and meta.encoding not in encodings:
                    raise PrismapInputError(
                        f"{self.path}: topic {topic}: image encoding {meta.encoding!r} at stamp {_seconds(stamp)} s "
                        f"is not supported; expected one of {sorted(encodings)}"
                        + (" (or a CompressedImage)" if encodings is _ENCODINGS else "")
                    )

    def __len__(self):
        return len(self._left)

    def __iter__(self):
        return (self[i] for i in range(len(self)))

    def __getitem__(self, index):
        index = frame_index(index, len(self), self.path)
        wanted = [("left", self._left[index]), ("right", self._right[index])]
        if self._truth is not None:
            wanted.append(("truth", self._truth[index]))
        reader = self._reader()
        connections = _connections(reader, self.path)
        found = {}
        try:
            for role, (stamp, bag_time, _) in wanted:
                topic = self._topics[role]
                for connection, _, raw in reader.messages(connections[topic], start=bag_time, stop=bag_time + 1):
                    msg = _deserialize(reader, raw, connection, self.path)
                    if _stamp_ns(msg.header) == stamp:
                        found[role] = msg
                        break
        except _damage() as exc:
            if isinstance(exc, PrismapInputError):
                raise
            raise _unreadable(self.path, exc) from None
        left = self._remap(_decode(found["left"], self._topics["left"]), 0)
        right = self._remap(_decode(found["right"], self._topics["right"]), 1)
        if right.shape != left.shape:
            raise PrismapInputError(f"{self.path}: frame {index}: right image shape {right.shape} != left {left.shape}")
        disparity = None
        if self._lidar is not None:
            disparity = self._lidar.disparity(found["truth"], index, self.camera, self.path)
        elif self._truth is not None:
            disparity = self._disparity(found["truth"])
        pose = None if self.poses is None else self.poses[index].copy()
        return StereoFrame(
            left, right, self.camera, disparity, pose, name=f"{self.path.name}@{_seconds(self.stamps_ns[index])}"
        )

    def ground_truth_path(self, index: int) -> None:
        """None: a bag's ground truth is a topic, not a file (the reader interface of ``GroundTruthFrames``)."""
        return None

    def disparity_gt(self, index: int) -> np.ndarray:
        """Ground-truth disparity of frame ``index`` from the truth topic: (H, W) float32, pixels, NaN = unknown."""
        if self._truth is None:
            raise PrismapInputError(f"{self.path}: no ground-truth topic was given (--truth-topic or --lidar-topic)")
        return self[index].disparity_gt

    def _reader(self):
        """The reader frames are read with, opened on first access and kept open (see :meth:`close`)."""
        if self._access is None:
            access = _open(self.path)
            access.__enter__()
            self._access = access
        return self._access.reader

    def close(self) -> None:
        """Close the bag file kept open for frame access (reopened if a frame is read again)."""
        if self._access is not None:
            self._access.__exit__(None, None, None)
            self._access = None

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        self.close()

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_access"] = None  # an open file does not cross processes
        return state

    def _remap(self, image, which):
        if self._maps is None:
            return image
        map_x, map_y = self._maps[which]
        return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    def _disparity(self, msg):
        topic = self._topics["truth"]
        if self._types[topic] == DISPARITY:
            values = _pixels(msg.image, topic, {"32FC1": (np.float32, 1)}).astype(np.float32)
            values[~(values >= msg.min_disparity)] = np.nan
            return values
        dtype, scale = _DEPTH_ENCODINGS[msg.encoding]
        depth = _pixels(msg, topic, {msg.encoding: (dtype, 1)}).astype(np.float64) * scale
        return self.camera.disparity_from_depth(np.where(depth > 0, depth, np.nan)).astype(np.float32)


@dataclass(frozen=True)
class _Lidar:
    """How a bag's LiDAR scans become each frame's ground-truth disparity.

    Attributes
    ----------
    topic : str
    scans : list of (stamp ns, bag time ns, frame id)
        The scan of each frame.
    T_cam_lidar : (4, 4) float64
    image_from_scan : (N, 4, 4) float64 or None
        Per frame, the camera at the scan's stamp -> the camera at the image's (None: no pose source, no
        motion compensation).
    """

    topic: str
    scans: list
    T_cam_lidar: np.ndarray
    image_from_scan: np.ndarray | None = None

    def disparity(self, msg, index, camera, path):
        """Frame ``index``'s ground-truth disparity from its scan ``msg`` (occlusions handled)."""
        from prismap.io._pointcloud2 import pointcloud2_xyz
        from prismap.io._velodyne import points_to_disparity

        where = f"{path}: topic {self.topic} at stamp {_seconds(self.scans[index][0])} s"
        points = pointcloud2_xyz(msg, where)
        T = self.T_cam_lidar if self.image_from_scan is None else self.image_from_scan[index] @ self.T_cam_lidar
        disparity = points_to_disparity(
            points @ T[:3, :3].T + T[:3, 3], camera, occlusion_window_px=LIDAR_OCCLUSION_WINDOW_PX
        )
        if not np.isfinite(disparity).any():
            raise PrismapInputError(
                f"{where}: none of the scan's {len(points)} points lies in front of the camera "
                "inside its image (wrong extrinsics, or a scan of another direction?)"
            )
        return disparity


def _lidar_setup(messages, topic, T_cam_lidar, camera_frame, left_items, left, tolerance_s):
    """The :class:`_Lidar` of a bag: each left image's scan (of ``messages[topic]``, nearest in time to each of
    ``left_items``) and the LiDAR-to-camera transform (``T_cam_lidar``, else ``/tf_static``)."""
    scans = messages[topic]
    if not scans:
        raise PrismapInputError(f"topic {topic} has no scans")
    index, _ = _pair(left_items, scans, left, topic, tolerance_s, both=False)
    frame_ids = {meta for _, _, meta in scans}
    if len(frame_ids) != 1:
        raise PrismapInputError(f"topic {topic}: scans come in several frames {sorted(frame_ids)}; expected one")
    if T_cam_lidar is None:
        lidar_frame = frame_ids.pop()
        if "/tf_static" not in messages:
            raise PrismapInputError(
                f"no transform from the LiDAR frame {lidar_frame!r} to the camera frame "
                f"{camera_frame!r}: the bag has no /tf_static; give --lidar-extrinsics FILE"
            )
        try:
            first = np.array([left_items[0][0]], dtype=np.int64)
            T_cam_lidar = _tf_poses([], messages["/tf_static"], (camera_frame, lidar_frame), first, 0.0)[0]
        except PrismapInputError as exc:
            raise PrismapInputError(
                f"no transform from the LiDAR frame {lidar_frame!r} to the camera frame "
                f"{camera_frame!r} in /tf_static ({exc}); give --lidar-extrinsics FILE"
            ) from None
    return _Lidar(topic, [scans[i] for i in index], np.asarray(T_cam_lidar, dtype=np.float64))


def _info_topic(image_topic):
    namespace = image_topic.rstrip("/").rpartition("/")[0]
    return f"{namespace}/camera_info"


def _named_rectified(left, right):
    return True if ("image_rect" in left and "image_rect" in right) else None


class _open:
    """``AnyReader`` on one bag as a context manager whose failures are :class:`PrismapInputError`."""

    def __init__(self, path):
        self.path = path

    def __enter__(self):
        AnyReader, typestore = _rosbags()
        if not self.path.exists():
            raise PrismapInputError(f"{self.path}: bag not found")
        try:
            self.reader = AnyReader([self.path], default_typestore=typestore)
            self.reader.open()
        except _damage() as exc:
            raise _unreadable(self.path, exc) from None
        return self.reader

    def __exit__(self, kind, exc, traceback):
        with contextlib.suppress(Exception):
            self.reader.close()
        damaged = kind is not None and issubclass(kind, _damage())
        if damaged and not issubclass(kind, PrismapInputError):
            raise _unreadable(self.path, exc) from None
        return False


def require_rosbags():
    """Raise a clear :class:`PrismapInputError` when the optional ``rosbags`` module is missing."""
    try:
        import rosbags  # noqa: F401
    except ImportError:
        raise PrismapInputError("ROS bags need the optional `rosbags` module: pip install 'prismap[ros]'") from None


def _rosbags():
    """``rosbags.highlevel.AnyReader`` and the ROS 2 Humble typestore (for bags without message definitions)."""
    require_rosbags()
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    return AnyReader, get_typestore(Stores.ROS2_HUMBLE)


def _damage():
    """The exception types that mean a bag (or one of its messages) is damaged or cut short."""
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Reader1Error
    from rosbags.rosbag2 import ReaderError as Reader2Error

    return (AnyReaderError, Reader1Error, Reader2Error, *_DAMAGE)


def _unreadable(path, exc):
    """One line naming the bag and the reader's complaint (a YAML parser's spans several lines: joined)."""
    detail = " ".join(line.strip() for line in str(exc).splitlines() if line.strip() and line.strip() != "^")
    return PrismapInputError(
        f"{path}: not a readable ROS bag (truncated or damaged?): {type(exc).__name__}: {detail[:300]}"
    )


def _connections(reader, path):
    """``{topic: [connections]}``: a ROS 1 topic has one connection per publisher (``/tf`` often several)."""
    connections = {}
    for connection in reader.connections:
        connections.setdefault(connection.topic, []).append(connection)
    return connections


def _check_topic(connections, topic, types, path):
    if topic not in connections:
        raise PrismapInputError(f"{path}: topic {topic} not in the bag; it has {sorted(connections)}")
    held = sorted({connection.msgtype for connection in connections[topic]})
    if any(msgtype not in types for msgtype in held):
        raise PrismapInputError(f"{path}: topic {topic} holds {' and '.join(held)}; expected {' or '.join(types)}")


def _deserialize(reader, raw, connection, path):
    try:
        return reader.deserialize(raw, connection.msgtype)
    except _damage() as exc:  # a message cut short or not of its declared type
        raise PrismapInputError(
            f"{path}: topic {connection.topic}: a {connection.msgtype} message does not "
            f"deserialize (truncated or damaged?): {exc}"
        ) from None


@dataclass(frozen=True)
class _ImageMeta:
    """What opening a bag keeps of an image message: its encoding (None if compressed) and (H, W)."""

    encoding: str | None
    shape: tuple | None


def _scan(reader, connections, path):
    """Every message of ``connections`` as ``{topic: [(header stamp ns, bag time ns, msg), ...]}`` in stamp order.

    Image messages are kept as :class:`_ImageMeta` (pixels are read again on access); the first compressed
    image of a topic is decoded for its size.
    """
    out = {connection.topic: [] for connection in connections}
    for connection, bag_time, raw in reader.messages(connections):
        msg = _deserialize(reader, raw, connection, path)
        stamp = _stamp_ns(msg.header) if hasattr(msg, "header") else bag_time
        if connection.msgtype == POINTCLOUD2:
            msg = msg.header.frame_id.strip("/")  # points are read again on access
        elif connection.msgtype in (IMAGE, DISPARITY):
            image = msg.image if connection.msgtype == DISPARITY else msg
            msg = _ImageMeta(image.encoding, (image.height, image.width))
        elif connection.msgtype == COMPRESSED:
            msg = _ImageMeta(None, None if out[connection.topic] else _decode(msg, connection.topic).shape[:2])
        out[connection.topic].append((stamp, bag_time, msg))
    for items in out.values():
        items.sort(key=lambda item: item[0])
    return out
