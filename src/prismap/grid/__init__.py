"""The sparse voxel occupancy map: keys, hashed block storage, ray casting, per-frame policies, queries, merge."""

from prismap.grid._keys import KEY_LIMIT, key_to_center, point_to_key
from prismap.grid._map import FREE, OCCUPIED, OCTOMAP_CLAMP, UNKNOWN, OccupancyMap, pose_noise_px

__all__ = [
    "FREE",
    "KEY_LIMIT",
    "OCCUPIED",
    "OCTOMAP_CLAMP",
    "UNKNOWN",
    "OccupancyMap",
    "key_to_center",
    "point_to_key",
    "pose_noise_px",
]
