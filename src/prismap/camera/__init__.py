"""Stereo camera geometry: intrinsics, disparity <-> depth, rays, triangulation, rectification, surface normals
from a disparity image, points projected into the image with occlusion handling, the named rigs."""

from prismap.camera._projection import (
    DISPARITY_MARGIN_PX,
    OCCLUSION_WINDOW_PX,
    fitted_disparity,
    project_points,
    visible_points,
)
from prismap.camera._rectify import Rectification, rectify_stereo, warp_pair
from prismap.camera._rigs import AVENUE_CAMERA, KITTI_CAMERA, KITTI_LIKE_CAMERA, MOTORCYCLE_CAMERA, TSUKUBA_CAMERA
from prismap.camera._stereo_camera import StereoCamera
from prismap.camera._surface import PLANE_WINDOW_PX, plane_normals

__all__ = [
    "AVENUE_CAMERA", "DISPARITY_MARGIN_PX", "KITTI_CAMERA", "KITTI_LIKE_CAMERA", "MOTORCYCLE_CAMERA",
    "OCCLUSION_WINDOW_PX", "PLANE_WINDOW_PX", "TSUKUBA_CAMERA", "Rectification", "StereoCamera", "fitted_disparity",
    "plane_normals", "project_points", "rectify_stereo", "visible_points", "warp_pair",
]
