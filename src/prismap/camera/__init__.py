"""Stereo camera geometry: intrinsics, disparity <-> depth, rays, triangulation, rectification, the named rigs."""

from prismap.camera._rectify import Rectification, rectify_stereo, warp_pair
from prismap.camera._rigs import KITTI_CAMERA, KITTI_LIKE_CAMERA, MOTORCYCLE_CAMERA, TSUKUBA_CAMERA
from prismap.camera._stereo_camera import StereoCamera

__all__ = [
    "KITTI_CAMERA", "KITTI_LIKE_CAMERA", "MOTORCYCLE_CAMERA", "TSUKUBA_CAMERA", "Rectification", "StereoCamera", "rectify_stereo",
    "warp_pair",
]
