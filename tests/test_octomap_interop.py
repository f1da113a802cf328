"""OctoMap interoperability: prismap with the hit/miss model agrees with `insertPointCloud`, and the
.ot/.bt exports read back with OctoMap give the same state at every voxel centre."""

import numpy as np
import pytest

from prismap.camera import integrate_disparity
from prismap.grid import FREE, OCCUPIED, OccupancyMap
from prismap.io._octomap import write_octomap
from support import HitMissModel, planes_frame, world_points

octomap = pytest.importorskip("octomap")


def octree_states(tree, centers):
    """State of each centre in an OctoMap tree: FREE, OCCUPIED or -1 (unknown)."""
    out = np.full(len(centers), -1, dtype=np.int8)
    for i, c in enumerate(centers):
        try:
            node = tree.search(c)
            out[i] = OCCUPIED if tree.isNodeOccupied(node) else FREE
        except octomap.NullPointerException:
            pass
    return out


@pytest.fixture(scope="module")
def frame_maps():
    camera, pose, depth = planes_frame()
    grid = OccupancyMap(0.1, p0=0.5)
    integrate_disparity(
        grid, camera.focal_baseline / depth, camera, pose, HitMissModel(camera.focal_baseline), max_range_m=12.0
    )
    tree = octomap.OcTree(0.1)
    tree.insertPointCloud(world_points(camera, pose, depth), pose[:3, 3].copy(), maxrange=12.0)
    return grid, tree


def test_hitmiss_states_agree_with_octomap_insert_point_cloud(frame_maps):
    grid, tree = frame_maps
    keys, log, count = grid.known_voxels()
    ours = grid.state_at_keys(keys)
    theirs = octree_states(tree, (keys + 0.5) * 0.1)
    # Voxels OctoMap knows that prismap does not: its leaves cover them; count them from the leaves.
    octo_known = 0
    for leaf in tree.begin_leafs():
        octo_known += round((leaf.getSize() / 0.1) ** 3)
    union = len(keys) + max(0, octo_known - int(np.count_nonzero(theirs >= 0)))
    agree = np.count_nonzero(ours == theirs)
    print(f"agreement {agree}/{union} = {agree / union:.5f}; prismap knows {len(keys)}, OctoMap {octo_known}")
    assert agree / union >= 0.999


@pytest.mark.parametrize("suffix", [".ot", ".bt"])
def test_octomap_files_read_back_with_the_same_states(frame_maps, tmp_path, suffix):
    grid, _ = frame_maps
    path = tmp_path / f"map{suffix}"
    write_octomap(grid, path)
    if suffix == ".ot":
        tree = octomap.OcTree.read(str(path).encode())
    else:
        tree = octomap.OcTree(0.1)
        assert tree.readBinary(str(path).encode())
    keys, _, _ = grid.known_voxels()
    np.testing.assert_array_equal(octree_states(tree, (keys + 0.5) * 0.1), grid.state_at_keys(keys))
