"""ROS messages to prismap's types: ``sensor_msgs/CameraInfo`` pairs to a :class:`~prismap.camera.StereoCamera`
(with the rectification maps of raw images), ``sensor_msgs/Image`` and ``CompressedImage`` to pixel arrays."""

import cv2
import numpy as np

from prismap.camera import StereoCamera
from prismap.errors import PrismapInputError
from prismap.io._images import check_encoded_image, check_image_pixels

_ENCODINGS = {"mono8": 1, "rgb8": 3, "bgr8": 3}


_DISTORTIONS = ("plumb_bob", "rational_polynomial", "equidistant", "")


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
        K, D, R, P = (
            _field(msg, "k").reshape(3, 3),
            _field(msg, "d"),
            _field(msg, "r").reshape(3, 3),
            _field(msg, "p").reshape(3, 4),
        )
        if not (K[0, 0] > 0 and K[1, 1] > 0 and P[0, 0] > 0 and P[1, 1] > 0):
            raise PrismapInputError(
                f"topic {topic}: camera_info has a zero or negative focal length (K fx, fy = {K[0, 0]}, {K[1, 1]}; "
                f"P fx, fy = {P[0, 0]}, {P[1, 1]}): the camera is not calibrated"
            )
        if (msg.height, msg.width) != shape:
            raise PrismapInputError(
                f"topic {topic}: camera_info is for {msg.width}x{msg.height} images; "
                f"the images are {shape[1]}x{shape[0]}"
            )
        for name, values in (("K", K), ("D", D), ("R", R), ("P", P)):
            if not np.all(np.isfinite(values)):
                raise PrismapInputError(
                    f"topic {topic}: camera_info field {name} holds non-finite values "
                    f"({values.ravel()[~np.isfinite(values.ravel())][:3]}): the camera is not "
                    "calibrated"
                )
        infos.append((topic, msg.distortion_model, K, D, R, P))
    try:
        camera = StereoCamera.from_kitti_projections(infos[0][5], infos[1][5], width=shape[1], height=shape[0])
    except PrismapInputError as exc:
        raise PrismapInputError(
            f"topics {left_topic}, {right_topic}: the P matrices are not a rectified stereo "
            f"pair as stereo_image_proc publishes them (right P[0, 3] = -fx * baseline): {exc}"
        ) from None
    if rectified is None:
        rectified = all(
            not np.any(D) and np.allclose(R, np.eye(3)) and np.allclose(K, P[:, :3]) for _, _, K, D, R, P in infos
        )
    if rectified:
        return camera, None
    maps = []
    for topic, model, K, D, R, P in infos:
        if model not in _DISTORTIONS:
            raise PrismapInputError(
                f"topic {topic}: distortion model {model!r} not supported; expected one of "
                f"{[m for m in _DISTORTIONS if m]}"
            )
        size = (shape[1], shape[0])
        if model == "equidistant":
            maps.append(cv2.fisheye.initUndistortRectifyMap(K, D[:4], R, P[:, :3], size, cv2.CV_32FC1))
        else:
            maps.append(cv2.initUndistortRectifyMap(K, D, R, P[:, :3], size, cv2.CV_32FC1))
    return camera, maps


def _pixels(msg, topic, encodings):
    """The (H, W[, C]) array of a ``sensor_msgs/Image`` whose encoding is in ``encodings`` {name: (dtype, channels)}."""
    if msg.encoding not in encodings:
        raise PrismapInputError(
            f"topic {topic}: image encoding {msg.encoding!r} is not supported; expected one of {sorted(encodings)}"
        )
    dtype, channels = encodings[msg.encoding]
    check_image_pixels(f"topic {topic}", "image", msg.width, msg.height)
    dtype = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    row_bytes = msg.width * channels * dtype.itemsize
    data = np.asarray(msg.data, dtype=np.uint8)
    if msg.step < row_bytes or data.size < msg.step * msg.height:
        raise PrismapInputError(
            f"topic {topic}: image data of {data.size} bytes is too short for "
            f"{msg.width}x{msg.height} {msg.encoding} (step {msg.step})"
        )
    rows = data[: msg.step * msg.height].reshape(msg.height, msg.step)[:, :row_bytes]
    values = np.ascontiguousarray(rows).view(dtype).reshape(msg.height, msg.width, channels)
    return values[..., 0] if channels == 1 else values


def _decode(msg, topic):
    """An image message as (H, W) grey or (H, W, 3) RGB uint8."""
    if hasattr(msg, "encoding"):
        image = _pixels(msg, topic, {name: (np.uint8, c) for name, c in _ENCODINGS.items()})
        return np.ascontiguousarray(image[..., ::-1]) if msg.encoding == "bgr8" else image
    check_encoded_image(np.asarray(msg.data, dtype=np.uint8), f"topic {topic}")
    image = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.dtype != np.uint8 or image.ndim not in (2, 3):
        raise PrismapInputError(f"topic {topic}: compressed image (format {msg.format!r}) does not decode to 8 bits")
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGB if image.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    return image
