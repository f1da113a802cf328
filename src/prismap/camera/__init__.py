"""Stereo camera geometry: intrinsics, disparity <-> depth, rays, triangulation, rectification, surface normals
from a disparity image, the named rigs, and the camera side of mapping: a disparity image seen from a pose as the
map's batch of measurements along rays (with pose noise and each ray's voxel overhang)."""

from prismap.camera._frame_batch import (
    OVERHANG_CAP_VOXELS,
    disparity_batch,
    frame_overhang_m,
    integrate_disparity,
    pose_noise_px,
    voxel_overhang_m,
)
from prismap.camera._rectify import Rectification, rectify_stereo, warp_pair
from prismap.camera._rigs import KITTI_CAMERA, KITTI_LIKE_CAMERA, MOTORCYCLE_CAMERA, TSUKUBA_CAMERA
from prismap.camera._stereo_camera import StereoCamera
from prismap.camera._surface import PLANE_WINDOW_PX, plane_normals

__all__ = [
    "KITTI_CAMERA", "KITTI_LIKE_CAMERA", "MOTORCYCLE_CAMERA", "OVERHANG_CAP_VOXELS", "PLANE_WINDOW_PX", "TSUKUBA_CAMERA",
    "Rectification", "StereoCamera", "disparity_batch", "frame_overhang_m", "integrate_disparity", "plane_normals",
    "pose_noise_px", "rectify_stereo", "voxel_overhang_m", "warp_pair",
]
