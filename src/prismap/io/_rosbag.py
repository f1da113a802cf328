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
  millimetres, 0 invalid), stamped like the left images.
"""

import contextlib
import sqlite3
import struct
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from prismap.camera import StereoCamera
from prismap.errors import PrismapInputError
from prismap.io._frame import StereoFrame, frame_index

PAIR_TOLERANCE_S = 0.005
"""Default largest |stamp difference| of a left and a right image of one frame, seconds."""
MAX_POSE_GAP_S = 0.25
"""Default largest spacing of the two pose samples an image stamp is interpolated between, seconds."""

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
DISPARITY = "stereo_msgs/msg/DisparityImage"
ODOMETRY = "nav_msgs/msg/Odometry"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
TF = "tf2_msgs/msg/TFMessage"
_ENCODINGS = {"mono8": 1, "rgb8": 3, "bgr8": 3}
_DEPTH_ENCODINGS = {"32FC1": (np.float32, 1.0), "16UC1": (np.uint16, 1e-3)}
_DISTORTIONS = ("plumb_bob", "rational_polynomial", "equidistant", "")
_DAMAGE = (struct.error, EOFError, KeyError, IndexError, ValueError, OSError, sqlite3.DatabaseError)
"""What rosbags raises, besides its own errors, for a file cut short."""


def read_bag(path, *, left, right, left_info=None, right_info=None, pose_topic=None, tf_frames=None,
             truth_topic=None, rectified=None, pair_tolerance_s=PAIR_TOLERANCE_S, max_pose_gap_s=MAX_POSE_GAP_S):
    """Open a stereo recording in a ROS bag as a sequence (see the module docstring).

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
        image has no partner or no pose within the tolerances. The message names the topic (and stamp).
    """
    return BagSequence(path, left=left, right=right, left_info=left_info, right_info=right_info,
                       pose_topic=pose_topic, tf_frames=tf_frames, truth_topic=truth_topic, rectified=rectified,
                       pair_tolerance_s=pair_tolerance_s, max_pose_gap_s=max_pose_gap_s)


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

    def __init__(self, path, *, left, right, left_info=None, right_info=None, pose_topic=None, tf_frames=None,
                 truth_topic=None, rectified=None, pair_tolerance_s=PAIR_TOLERANCE_S, max_pose_gap_s=MAX_POSE_GAP_S):
        self.path = Path(path)
        self._access = None
        if pose_topic is not None and tf_frames is not None:
            raise PrismapInputError("give a pose topic or tf frames (WORLD:CAMERA), not both")
        left_info = left_info or _info_topic(left)
        right_info = right_info or _info_topic(right)
        with _open(self.path) as reader:
            connections = _connections(reader, self.path)
            wanted = {left: (IMAGE, COMPRESSED), right: (IMAGE, COMPRESSED), left_info: (CAMERA_INFO,),
                      right_info: (CAMERA_INFO,)}
            if pose_topic is not None:
                wanted[pose_topic] = (ODOMETRY, POSE_STAMPED)
            if truth_topic is not None:
                wanted[truth_topic] = (DISPARITY, IMAGE)
            if tf_frames is not None:
                wanted["/tf"] = (TF,)
            for topic, types in wanted.items():
                _check_topic(connections, topic, types, self.path)
            topics = list(wanted) + (["/tf_static"] if "/tf_static" in connections and tf_frames else [])
            messages = _scan(reader, [c for t in topics for c in connections[t]], self.path)
        self._topics = {"left": left, "right": right, "truth": truth_topic}
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
        self.camera, self._maps = _rig(messages[left_info], messages[right_info], left_info, right_info, shape,
                                       rectified if rectified is not None else _named_rectified(left, right))
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
            self.poses = _tf_poses(messages["/tf"], messages.get("/tf_static", []), tf_frames, self.stamps_ns,
                                   max_pose_gap_s)

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
        if self._truth is not None:
            disparity = self._disparity(found["truth"])
        pose = None if self.poses is None else self.poses[index].copy()
        return StereoFrame(left, right, self.camera, disparity, pose,
                           name=f"{self.path.name}@{_seconds(self.stamps_ns[index])}")

    def ground_truth_path(self, index):
        """None: a bag's ground truth is a topic, not a file (the reader interface of ``GroundTruthFrames``)."""
        return None

    def disparity_gt(self, index):
        """Ground-truth disparity of frame ``index`` from the truth topic: (H, W) float32, pixels, NaN = unknown."""
        if self._truth is None:
            raise PrismapInputError(f"{self.path}: no ground-truth topic was given (--truth-topic)")
        return self[index].disparity_gt

    def _reader(self):
        """The reader frames are read with, opened on first access and kept open (see :meth:`close`)."""
        if self._access is None:
            access = _open(self.path)
            access.__enter__()
            self._access = access
        return self._access.reader

    def close(self):
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
    return PrismapInputError(f"{path}: not a readable ROS bag (truncated or damaged?): {type(exc).__name__}: {exc}")


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
        raise PrismapInputError(f"{path}: topic {connection.topic}: a {connection.msgtype} message does not "
                                f"deserialize (truncated or damaged?): {exc}") from None


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
        if connection.msgtype in (IMAGE, DISPARITY):
            image = msg.image if connection.msgtype == DISPARITY else msg
            msg = _ImageMeta(image.encoding, (image.height, image.width))
        elif connection.msgtype == COMPRESSED:
            msg = _ImageMeta(None, None if out[connection.topic] else _decode(msg, connection.topic).shape[:2])
        out[connection.topic].append((stamp, bag_time, msg))
    for items in out.values():
        items.sort(key=lambda item: item[0])
    return out


