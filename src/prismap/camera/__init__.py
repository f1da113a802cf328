"""Stereo camera geometry: intrinsics, disparity <-> depth, rays, triangulation, rectification, surface normals
from a disparity image, the named rigs."""

from prismap.camera._rectify import Rectification, rectify_stereo, warp_pair
from prismap.camera._rigs import AVENUE_CAMERA, KITTI_CAMERA, KITTI_LIKE_CAMERA, MOTORCYCLE_CAMERA, TSUKUBA_CAMERA
from prismap.camera._stereo_camera import StereoCamera
from prismap.camera._surface import PLANE_WINDOW_PX, plane_normals

__all__ = [
    "AVENUE_CAMERA", "KITTI_CAMERA", "KITTI_LIKE_CAMERA", "MOTORCYCLE_CAMERA", "PLANE_WINDOW_PX", "TSUKUBA_CAMERA",
    "Rectification", "StereoCamera", "plane_normals", "rectify_stereo", "warp_pair",
]
