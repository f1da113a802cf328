"""One rectified stereo frame with its calibration and, when known, its ground truth and pose; frame indexing."""

from abc import abstractmethod
from collections.abc import Sequence
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


class LazyFrames(Sequence):
    """Base of the readers whose frames are read from disk on access: ``len(seq)``, ``seq[i]``, ``seq[a:b]``.

    Subclasses define ``__len__`` and ``_frame(index)``, which receives an index already checked and made
    non-negative; ``_index`` does the same for their other per-frame methods.
    """

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self._frame(i) for i in range(*index.indices(len(self)))]
        return self._frame(self._index(index))

    def _index(self, index):
        """``index`` as a position in ``0..len - 1`` (negative counts from the end); IndexError beyond."""
        return frame_index(index, len(self), getattr(self, "path", type(self).__name__))

    @abstractmethod
    def _frame(self, index):
        """The :class:`StereoFrame` at ``index`` (``0 <= index < len``)."""


def frame_index(index, length, where):
    """``index`` as a frame number in ``[0, length)`` (negative counts from the end), as sequences index frames.

    Raises TypeError for a non-integer and IndexError out of range, naming ``where`` (the sequence's path).
    """
    if not isinstance(index, (int, np.integer)):
        raise TypeError(f"sequence indices must be integers; got {type(index).__name__}")
    if not -length <= index < length:
        raise IndexError(f"frame {index} out of range for {length} frames in {where}")
    return int(index) % length
