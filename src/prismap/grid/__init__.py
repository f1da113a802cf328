"""The sparse voxel occupancy map: keys, hashed block storage, integrators, per-frame policies, queries, merge."""

from prismap.grid._integrators import INTEGRATOR_NAMES, ImageProjection, Integrator, RayBatch, make_integrator
from prismap.grid._keys import (
    KEY_LIMIT,
    PACK_OFFSET,
    key_limit_m,
    key_to_center,
    pack_key_sets,
    pack_keys,
    point_to_key,
    unpack_keys,
)
from prismap.grid._map import FREE, OCCUPIED, OCTOMAP_CLAMP, UNKNOWN, OccupancyMap, pose_noise_px
from prismap.grid._policies import POLICIES

__all__ = [
    "FREE",
    "INTEGRATOR_NAMES",
    "KEY_LIMIT",
    "OCCUPIED",
    "OCTOMAP_CLAMP",
    "PACK_OFFSET",
    "POLICIES",
    "UNKNOWN",
    "ImageProjection",
    "Integrator",
    "OccupancyMap",
    "RayBatch",
    "key_limit_m",
    "key_to_center",
    "make_integrator",
    "pack_key_sets",
    "pack_keys",
    "point_to_key",
    "pose_noise_px",
    "unpack_keys",
]