def _stamp_ns(header):
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _seconds(stamp_ns):
    """A stamp in nanoseconds as exact decimal seconds, for messages."""
    return f"{int(stamp_ns) // 1_000_000_000}.{int(stamp_ns) % 1_000_000_000:09d}"


def _pair(first, second, first_topic, second_topic, tolerance_s, *, both=True):
    """Indices ``(i, j)`` pairing each message of ``first`` with the nearest-stamped one of ``second``.

    Raises when a message of ``first`` (and, with ``both``, of ``second``) has no partner within
    ``tolerance_s``, or two of ``first`` would share one of ``second``.
    """
    a = np.array([item[0] for item in first], dtype=np.int64)
    b = np.array([item[0] for item in second], dtype=np.int64)
    tolerance_ns = round(tolerance_s * 1e9)
    if b.size == 0:
        raise PrismapInputError(f"topic {second_topic} has no messages to pair with {first_topic}")
    j = np.clip(np.searchsorted(b, a), 1, max(1, b.size - 1)) if b.size > 1 else np.zeros(a.size, dtype=np.intp)
    if b.size > 1:
        j = np.where(np.abs(b[j - 1] - a) <= np.abs(b[j] - a), j - 1, j)
    far = np.abs(b[j] - a) > tolerance_ns
    if np.any(far):
        stamp = a[np.argmax(far)]
        raise PrismapInputError(
            f"topic {first_topic}: the message at stamp {_seconds(stamp)} s has no partner on {second_topic} "
            f"within {tolerance_s} s ({int(far.sum())} unpaired)"
        )
    if np.unique(j).size != j.size:
        raise PrismapInputError(f"topics {first_topic} and {second_topic}: two messages pair with one; "
                                f"lower the pairing tolerance (now {tolerance_s} s)")
    if both and j.size != b.size:
        lonely = np.setdiff1d(np.arange(b.size), j)[0]
        raise PrismapInputError(
            f"topic {second_topic}: the message at stamp {_seconds(b[lonely])} s has no partner on {first_topic} "
            f"within {tolerance_s} s ({b.size - j.size} unpaired)"
        )
    return np.arange(a.size), j


def _field(msg, name):
    """A CameraInfo matrix field: ROS 2 spells it lower case (``k``), ROS 1 upper case (``K``)."""
    return np.asarray(getattr(msg, name) if hasattr(msg, name) else getattr(msg, name.upper()), dtype=np.float64)


