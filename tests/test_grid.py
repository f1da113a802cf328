"""The sparse voxel map: keys, ray casting against hand-computed maps and a slow reference, policies,
queries, merging, pose noise and bad input."""

import numpy as np
import pytest

from prismap.errors import PrismapInputError
from prismap.grid import OccupancyMap, key_to_center, point_to_key
from prismap.grid._kernels_traverse import cast_rays
from prismap.sensor_models import InverseSensorModel
from support import FB, L_HIT, L_MISS, HitMissModel, assert_same_map


class ConstantModel(InverseSensorModel):
    """Every cell of ray i gets increment ``values[i]``; rays stop at depth ``depth_m``."""

    name = "test-constant"
    default_policy = "mean"

    def __init__(self, values, depth_m):
        self.values, self.depth_m = np.asarray(values, dtype=float), depth_m

    def cell_posteriors(self, disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m):
        inc = self.values[ray_of_cell]
        return 1 / (1 + np.exp(-inc)), inc

    def influence_depth(self, disparity_px, ray_norm):
        return np.full(np.shape(disparity_px), self.depth_m)

    def with_extra_noise(self, sigma_px):
        return self


def one_ray(origin, ray, depth, *, voxel=0.1, max_range=np.inf, policy=None):
    grid = OccupancyMap(voxel, p0=0.5)
    grid.integrate_rays(origin, [ray], [FB / depth], HitMissModel(FB), max_range_m=max_range, policy=policy)
    return grid


def as_dict(grid):
    keys, log, count = grid.known_voxels()
    assert np.all(count == 1)
    return {tuple(k): float(v) for k, v in zip(keys.tolist(), log)}


def expected(free, hit):
    out = {tuple(k): L_MISS for k in free}
    out.update({tuple(k): L_HIT for k in hit})
    return out


def assert_map(grid, free, hit):
    got, want = as_dict(grid), expected(free, hit)
    assert got.keys() == want.keys()
    for k in want:
        assert got[k] == pytest.approx(want[k], abs=1e-6), k


# ------------------------------------------------------------------------------------------- keys
def test_point_to_key_and_key_to_center_round_trip():
    rng = np.random.default_rng(0)
    keys = rng.integers(-100000, 100000, size=(1000, 3))
    for voxel in (0.05, 0.1, 0.37):
        centers = key_to_center(keys, voxel)
        np.testing.assert_array_equal(point_to_key(centers, voxel), keys)
        points = rng.uniform(-500, 500, size=(1000, 3))
        k = point_to_key(points, voxel)
        assert np.all(np.abs(points - key_to_center(k, voxel)) <= voxel / 2 + 1e-9)
    assert point_to_key([[-0.01, 0.0, 0.099]], 0.1).tolist() == [[-1, 0, 0]]


@pytest.mark.parametrize("bad", [0.0, -0.1, np.nan, np.inf])
def test_bad_voxel_size_is_an_error(bad):
    with pytest.raises(PrismapInputError, match="voxel_size_m"):
        OccupancyMap(bad, p0=0.5)
    with pytest.raises(PrismapInputError, match="voxel_size_m"):
        point_to_key([[0.0, 0.0, 0.0]], bad)


# ------------------------------------------------------------------------------ hand-computed maps
def test_single_ray_along_an_axis():
    grid = one_ray([0.05, 0.05, 0.05], [1.0, 0.0, 0.0], 0.53)
    assert_map(grid, [(x, 0, 0) for x in range(5)], [(5, 0, 0)])


def test_diagonal_ray_through_voxel_corners_skips_touched_voxels():
    grid = one_ray([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], 0.35)
    assert_map(grid, [(0, 0, 0), (1, 1, 1), (2, 2, 2)], [(3, 3, 3)])


def test_ray_shorter_than_one_voxel():
    grid = one_ray([0.01, 0.01, 0.01], [0.0, 0.0, 1.0], 0.05)
    assert_map(grid, [], [(0, 0, 0)])


