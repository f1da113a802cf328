"""Voxel keys: the limit from the block bits, packing (numba == numpy), round trips at and across every
boundary (block, sign, +-limit), and refusals that give the limit in metres."""

import numba
import numpy as np
import pytest

from prismap.errors import PrismapInputError
from prismap.grid import KEY_LIMIT, PACK_OFFSET, OccupancyMap, key_limit_m, pack_key_sets, pack_keys, unpack_keys
from prismap.grid._keys import BLOCK_BITS, pack_block, split_key
from support import FB, HitMissModel

L = KEY_LIMIT


@numba.njit(cache=False)
def _numba_pack(coords):
    out = np.empty(coords.shape[0], dtype=np.int64)
    for i in range(coords.shape[0]):
        out[i] = pack_block(coords[i, 0], coords[i, 1], coords[i, 2])
    return out


@numba.njit(cache=False)
def _numba_split(keys, bits):
    blocks = np.empty(keys.shape[0], dtype=np.int64)
    local = np.empty(keys.shape[0], dtype=np.int64)
    for i in range(keys.shape[0]):
        blocks[i], local[i] = split_key(np.int64(keys[i, 0]), np.int64(keys[i, 1]), np.int64(keys[i, 2]), bits)
    return blocks, local


def _edge_coords(rng, limit, n=2000):
    """Coordinates at the extremes, around 0 and random, in [-limit, limit)."""
    edges = np.array([-limit, -limit + 1, -1, 0, 1, limit - 2, limit - 1], dtype=np.int64)
    picks = rng.choice(edges, size=(n // 2, 3))
    return np.vstack([picks, rng.integers(-limit, limit, size=(n - n // 2, 3))])


def test_key_limit_follows_from_the_block_bits_and_the_packing():
    assert PACK_OFFSET == 2**20 and L == PACK_OFFSET << min(BLOCK_BITS[3]) == 2**22
    assert min(BLOCK_BITS[2][:2]) >= min(BLOCK_BITS[3])  # 2-D blocks are at least as wide on x, y
    assert key_limit_m(0.1) == pytest.approx(419430.4)


def test_numba_packing_equals_numpy_packing_and_unpacks():
    rng = np.random.default_rng(0)
    coords = _edge_coords(rng, PACK_OFFSET)
    packed = pack_keys(coords)
    np.testing.assert_array_equal(_numba_pack(coords), packed)
    np.testing.assert_array_equal(unpack_keys(packed), coords)
    # the packing keeps the lexicographic order of (x, y, z)
    np.testing.assert_array_equal(np.argsort(packed, kind="stable"), np.lexsort(coords.T[::-1]))
    with pytest.raises(PrismapInputError, match=r"\[-1048576, 1048576\) to pack; got \[0, 1048576\]"):
        pack_keys([[0, 0, PACK_OFFSET]])


@pytest.mark.parametrize("ndim", [3, 2])
def test_numba_split_equals_the_numpy_block_split(ndim):
    bits = BLOCK_BITS[ndim]
    rng = np.random.default_rng(1)
    keys = _edge_coords(rng, L)
    if ndim == 2:
        keys[:, 2] = 0
    blocks, local = _numba_split(keys, bits)
    shifts = np.array(bits)
    np.testing.assert_array_equal(blocks, pack_keys(keys >> shifts))
    offsets = keys & ((1 << shifts) - 1)
    np.testing.assert_array_equal(
        local, offsets[:, 0] | offsets[:, 1] << bits[0] | offsets[:, 2] << (bits[0] + bits[1])
    )


@pytest.mark.parametrize("order", ["sorted", "shuffled"])
def test_keys_round_trip_across_block_sign_and_limit_boundaries(order):
    """A brute-force dict against the map: every key reads back its own value, none aliases another, whether the
    keys of one block come in a row (sorted) or return to blocks seen before (shuffled)."""
    rng = np.random.default_rng(2)
    axis = np.unique(
        np.concatenate(
            [np.arange(-9, 9), np.arange(-L, -L + 6), np.arange(L - 6, L), [2**21 - 1, 2**21, -(2**21), -(2**21) - 1]]
        )
    )
    keys = rng.choice(axis, size=(5000, 3))
    keys = np.unique(keys, axis=0)
    if order == "shuffled":
        keys = rng.permutation(keys)
    values = rng.uniform(-5, 5, keys.shape[0])
    counts = rng.integers(1, 65536, keys.shape[0])
    grid = OccupancyMap(0.1, p0=0.5)
    grid.set_voxels(keys, values, counts)
    assert grid.n_known == keys.shape[0]
    log, count = grid.lookup_keys(keys)
    np.testing.assert_allclose(log, values, atol=2**-21)
    np.testing.assert_array_equal(count, counts)
    got_keys, got_log, _ = grid.known_voxels()
    reference = {tuple(k): v for k, v in zip(keys.tolist(), log)}
    assert {tuple(k): v for k, v in zip(got_keys.tolist(), got_log)} == reference


def test_keys_past_2_to_22_no_longer_alias():
    """Blocks packed in 21 bits aliased (0, 2**22, 0) onto (4, -2**22, 0); now it is refused, and the keys
    either side of the limit stay apart."""
    grid = OccupancyMap(0.1, p0=0.5)
    keys = np.array([[0, L - 1, 0], [4, -L, 0], [0, -L, 0], [L - 1, L - 1, L - 1], [-L, -L, -L]])
    grid.set_voxels(keys, [1.0, 2.0, 3.0, 4.0, 5.0], [1, 1, 1, 1, 1])
    np.testing.assert_array_equal(grid.lookup_keys(keys)[0], [1.0, 2.0, 3.0, 4.0, 5.0])
    message = r"must lie in the key range \[-4194304, 4194304\) \(\+-419430 m at 0.1 m voxels\)"
    for bad in ([0, L, 0], [0, -L - 1, 0], [L, 0, 0], [0, 0, -L - 1]):
        with pytest.raises(PrismapInputError, match=message):
            grid.set_voxels([bad], [1.0], [1])
        with pytest.raises(PrismapInputError, match=message):
            grid.lookup_keys([bad])
    assert grid.n_known == 5


def test_points_beyond_the_key_range_are_refused_with_the_limit_in_metres():
    grid = OccupancyMap(0.01, p0=0.5)  # +-41943 m
    assert grid.point_keys([[41943.0, 0, 0]]).tolist() == [[4194300, 0, 0]]
    for point in ([41943.05, 0, 0], [0, -41943.05, 0], [1e300, 0, 0]):
        with pytest.raises(PrismapInputError, match=r"key range .*\+-41943 m at 0.01 m voxels"):
            grid.probability([point])


def test_a_camera_beyond_the_key_range_is_refused_not_aliased():
    """A frame 5e5 m from the origin at 0.1 m voxels (keys ~5e6 > 2**22) must refuse, not write aliased keys."""
    grid = OccupancyMap(0.1, p0=0.5)
    with pytest.raises(PrismapInputError, match=r"`origin_w` .* outside the map's key range .*\+-419430 m at 0.1 m"):
        grid.integrate_rays([5e5, 0.0, 0.0], [[0.0, 0.0, 1.0]], [FB / 2.0], HitMissModel(FB), max_range_m=10.0)
    assert grid.n_known == 0 and grid.n_frames == 0


def test_map_cli_refuses_a_sequence_far_from_the_origin(tmp_path, capsys):
    from prismap.cli import main
    from support import synthetic_sequence

    seq = synthetic_sequence(tmp_path / "seq", n_frames=2, truth=False)
    poses = seq / "poses.txt"
    rows = np.loadtxt(poses).reshape(-1, 12)
    rows[:, 3] += 5e5  # x translation of each 3x4 camera-to-world pose
    np.savetxt(poses, rows)
    out = tmp_path / "map.npz"
    argv = [
        "map",
        "--sequence",
        str(seq),
        "--model",
        "hitmiss",
        "--voxel",
        "0.1",
        "--max-range",
        "8",
        "--disparity-dir",
        str(seq / "disp"),
        "--out",
        str(out),
    ]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "key range" in err and "419430 m at 0.1 m voxels" in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_pack_key_sets_gives_equal_codes_for_equal_keys_and_refuses_wide_spans():
    a = np.array([[5, -3], [-1000, 7]])
    b = np.array([[5, -3], [0, 0]])
    pa, pb = pack_key_sets(a, b)
    assert pa[0] == pb[0] and len(set(pa.tolist()) | set(pb.tolist())) == 3
    with pytest.raises(PrismapInputError, match="too far apart"):
        pack_key_sets(np.array([[0, 0, 0], [2**21, 0, 0]]))
