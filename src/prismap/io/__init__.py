"""Dataset readers, map files and exports."""

from prismap.io._frame import StereoFrame

__all__ = ["StereoFrame"]
