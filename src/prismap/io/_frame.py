"""One rectified stereo frame with its calibration and, when known, its ground truth and pose; frame indexing."""

from dataclasses import dataclass, field

import numpy as np

from prismap.camera import StereoCamera


@dataclass(frozen=True)
class StereoFrame:
    """A rectified stereo frame as every reader and simulator returns it.

    Attributes
    ----------
    left, right : (H, W) or (H, W, 3) uint8
        Rectified images (RGB when colour).
    camera : StereoCamera
    disparity_gt : (H, W) float32, pixels, NaN = unknown; or None
        Ground-truth disparity of the left image.
    T_world_cam : (4, 4) float64 or None
        Camera-to-world pose of the left camera, metres.
    name : str
        Where the frame came from (file or scene and index), for messages and tables.
    """

    left: np.ndarray
    right: np.ndarray
    camera: StereoCamera
    disparity_gt: np.ndarray | None = None
    T_world_cam: np.ndarray | None = None
    name: str = ""
    extras: dict = field(default_factory=dict)


def frame_index(index, length, where):
    """``index`` as a frame number in ``[0, length)`` (negative counts from the end), as sequences index frames.

    Raises TypeError for a non-integer and IndexError out of range, naming ``where`` (the sequence's path).
    """
    if not isinstance(index, (int, np.integer)):
        raise TypeError(f"sequence indices must be integers; got {type(index).__name__}")
    if not -length <= index < length:
        raise IndexError(f"frame {index} out of range for {length} frames in {where}")
    return int(index) % length
