"""Dataset readers, map files and exports."""

from prismap.io._frame import StereoFrame
from prismap.io._images import write_disparity_png
from prismap.io._kitti import (
    KittiOdometry,
    KittiRaw,
    read_kitti_calib,
    read_kitti_disparity,
    read_kitti_poses,
)
from prismap.io._mapfile import load_map, save_map
from prismap.io._middlebury import (
    MOTORCYCLE_CAMERA,
    load_middlebury_folder,
    load_middlebury_motorcycle,
    read_middlebury_calib,
)
from prismap.io._octomap import to_octree, write_octomap
from prismap.io._pfm import read_pfm, write_pfm
from prismap.io._ply import read_ply, write_ply
from prismap.io._sequence import (
    GroundTruthOccupancy,
    Sequence,
    read_ground_truth,
    read_sequence,
    write_ground_truth,
    write_sequence,
)
from prismap.io._tsukuba import (
    TSUKUBA_CAMERA,
    NewTsukuba,
    read_tsukuba_depth,
    read_tsukuba_disparity,
    read_tsukuba_track,
)
from prismap.io._velodyne import read_velodyne_bin, velodyne_to_camera

__all__ = [
    "GroundTruthOccupancy",
    "KittiOdometry",
    "KittiRaw",
    "MOTORCYCLE_CAMERA",
    "NewTsukuba",
    "Sequence",
    "StereoFrame",
    "TSUKUBA_CAMERA",
    "load_map",
    "load_middlebury_folder",
    "load_middlebury_motorcycle",
    "read_ground_truth",
    "read_kitti_calib",
    "read_kitti_disparity",
    "read_kitti_poses",
    "read_middlebury_calib",
    "read_pfm",
    "read_ply",
    "read_sequence",
    "read_tsukuba_depth",
    "read_tsukuba_disparity",
    "read_tsukuba_track",
    "read_velodyne_bin",
    "save_map",
    "to_octree",
    "velodyne_to_camera",
    "write_disparity_png",
    "write_ground_truth",
    "write_octomap",
    "write_pfm",
    "write_ply",
    "write_sequence",
]
