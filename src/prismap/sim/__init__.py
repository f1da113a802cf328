"""Synthetic worlds with exact ground truth: 2-D rectangle worlds with a 1-row stereo range sensor, and
textured 3-D box scenes (an indoor room, a KITTI-like street, a second street: the avenue) rendered as rectified stereo pairs."""

from prismap.sim._avenue import avenue_scene
from prismap.sim._cameras import avenue_camera, kitti_camera, scaled_camera, tsukuba_camera
from prismap.sim._lidar import LIDAR_FROM_CAMERA_M, lidar_disparity, lidar_scan
from prismap.sim._poses import pose_from_heading, poses_from_se2
from prismap.sim._scene3d import Scene3D, indoor_scene, indoor_trajectory
from prismap.sim._street import street_scene, street_trajectory, street_trajectory_between
from prismap.sim._textures import OTHER_PHOTOGRAPHS, PHOTOGRAPHS, texture_bank
from prismap.sim._truth import SOLID_DEPTH_QUANTILE, solid_depth_along_rays
from prismap.sim._world2d import (
    DisparityFrame,
    StereoScanner2D,
    World2D,
    office_world,
    simple_world,
    waypoint_path,
)

__all__ = [
    "LIDAR_FROM_CAMERA_M",
    "OTHER_PHOTOGRAPHS",
    "PHOTOGRAPHS",
    "SOLID_DEPTH_QUANTILE",
    "DisparityFrame",
    "Scene3D",
    "StereoScanner2D",
    "World2D",
    "avenue_camera",
    "avenue_scene",
    "indoor_scene",
    "indoor_trajectory",
    "kitti_camera",
    "lidar_disparity",
    "lidar_scan",
    "office_world",
    "pose_from_heading",
    "poses_from_se2",
    "scaled_camera",
    "simple_world",
    "solid_depth_along_rays",
    "street_scene",
    "street_trajectory",
    "street_trajectory_between",
    "texture_bank",
    "tsukuba_camera",
    "waypoint_path",
]