def _rig(left_infos, right_infos, left_topic, right_topic, shape, rectified):
    """The rectified camera and the remap tables ``((x, y) left, (x, y) right)``, or None when rectified."""
    infos = []
    for topic, items in ((left_topic, left_infos), (right_topic, right_infos)):
        if not items:
            raise PrismapInputError(f"topic {topic} has no camera_info message")
        msg = items[0][2]
        K, D, R, P = _field(msg, "k").reshape(3, 3), _field(msg, "d"), _field(msg, "r").reshape(3, 3), \
            _field(msg, "p").reshape(3, 4)
        if not (K[0, 0] > 0 and K[1, 1] > 0 and P[0, 0] > 0 and P[1, 1] > 0):
            raise PrismapInputError(
                f"topic {topic}: camera_info has a zero or negative focal length (K fx, fy = {K[0, 0]}, {K[1, 1]}; "
                f"P fx, fy = {P[0, 0]}, {P[1, 1]}): the camera is not calibrated"
            )
        if (msg.height, msg.width) != shape and msg.height and msg.width:
            raise PrismapInputError(f"topic {topic}: camera_info is for {msg.width}x{msg.height} images; "
                                    f"the images are {shape[1]}x{shape[0]}")
        infos.append((topic, msg.distortion_model, K, D, R, P))
    try:
        camera = StereoCamera.from_kitti_projections(infos[0][5], infos[1][5], width=shape[1], height=shape[0])
    except PrismapInputError as exc:
        raise PrismapInputError(f"topics {left_topic}, {right_topic}: the P matrices are not a rectified stereo "
                                f"pair as stereo_image_proc publishes them (right P[0, 3] = -fx * baseline): {exc}") from None
    if rectified is None:
        rectified = all(not np.any(D) and np.allclose(R, np.eye(3)) and np.allclose(K, P[:, :3])
                        for _, _, K, D, R, P in infos)
    if rectified:
        return camera, None
    maps = []
    for topic, model, K, D, R, P in infos:
        if model not in _DISTORTIONS:
            raise PrismapInputError(f"topic {topic}: distortion model {model!r} not supported; expected one of "
                                    f"{[m for m in _DISTORTIONS if m]}")
        size = (shape[1], shape[0])
        if model == "equidistant":
            maps.append(cv2.fisheye.initUndistortRectifyMap(K, D[:4], R, P[:, :3], size, cv2.CV_32FC1))
        else:
            maps.append(cv2.initUndistortRectifyMap(K, D, R, P[:, :3], size, cv2.CV_32FC1))
    return camera, maps


def _pixels(msg, topic, encodings):
    """The (H, W[, C]) array of a ``sensor_msgs/Image`` whose encoding is in ``encodings`` {name: (dtype, channels)}."""
    if msg.encoding not in encodings:
        raise PrismapInputError(f"topic {topic}: image encoding {msg.encoding!r} is not supported; "
                                f"expected one of {sorted(encodings)}")
    dtype, channels = encodings[msg.encoding]
    dtype = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    row_bytes = msg.width * channels * dtype.itemsize
    data = np.asarray(msg.data, dtype=np.uint8)
    if msg.step < row_bytes or data.size < msg.step * msg.height:
        raise PrismapInputError(f"topic {topic}: image data of {data.size} bytes is too short for "
                                f"{msg.width}x{msg.height} {msg.encoding} (step {msg.step})")
    rows = data[:msg.step * msg.height].reshape(msg.height, msg.step)[:, :row_bytes]
    values = np.ascontiguousarray(rows).view(dtype).reshape(msg.height, msg.width, channels)
    return values[..., 0] if channels == 1 else values


def _decode(msg, topic):
    """An image message as (H, W) grey or (H, W, 3) RGB uint8."""
    if hasattr(msg, "encoding"):
        image = _pixels(msg, topic, {name: (np.uint8, c) for name, c in _ENCODINGS.items()})
        return np.ascontiguousarray(image[..., ::-1]) if msg.encoding == "bgr8" else image
    image = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.dtype != np.uint8 or image.ndim not in (2, 3):
        raise PrismapInputError(f"topic {topic}: compressed image (format {msg.format!r}) does not decode to 8 bits")
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGB if image.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    return image


def _pose_series(items, topic):
    """``(stamps ns, translations (N, 3), Rotation)`` of an Odometry or PoseStamped topic."""
    if not items:
        raise PrismapInputError(f"topic {topic} has no pose messages")
    poses = [msg.pose.pose if hasattr(msg, "child_frame_id") else msg.pose for _, _, msg in items]
    stamps = np.array([stamp for stamp, _, _ in items], dtype=np.int64)
    translations = np.array([[p.position.x, p.position.y, p.position.z] for p in poses])
    quaternions = np.array([[p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w] for p in poses])
    return _series(stamps, translations, quaternions, topic)


def _series(stamps, translations, quaternions, what):
    norms = np.linalg.norm(quaternions, axis=1)
    if not np.all(np.isfinite(translations)) or not np.all(np.abs(norms - 1) < 1e-3):
        raise PrismapInputError(f"{what}: poses must be finite with unit quaternions; got norms in "
                                f"[{norms.min():.6g}, {norms.max():.6g}]")
    stamps, first = np.unique(stamps, return_index=True)
    return stamps, translations[first], Rotation.from_quat(quaternions[first])


