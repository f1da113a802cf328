"""One rectified stereo frame with its calibration and, when known, its ground truth and pose."""

from dataclasses import dataclass, field

import numpy as np

from prismap._validate import check_pose
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
        Camera-to-world pose of the left camera, metres; checked by :func:`prismap._validate.check_pose`
        (a rigid transform), so no invalid pose enters the pipeline from any source.
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

    def __post_init__(self):
        if self.T_world_cam is not None:
            label = f"{self.name}: `T_world_cam`" if self.name else "`T_world_cam`"
            object.__setattr__(self, "T_world_cam", check_pose(self.T_world_cam, label))
