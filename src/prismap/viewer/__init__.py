"""The 3-D map viewer in the browser (viser) and the voxel level-of-detail it draws from."""

from prismap.viewer._app import POINT_BUDGET, MapViewer, load_trajectory
from prismap.viewer._voxels import (
    AGREEMENT,
    CLASSES,
    COLORMAP,
    VoxelLevel,
    VoxelPyramid,
    agreement_codes,
    coarsen,
    probability_colors,
    select,
    select_codes,
    unobserved_cells,
    voxel_classes,
    voxel_pyramid,
)

__all__ = [
    "AGREEMENT",
    "CLASSES",
    "COLORMAP",
    "POINT_BUDGET",
    "MapViewer",
    "VoxelLevel",
    "VoxelPyramid",
    "agreement_codes",
    "coarsen",
    "load_trajectory",
    "probability_colors",
    "select",
    "select_codes",
    "unobserved_cells",
    "voxel_classes",
    "voxel_pyramid",
]
