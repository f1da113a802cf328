"""Frames in, map out: mapping configs, sensor models for a camera, sequential or Dask runs, checkpoints,
LiDAR reference maps."""

from prismap.pipeline._characterise import characterise_sequence
from prismap.pipeline._checkpoint import open_checkpoint, remove_checkpoint, run_fingerprint, save_checkpoint
from prismap.pipeline._config import MappingConfig, build_sensor_model
from prismap.pipeline._lidar import (
    LIDAR_P0,
    KittiLidarScans,
    ground_truth_from_map,
    in_camera_view,
    kitti_lidar_scans,
    lidar_reference_map,
)
from prismap.pipeline._run import DisparitySource, integrate_frames, map_sequence

__all__ = [
    "LIDAR_P0",
    "DisparitySource",
    "KittiLidarScans",
    "MappingConfig",
    "build_sensor_model",
    "characterise_sequence",
    "ground_truth_from_map",
    "in_camera_view",
    "integrate_frames",
    "kitti_lidar_scans",
    "lidar_reference_map",
    "map_sequence",
    "open_checkpoint",
    "remove_checkpoint",
    "run_fingerprint",
    "save_checkpoint",
]