def test_ray_beyond_max_range_clears_free_space_only():
    grid = one_ray([0.05, 0.05, 0.05], [1.0, 0.0, 0.0], 2.0, max_range=0.5)
    # The max-range point x = 0.55 lies in voxel 5, which is excluded (as OctoMap).
    assert_map(grid, [(x, 0, 0) for x in range(5)], [])


def test_camera_on_a_voxel_boundary():
    grid = one_ray([0.0, 0.05, 0.05], [-1.0, 0.0, 0.0], 0.25)
    assert_map(grid, [(-1, 0, 0), (-2, 0, 0)], [(-3, 0, 0)])
    grid = one_ray([0.0, 0.05, 0.05], [1.0, 0.0, 0.0], 0.25)
    assert_map(grid, [(0, 0, 0), (1, 0, 0)], [(2, 0, 0)])


def test_oblique_ray_with_camera_depth_parameter():
    # Camera ray (x/z, y/z, 1) = (0.5, 0, 1) from (0.05, 0.05, 0.05): x = 0.05 + 0.5 t, z = 0.05 + t.
    # Borders crossed: z=0.1 (t=.05), x=0.1 (t=.1), z=0.2 (.15), z=0.3 (.25), x=0.2 (.3), z=0.4 (.35).
    grid = one_ray([0.05, 0.05, 0.05], [0.5, 0.0, 1.0], 0.4)
    free = [(0, 0, 0), (0, 0, 1), (1, 0, 1), (1, 0, 2), (1, 0, 3), (2, 0, 3)]
    assert_map(grid, free, [(2, 0, 4)])