def _interpolate(series, stamps_ns, max_gap_s, what):
    """(N, 4, 4) poses of ``series`` at ``stamps_ns``: linear position, slerp rotation, bounded gap."""
    times, translations, rotations = series
    t = np.asarray(stamps_ns, dtype=np.int64)
    after = np.searchsorted(times, t)
    exact = (after < times.size) & (times[np.minimum(after, times.size - 1)] == t)
    inside = (after > 0) & (after < times.size)
    gap = np.where(inside, times[np.clip(after, 1, times.size - 1)] - times[np.clip(after - 1, 0, times.size - 1)], 0)
    bad = ~exact & (~inside | (gap > max_gap_s * 1e9))
    if np.any(bad):
        stamp = t[np.argmax(bad)]
        raise PrismapInputError(
            f"{what}: no pose within {max_gap_s} s around the image stamp {_seconds(stamp)} s (samples span "
            f"{_seconds(times[0])}-{_seconds(times[-1])} s; {int(bad.sum())} image(s) without a pose)"
        )
    seconds = (times - times[0]) * 1e-9
    query = (t - times[0]) * 1e-9
    poses = np.tile(np.eye(4), (t.size, 1, 1))
    for axis in range(3):
        poses[:, axis, 3] = np.interp(query, seconds, translations[:, axis])
    poses[:, :3, :3] = (Slerp(seconds, rotations)(query) if times.size > 1 else rotations[np.zeros(t.size, int)]).as_matrix()
    return poses


def _tf_poses(dynamic, static, frames, stamps_ns, max_gap_s):
    """``T_world_cam`` at ``stamps_ns`` from ``/tf`` and ``/tf_static`` messages: WORLD -> ... -> CAMERA, edge by edge.

    A dynamic edge is interpolated at each stamp (:func:`_interpolate`); a static one holds its last value.
    """
    world, camera = frames
    edges = {}  # child -> (parent, [(stamp, translation, quaternion)], static)
    for items, is_static in ((dynamic, False), (static, True)):
        for _, _, msg in items:
            for transform in msg.transforms:
                child, parent = transform.child_frame_id.strip("/"), transform.header.frame_id.strip("/")
                t, q = transform.transform.translation, transform.transform.rotation
                entry = edges.setdefault(child, (parent, [], is_static))
                if entry[0] != parent or entry[2] != is_static:
                    raise PrismapInputError(f"/tf: frame {child!r} has two parents or is both static and dynamic "
                                            f"({entry[0]!r}, {parent!r})")
                entry[1].append((_stamp_ns(transform.header), [t.x, t.y, t.z], [q.x, q.y, q.z, q.w]))
    world, camera = world.strip("/"), camera.strip("/")

    def chain(frame):
        path = [frame]
        while path[-1] in edges:
            path.append(edges[path[-1]][0])
            if len(path) > len(edges) + 1:
                raise PrismapInputError(f"/tf: the frames above {frame!r} form a loop")
        return path

    up_camera, up_world = chain(camera), chain(world)
    common = next((f for f in up_camera if f in up_world), None)
    if common is None:
        raise PrismapInputError(f"/tf, /tf_static: no chain of transforms joins frames {world!r} and {camera!r}; "
                                f"known frames are {sorted(set(edges) | {p for p, _ in edges.values()})}")

    def to_ancestor(path):
        """(N, 4, 4) T_ancestor_frame along ``path`` (frame first, ancestor last)."""
        T = np.tile(np.eye(4), (len(stamps_ns), 1, 1))
        for child in path[:-1]:
            parent, samples, is_static = edges[child]
            samples = sorted(samples, key=lambda s: s[0])
            what = f"{'/tf_static' if is_static else '/tf'} {parent} -> {child}"
            if is_static:
                samples = samples[-1:]
            stamps = np.array([s[0] for s in samples], dtype=np.int64)
            series = _series(stamps, np.array([s[1] for s in samples]), np.array([s[2] for s in samples]), what)
            if is_static:
                step = np.eye(4)
                step[:3, :3], step[:3, 3] = series[2].as_matrix()[0], series[1][0]
            else:
                step = _interpolate(series, stamps_ns, max_gap_s, what)
            T = step @ T
        return T

    T_common_cam = to_ancestor(up_camera[:up_camera.index(common) + 1])
    T_common_world = to_ancestor(up_world[:up_world.index(common) + 1])
    return np.linalg.inv(T_common_world) @ T_common_cam
