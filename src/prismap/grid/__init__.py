"""The sparse voxel occupancy map: keys, hashed block storage, integrators, per-frame policies, queries, merge.

Design notes (one owner per concept):

- ``_keys``: the voxel key (``floor(p / voxel)``), the block split, the packing and the limit derived from
  them (:data:`KEY_LIMIT`); keys beyond it are refused with the limit in metres, never wrapped.
- ``_logodds``: log-odds are stored in fixed point (int64 units of 2**-20), as Bonxai does, rather than
  summed in a fixed order: a fixed order would tie every merge to the sequence's frame order and still
  round differently from one sequential sum, whereas integer sums are exact in any order, so a map
  merged from chunks (Dask, any workers, any chunking) equals the sequential map bit for bit.
- ``_policies``: the per-frame policies (names, codes, combining rule).
- ``_integrators``: :class:`RayBatch` (measurements along rays: disparities or ranges, with their per-ray
  noise, class and voxel overhang) in, ``make_integrator("ray" | "projective")`` out; the per-frame bounds on
  work and memory (docs/errors.md). The map knows nothing of cameras: ``prismap.camera`` turns a disparity
  image and a pose into a batch.
- ``_fusion``: :class:`PersistentFailure`, :class:`FailureMixture` and :class:`FailureClamp`, how a voxel's
  stored sums (log-odds, count) read as a probability when a matcher's failures persist across views; the
  stored sums stay plain additions.
- ``_traverse``: :func:`crossed_voxels`, the checked traversal for callers outside the integrators (the
  map's queries, the simulator's ground truth).
- ``_kernels_hash``, ``_kernels_traverse``, ``_kernels_project``, ``_kernels_accumulate``: numba kernels,
  called only by the wrappers of this package.
"""

from prismap.grid._floor_sampling import FLOOR_RAYS, RayLevels, image_levels
from prismap.grid._fusion import MAP_READINGS, READINGS, FailureClamp, FailureMixture, MapReading, PersistentFailure
from prismap.grid._integrators import INTEGRATOR_NAMES, Integrator, make_integrator
from prismap.grid._keys import (
    KEY_LIMIT,
    PACK_OFFSET,
    key_limit_m,
    key_range_text,
    key_to_center,
    pack_key_sets,
    pack_keys,
    point_to_key,
    unpack_keys,
)
from prismap.grid._map import FREE, OCCUPIED, OCTOMAP_CLAMP, UNKNOWN, OccupancyMap
from prismap.grid._policies import POLICIES
from prismap.grid._projectors import PROJECTOR_NAMES, ImageProjection, make_projector
from prismap.grid._ray_batch import MEASUREMENT_KINDS, RayBatch
from prismap.grid._traverse import crossed_voxels

__all__ = [
    "FLOOR_RAYS",
    "FREE",
    "INTEGRATOR_NAMES",
    "KEY_LIMIT",
    "MAP_READINGS",
    "MEASUREMENT_KINDS",
    "OCCUPIED",
    "OCTOMAP_CLAMP",
    "READINGS",
    "PACK_OFFSET",
    "POLICIES",
    "PROJECTOR_NAMES",
    "UNKNOWN",
    "ImageProjection",
    "Integrator",
    "OccupancyMap",
    "FailureClamp",
    "FailureMixture",
    "MapReading",
    "PersistentFailure",
    "RayBatch",
    "RayLevels",
    "crossed_voxels",
    "image_levels",
    "key_limit_m",
    "key_range_text",
    "key_to_center",
    "make_integrator",
    "make_projector",
    "pack_key_sets",
    "pack_keys",
    "point_to_key",
    "unpack_keys",
]
