"""Stereo camera geometry: intrinsics, disparity <-> depth, rays, triangulation, rectification, surface normals
from a disparity image, points projected into the image with occlusion handling, the named rigs, and the camera
side of mapping: a disparity image seen from a pose as the map's batch of measurements along rays (with pose noise
and each ray's voxel overhang)."""

from prismap.camera._frame_batch import (
    OVERHANG_CAP_VOXELS,
    disparity_batch,
    frame_overhang_m,
    integrate_disparity,
    pose_noise_px,
    voxel_overhang_m,
)
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
    "AVENUE_CAMERA",
    "DISPARITY_MARGIN_PX",
    "KITTI_CAMERA",
    "KITTI_LIKE_CAMERA",
    "MOTORCYCLE_CAMERA",
    "OCCLUSION_WINDOW_PX",
    "OVERHANG_CAP_VOXELS",
    "PLANE_WINDOW_PX",
    "TSUKUBA_CAMERA",
    "Rectification",
    "StereoCamera",
    "disparity_batch",
    "fitted_disparity",
    "frame_overhang_m",
    "integrate_disparity",
    "plane_normals",
    "pose_noise_px",
    "project_points",
    "rectify_stereo",
    "visible_points",
    "voxel_overhang_m",
    "warp_pair",
]