def reference_cells(origin, ray, t_stop, voxel, exclusive=False):
    """Slow reference: every voxel of the bounding box whose slab interval with the ray passes the rule."""
    end = origin + ray * t_stop
    lo = np.floor(np.minimum(origin, end) / voxel).astype(int) - 1
    hi = np.floor(np.maximum(origin, end) / voxel).astype(int) + 1
    grid = np.stack(np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(lo, hi)], indexing="ij"), -1).reshape(-1, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (grid * voxel - origin) / ray
        tb = ((grid + 1) * voxel - origin) / ray
    t0 = np.maximum(np.minimum(ta, tb).max(axis=1), 0.0)
    t1 = np.maximum(ta, tb).min(axis=1)
    keep = (t1 - t0) > 1e-6 * voxel
    keep &= (t1 <= t_stop) if exclusive else (t0 <= t_stop)
    return {tuple(k): (a, b) for k, a, b in zip(grid[keep], t0[keep], t1[keep])}


def test_cast_rays_matches_slow_reference_on_random_rays():
    rng = np.random.default_rng(1)
    voxel = 0.1
    for exclusive in (False, True):
        origin = rng.uniform(-1, 1, 3)
        rays = rng.normal(size=(40, 3))
        t_stop = rng.uniform(0.01, 1.5, 40)
        ray_of, keys, t_in, t_out = cast_rays(origin, rays, t_stop, np.full(40, exclusive), voxel)
        for i in range(40):
            mine = ray_of == i
            got = {tuple(k): (a, b) for k, a, b in zip(keys[mine].tolist(), t_in[mine], t_out[mine])}
            want = reference_cells(origin, rays[i], t_stop[i], voxel, exclusive)
            assert got.keys() == want.keys()
            for k in want:
                np.testing.assert_allclose(got[k], want[k], atol=1e-9)
            assert np.all(np.diff(t_in[mine]) > 0)  # nearest first


# --------------------------------------------------------------------------------------- policies
@pytest.mark.parametrize(
    ("policy", "want"),
    [("mean", 0.5), ("max-abs", -2.0), ("occupied-wins", 1.5), ("max", 1.5), ("sum", 2.0), (None, 0.5)],
)
def test_policies_combine_rays_of_one_frame_into_one_update(policy, want):
    grid = OccupancyMap(0.1, p0=0.5)
    values = [1.5, 1.0, -2.0, 1.5]
    rays = np.tile([0.0, 0.0, 1.0], (4, 1))
    grid.integrate_rays([0.05, 0.05, 0.05], rays, np.ones(4), ConstantModel(values, 0.3), policy=policy)
    keys, log, count = grid.known_voxels()
    assert sorted(keys[:, 2].tolist()) == [0, 1, 2, 3]
    np.testing.assert_allclose(log, want, atol=1e-6)
    assert np.all(count == 1)


def test_occupied_wins_without_positive_increments_takes_the_mean():
    grid = OccupancyMap(0.1, p0=0.5)
    rays = np.tile([0.0, 0.0, 1.0], (2, 1))
    grid.integrate_rays([0.05, 0.05, 0.05], rays, np.ones(2), ConstantModel([-1.0, -3.0], 0.1), policy="occupied-wins")
    np.testing.assert_allclose(grid.known_voxels()[1], -2.0)


def test_unknown_policy_is_an_error():
    with pytest.raises(PrismapInputError, match="policy"):
        one_ray([0.05, 0.05, 0.05], [1.0, 0.0, 0.0], 0.5, policy="median")


@pytest.mark.parametrize("from_start", [False, True])
def test_cast_into_registers_the_cells_of_cast_rays_while_growing_the_accumulator(from_start):
    """From the origin, the cells of cast_rays bit for bit; from a start depth (floor sampling's casts), the cells of
    cast_rays ending past it, their borders before it crossed at once (depths to rounding)."""
    from prismap.grid import _accumulator

    rng = np.random.default_rng(2)
    origin = rng.uniform(-1, 1, 3)
    rays = rng.normal(size=(300, 3))
    t_stop = rng.uniform(0.01, 3.0, 300)
    exclusive = rng.random(300) < 0.5
    t_start = np.where(rng.random(300) < 0.7, rng.uniform(0.0, 3.5, 300), 0.0) if from_start else np.zeros(300)
    ray_of, keys, t_in, t_out = cast_rays(origin, rays, t_stop, exclusive, 0.1)
    keep = t_out > t_start[ray_of]
    assert keep.all() != from_start
    acc = _accumulator.new_accumulator((3, 3, 3))  # empty: the kernel stops short and is resumed many times
    got_ray, rows, got_in, got_out = _accumulator.cast_into(acc, origin, rays, t_start, t_stop, exclusive, 0.1)
    np.testing.assert_array_equal(got_ray, ray_of[keep])
    np.testing.assert_allclose(got_in, t_in[keep], rtol=1e-12 * from_start, atol=1e-12 * from_start)
    np.testing.assert_allclose(got_out, t_out[keep], rtol=1e-12 * from_start, atol=1e-12 * from_start)
    # Row -> key through the accumulator's blocks: the same voxel keys as cast_rays.
    voxel_keys = acc.voxel_keys().reshape(-1, 3)
    np.testing.assert_array_equal(voxel_keys[rows], keys[keep])
    # Scattered increments land on their voxel: (sum, count, max, min) per row.
    _accumulator.scatter(acc, rows, np.arange(rows.size, dtype=np.float64))
    flat = acc.payload["acc"][: len(acc)].reshape(-1, 4)  # the rows of the blocks in use (spare capacity is garbage)
    counts = np.bincount(rows, minlength=flat.shape[0])
    np.testing.assert_array_equal(flat[:, 1], counts)
    np.testing.assert_allclose(
        flat[:, 0], np.bincount(rows, weights=np.arange(rows.size), minlength=flat.shape[0]), rtol=1e-6
    )


def test_chunked_pipeline_gives_the_map_of_one_chunk(monkeypatch):
    from prismap.grid import _integrators

    rng = np.random.default_rng(4)
    rays = np.column_stack([rng.uniform(-1, 1, (500, 2)), np.ones(500)])
    disparity = FB / rng.uniform(0.3, 3.0, 500)
    maps = []
    for chunk in (10_000, 7):
        monkeypatch.setattr(_integrators, "RAYS_PER_CHUNK", chunk)
        grid = OccupancyMap(0.1, p0=0.5)
        grid.integrate_rays([0.05, -0.3, 0.0], rays, disparity, HitMissModel(FB), policy="mean")
        maps.append(as_dict(grid))
    assert maps[0].keys() == maps[1].keys()
    for k, v in maps[0].items():
        assert maps[1][k] == pytest.approx(v, abs=1e-5)


@pytest.mark.parametrize("ndim", [3, 2])
@pytest.mark.parametrize("policy", ["mean", "max-abs", "occupied-wins", "max", "sum"])
def test_hit_miss_cast_gives_the_map_of_the_cell_path(policy, ndim):
    """A model with hit_miss_increments is added while casting; hiding them takes the generic path
    (cells -> cell_posteriors -> scatter): same voxels, counts and log-odds, with rays cut at max range,
    rays from noise groups and an accumulator grown from empty many times (rays of up to ~40 blocks);
    in 3-D and in a 2-D map (8x8x1 blocks)."""
    from prismap.sensor_models import HitMissModel as LibraryHitMiss

    class CellPath(LibraryHitMiss):
        def hit_miss_increments(self):
            return None

    rng = np.random.default_rng(7)
    rays = np.column_stack([rng.uniform(-1, 1, (2000, 2)), np.ones(2000)])[:, -ndim:]
    disparity = FB / rng.uniform(0.05, 12.0, 2000)
    noise = np.where(rng.random(2000) < 0.5, 0.0, rng.uniform(0.02, 1.0, 2000))
    maps = []
    for cls in (LibraryHitMiss, CellPath):
        model = cls(focal_baseline=FB, voxel_size_m=0.1, p0=0.3)
        assert (model.hit_miss_increments() is None) == (cls is CellPath)
        grid = OccupancyMap(0.1, p0=0.3, ndim=ndim)
        grid.integrate_rays(
            [0.05, -0.3, 0.02][:ndim], rays, disparity, model, policy=policy, max_range_m=8.0, extra_noise_px=noise
        )
        maps.append(grid)
    assert maps[0].n_known > (50_000 if ndim == 3 else 2_000)
    assert_same_map(*maps)


def test_group_by_ray_is_a_stable_sort_by_first_appearance_with_used_rays_and_their_ranks():
    from prismap.grid._kernels_project import group_by_ray

    rng = np.random.default_rng(11)
    ray_of_cell = rng.integers(0, 50, 400) * 2  # odd rays and some even ones have no cell
    t_in, t_out = rng.random(400), rng.random(400)
    order, got_in, got_out, used, local = group_by_ray(ray_of_cell, 103, t_in, t_out, np.zeros(103, np.int64))
    first = np.unique(ray_of_cell, return_index=True)[1]
    np.testing.assert_array_equal(used, ray_of_cell[np.sort(first)])  # rays by their first cell
    rank = np.empty(103, dtype=np.int64)
    rank[used] = np.arange(used.size)
    np.testing.assert_array_equal(order, np.argsort(rank[ray_of_cell], kind="stable"))
    np.testing.assert_array_equal(got_in, t_in[order])
    np.testing.assert_array_equal(got_out, t_out[order])
    np.testing.assert_array_equal(used[local], ray_of_cell[order])
    empty = np.empty(0)
    assert group_by_ray(np.empty(0, dtype=np.int64), 5, empty, empty, np.zeros(5, np.int64))[3].size == 0


def test_group_by_ray_puts_the_rays_in_key_order_then_by_first_appearance():
    """With keys (class + 1), the used rays are a stable sort by key of the rays by first cell, and the cells
    follow their rays: a conditioned model then gets each class's rays and cells as one contiguous run."""
    from prismap.grid._kernels_project import group_by_ray

    rng = np.random.default_rng(12)
    ray_of_cell = rng.integers(0, 80, 600)
    t_in, t_out = rng.random(600), rng.random(600)
    ray_key = rng.integers(0, 5, 90)
    order, got_in, got_out, used, local = group_by_ray(ray_of_cell, 90, t_in, t_out, ray_key)
    first = np.unique(ray_of_cell, return_index=True)[1]
    by_first = ray_of_cell[np.sort(first)]
    np.testing.assert_array_equal(used, by_first[np.argsort(ray_key[by_first], kind="stable")])
    assert np.all(np.diff(ray_key[used]) >= 0) and np.all(np.diff(local) >= 0)
    rank = np.empty(90, dtype=np.int64)
    rank[used] = np.arange(used.size)
    np.testing.assert_array_equal(order, np.argsort(rank[ray_of_cell], kind="stable"))
    np.testing.assert_array_equal(used[local], ray_of_cell[order])
    np.testing.assert_array_equal(got_in, t_in[order])
    np.testing.assert_array_equal(got_out, t_out[order])


def test_frustum_box_holds_the_origin_and_every_stop_point_with_a_voxel_margin():
    from prismap.grid._kernels_project import frustum_box

    rng = np.random.default_rng(12)
    origin = rng.uniform(-1, 1, 3)
    rays = rng.normal(size=(200, 3))
    t_stop = np.where(rng.random(200) < 0.3, 0.0, rng.uniform(0.1, 5.0, 200))
    t_stop[0] = np.nan
    key_min, shape, n = frustum_box(origin, rays, t_stop, 0.1)
    casting = t_stop > 0
    points = np.vstack([origin, origin + rays[casting] * t_stop[casting, None]])
    keys = np.floor(points / 0.1).astype(np.int64)
    assert n == casting.sum()
    np.testing.assert_array_equal(key_min, keys.min(axis=0) - 1)
    np.testing.assert_array_equal(key_min + shape - 1, keys.max(axis=0) + 1)


def test_rotate_rays_equals_the_matrix_product():
    from prismap.camera._frame_batch import rotate_rays

    rng = np.random.default_rng(13)
    rays, rotation = rng.normal(size=(50, 3)), np.linalg.qr(rng.normal(size=(3, 3)))[0]
    np.testing.assert_allclose(rotate_rays(rays, rotation), rays @ rotation.T, rtol=1e-14, atol=1e-15)


def _project(
    key_min,
    shape,
    origin,
    R_cam_world,
    focal,
    cx,
    cy,
    ray_index,
    rays,
    t_stop,
    exclusive,
    voxel_size,
    *,
    capacity=64,
    bits=(2, 2, 2),
    acc=None,
    parts=1,
):
    """The projective walk's kept voxels (subsample 1), its lines in ``parts`` parts whose cell arrays start with
    room for ``capacity`` cells, registered in order in an accumulator (by default empty, so grown many times):
    ``(ray, key, t_in, t_out)`` with keys read back through the accumulator's blocks."""
    from prismap.grid import _accumulator, _kernels_project
    from prismap.grid._kernel_args import Projection

    acc = _accumulator.new_accumulator(bits) if acc is None else acc
    stops = _kernels_project.stop_image(ray_index, t_stop)
    projection = Projection(
        key_min,
        shape,
        origin,
        R_cam_world,
        focal,
        cx,
        cy,
        1.0,
        ray_index,
        rays,
        exclusive,
        stops,
        _kernels_project.tile_stops(stops),
        voxel_size,
    )
    cuts = np.linspace(0, _kernels_project.walk_lines(R_cam_world, shape), parts + 1).astype(np.int64)
    max_cells = _accumulator.frame_budget_bytes() // 32
    walked = [
        _kernels_project.project_part(projection, start, stop, capacity, max_cells)
        for start, stop in zip(cuts[:-1], cuts[1:])
    ]
    keys, ray, t_in, t_out = (np.concatenate([part[k][: part[4]] for part in walked]) for k in range(4))
    n_before = acc.payload["acc"][: len(acc), :, 1].sum()
    _accumulator.scatter_keys(acc, keys, np.arange(keys.shape[0], dtype=np.float64))
    # Each cell lands in the row of its key: the row's only increment is the cell's index.
    rows = acc.payload["acc"][: len(acc)].reshape(-1, 4)
    filled = np.flatnonzero(rows[:, 1] > 0)
    assert rows[:, 1].sum() - n_before == keys.shape[0] == filled.size
    order = np.argsort(rows[filled, 0], kind="stable")
    np.testing.assert_array_equal(acc.voxel_keys().reshape(-1, 3)[filled[order]], keys)
    return ray, keys, t_in, t_out


def _small_view():
    rng = np.random.default_rng(14)
    ray_index = np.arange(48, dtype=np.int32).reshape(6, 8)
    rays = np.column_stack([(np.arange(48) % 8 - 3.5) / 8, (np.arange(48) // 8 - 2.5) / 8, np.ones(48)])
    t_stop = rng.uniform(0.3, 2.0, 48)
    exclusive = rng.random(48) < 0.5
    origin = np.array([0.01, -0.02, 0.03])
    from prismap.grid._kernels_project import frustum_box

    key_min, shape, _ = frustum_box(origin, rays, t_stop, 0.1)
    return (key_min, shape, origin, np.eye(3), 8.0, 3.5, 2.5, ray_index, rays, t_stop, exclusive, 0.1)


def test_projected_cells_do_not_depend_on_the_room_they_start_with():
    # Cell arrays that start with room for 7 cells grow to hold all; same cells in the same order as with room
    # for the whole box, and as with 8^3 blocks (other block changes, other resumes).
    view = _small_view()
    full = _project(*view, capacity=int(np.prod(view[1])))
    for got in (
        _project(*view, capacity=7),
        _project(*view, capacity=7, bits=(3, 3, 3)),
        _project(*view, capacity=7, parts=5),
    ):
        assert got[0].size == full[0].size > 7
        for a, b in zip(full, got):
            np.testing.assert_array_equal(a, b)


def test_the_walk_runs_along_the_world_axis_nearest_the_image_rows():
    from prismap.grid._kernels_project import _loop_axes

    assert _loop_axes(np.eye(3)) == (2, 1, 0)  # looking along world z: lines along x, then y
    street = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # looking along x, z up
    assert _loop_axes(street) == (0, 2, 1)
    assert _loop_axes(street[[1, 0, 2]]) == (0, 1, 2)  # rolled a quarter turn: image rows along world z


def _project_voxels_reference(
    key_min, shape, origin, R_cam_world, focal, cx, cy, ray_index, rays, t_stop, exclusive, voxel_size
):
    """Every voxel of the box by the rule of ``project_voxels`` (numpy, subsample 1): (ray, key, t_in, t_out)."""
    grid = np.stack(np.meshgrid(*(np.arange(s) for s in shape), indexing="ij"), -1).reshape(-1, 3) + key_min
    p = ((grid + 0.5) * voxel_size - origin) @ R_cam_world.T
    with np.errstate(divide="ignore", invalid="ignore"):
        col = np.floor(p[:, 0] * focal / p[:, 2] + cx + 0.5)
        row = np.floor(p[:, 1] * focal / p[:, 2] + cy + 0.5)
        seen = (p[:, 2] > 0) & (col >= 0) & (row >= 0) & (col < ray_index.shape[1]) & (row < ray_index.shape[0])
    ray = np.full(len(grid), -1)
    ray[seen] = ray_index[row[seen].astype(int), col[seen].astype(int)]
    keep = (ray >= 0) & (p[:, 2] - np.sqrt(0.75) * voxel_size <= t_stop[ray])
    grid, p, ray = grid[keep], p[keep], ray[keep]
    lo, r = grid * voxel_size - origin, rays[ray]
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = lo / r, (lo + voxel_size) / r
    inside = (lo <= 0) & (lo + voxel_size > 0)  # axis with r == 0: no limit if the ray lies in the slab
    t0 = np.max(np.where(r != 0, np.minimum(ta, tb), np.where(inside, -np.inf, np.inf)), axis=1)
    t1 = np.min(np.where(r != 0, np.maximum(ta, tb), np.where(inside, np.inf, -np.inf)), axis=1)
    t0 = np.maximum(t0, 0.0)
    miss = t1 <= t0
    t0 = np.where(miss, np.maximum(p[:, 2] - 0.5 * voxel_size, 0.0), t0)
    t1 = np.where(miss, p[:, 2] + 0.5 * voxel_size, t1)
    stop = t_stop[ray]
    keep = np.where(exclusive[ray], t1 <= stop, t0 <= stop)
    return ray[keep], grid[keep], t0[keep], t1[keep]


@pytest.mark.parametrize("pose", ["random", "street"])
@pytest.mark.parametrize("wall", [False, True])
def test_projected_cells_equal_visiting_every_voxel_of_the_box(wall, pose):
    # The walk skips the parts of each line that cannot project into the image, and runs of voxels beyond
    # every stop depth of the image tiles they project to; the result must be that of testing every voxel
    # (a rotated camera, or one looking along world x with z up and a slight pitch and roll, invalid pixels,
    # rays cut at random depths; with a wall: a near third of them).
    from prismap.grid._kernels_project import TILE, frustum_box

    rng = np.random.default_rng(15)
    rows, cols, focal, cx, cy = 2 * TILE, 3 * TILE, 14.0, 1.5 * TILE, TILE - 0.5
    pixel = np.stack(np.meshgrid(np.arange(cols), np.arange(rows)), -1).reshape(-1, 2)
    valid = rng.random(rows * cols) < 0.8
    ray_index = np.full(rows * cols, -1, dtype=np.int32)
    ray_index[valid] = np.arange(valid.sum())
    ray_index = ray_index.reshape(rows, cols)
    if pose == "random":
        R_world_cam = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    else:  # camera x, y, z = world -y, -z, x, pitched and rolled by a few degrees
        tilt = np.linalg.qr(np.eye(3) + rng.normal(scale=0.05, size=(3, 3)))[0]
        R_world_cam = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]) @ (tilt * np.sign(np.diag(tilt)))
    rays_cam = np.column_stack([(pixel[valid, 0] - cx) / focal, (pixel[valid, 1] - cy) / focal, np.ones(valid.sum())])
    rays = rays_cam @ R_world_cam.T
    t_stop = rng.uniform(0.2, 1.5, valid.sum())
    if wall:  # the left two tiles' rays stop near the camera
        t_stop[pixel[valid, 0] < 2 * TILE] = rng.uniform(0.15, 0.3, int((pixel[valid, 0] < 2 * TILE).sum()))
    exclusive = rng.random(valid.sum()) < 0.5
    origin = np.array([0.013, -0.027, 0.031])
    key_min, shape, _ = frustum_box(origin, rays, t_stop, 0.1)
    R_cam_world = np.ascontiguousarray(R_world_cam.T)
    args = (key_min, shape, origin, R_cam_world, focal, cx, cy, ray_index, rays, t_stop, exclusive, 0.1)
    got, want = _project(*args), _project_voxels_reference(*args)
    assert want[0].size > 100

    def ordered(ray, keys, t0, t1):
        order = np.lexsort(keys.T[::-1])
        return ray[order], keys[order], t0[order], t1[order]

    got, want = ordered(*got), ordered(*want)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    np.testing.assert_allclose(got[2], want[2], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got[3], want[3], rtol=1e-12, atol=1e-12)


def test_a_run_of_voxels_is_skipped_only_beyond_the_stops_of_every_tile_it_projects_to():
    from prismap.grid._kernels_project import TILE, _run_beyond_stops

    tile_stop = np.array([[1.0, 5.0]])  # one row of two tiles; camera at the origin looking along z
    reach = 0.05

    def beyond(x, z0, z1):  # a run along the camera's z axis at lateral offset x
        return _run_beyond_stops(x, 0.0, z0, x, 0.0, z1, float(TILE), 0.5 * TILE, 0.5 * TILE, reach, tile_stop)

    assert beyond(-0.1, 2.0, 3.0)  # projects into the left tile only, behind its 1 m
    assert not beyond(-0.1, 0.5, 1.0)  # in front of it
    assert not beyond(-0.1, 1.04, 2.0)  # within reach of it
    assert beyond(1.0875, 3.0, 4.0)  # columns 6.2-6.9: the left tile, one pixel of margin
    assert not beyond(1.3125, 3.0, 4.0)  # columns 6.6-7.5: the margin reaches the right tile's first column
    assert beyond(-2.0, 1.5, 3.0)  # columns -6.7 to -1.3: outside the image, no tile
    assert not beyond(1.5, 2.0, 3.0)  # columns 8-10: the right tile (5 m)
    assert not beyond(-0.1, -1.0, 3.0)  # starts behind the camera
