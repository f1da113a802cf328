"""Dataset readers, map files and exports."""

from prismap.io._frame import StereoFrame
from prismap.io._middlebury import load_middlebury_folder, load_middlebury_motorcycle, read_middlebury_calib
from prismap.io._pfm import read_pfm, write_pfm

__all__ = [
    "StereoFrame",
    "load_middlebury_folder",
    "load_middlebury_motorcycle",
    "read_middlebury_calib",
    "read_pfm",
    "write_pfm",
]
