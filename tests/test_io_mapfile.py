"""The .npz map file and the PLY export: round trips, and clear errors for bad files with nothing overwritten."""

import io
import zipfile
import zlib

import numpy as np
import pytest

from prismap._files import NPZ_LEVEL, save_npz
from prismap.errors import PrismapInputError
from prismap.grid import OCTOMAP_CLAMP, OccupancyMap
from prismap.io import _mapfile
from prismap.io._mapfile import load_map, save_map
from prismap.io._ply import read_ply, write_ply
from support import FB, HitMissModel


def small_map(**options):
    grid = OccupancyMap(0.1, p0=0.5, **options)
    rng = np.random.default_rng(3)
    rays = np.column_stack([rng.uniform(-0.5, 0.5, (200, 2)), np.ones(200)])
    grid.integrate_rays([0.05, -0.02, 0.0], rays, FB / rng.uniform(0.5, 2.0, 200), HitMissModel(FB))
    return grid


@pytest.mark.parametrize("options", [{}, {"clamp": OCTOMAP_CLAMP, "occupied_threshold": 0.6, "free_threshold": 0.4}])
def test_map_file_round_trip(tmp_path, options):
    grid = small_map(**options)
    save_map(grid, tmp_path / "m.npz")
    back = load_map(tmp_path / "m.npz")
    for attr in ("voxel_size_m", "p0", "ndim", "clamp", "occupied_threshold", "free_threshold", "policies", "n_frames"):
        assert getattr(back, attr) == getattr(grid, attr), attr
    for a, b in zip(grid.known_voxels(), back.known_voxels()):
        order_a, order_b = np.lexsort(grid.known_voxels()[0].T), np.lexsort(back.known_voxels()[0].T)
        np.testing.assert_array_equal(a[order_a], b[order_b])


def test_map_file_is_a_deflated_npz_that_numpy_reads(tmp_path):
    """Every member deflated at NPZ_LEVEL, and ``np.load`` gives back each array's exact dtype and values."""
    grid = small_map()
    save_map(grid, tmp_path / "m.npz")
    with zipfile.ZipFile(tmp_path / "m.npz") as archive:
        infos = archive.infolist()
    assert infos and all(info.compress_type == zipfile.ZIP_DEFLATED for info in infos)
    keys = next(info for info in infos if info.filename == "keys.npy")
    assert keys.compress_size < keys.file_size  # integer keys of a small block compress
    with np.load(tmp_path / "m.npz") as loaded:
        stored = grid.known_voxels()
        for name, expected in zip(("keys", "log_odds", "counts"), stored):
            assert loaded[name].dtype == expected.dtype
            np.testing.assert_array_equal(loaded[name], expected)
        assert loaded["fusion_model"].item() == "independent"


def test_npz_writer_deflates_at_its_level(tmp_path):
    """The archive holds the array's .npy serialisation, deflated exactly as zlib at NPZ_LEVEL does it."""
    values = np.arange(20_000, dtype=np.int64) % 97
    save_npz(tmp_path / "a.npz", values=values)
    with zipfile.ZipFile(tmp_path / "a.npz") as archive:
        raw = archive.read("values.npy")
        size = archive.getinfo("values.npy").compress_size
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, values, allow_pickle=False)
    assert raw == buffer.getvalue()
    deflate = zlib.compressobj(NPZ_LEVEL, zlib.DEFLATED, -15)
    assert size == len(deflate.compress(raw) + deflate.flush())


def test_two_dimensional_map_round_trip(tmp_path):
    grid = OccupancyMap(0.05, p0=0.1, ndim=2)
    grid.integrate_rays([0.0, 0.0], [[1.0, 0.3], [1.0, -0.2]], [FB / 1.0, FB / 0.5], HitMissModel(FB, p0=0.1))
    save_map(grid, tmp_path / "m2.npz")
    back = load_map(tmp_path / "m2.npz")
    keys = back.known_voxels()[0]
    assert back.ndim == 2 and np.all(keys[:, 2] == 0)
    np.testing.assert_array_equal(back.state_at_keys(keys), grid.state_at_keys(keys))


def write_fields(path, **changes):
    grid = small_map()
    save_map(grid, path)
    with np.load(path) as data:
        fields = dict(data)
    for key, value in changes.items():
        if value is None:
            del fields[key]
        else:
            fields[key] = value
    np.savez(path, **fields)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda p: p.write_bytes(b"not a zip file at all"), "not a readable .npz"),
        (lambda p: (save_map(small_map(), p), p.write_bytes(p.read_bytes()[:200])), "truncated or corrupt"),
        (lambda p: write_fields(p, format_version=np.array(5)), "version 5 is not supported"),
        (lambda p: write_fields(p, counts=None), r"lacks field\(s\) \['counts'\]"),
        (lambda p: write_fields(p, format=np.array("something-else")), "not a prismap map file"),
        (lambda p: np.save(open(p, "wb"), np.zeros(3)), "not a readable .npz"),
        (lambda p: write_fields(p, keys=np.zeros((3, 2), np.int32)), r"`keys` must be an \(N, 3\) integer array"),
    ],
)
def test_bad_map_files_give_clear_errors(tmp_path, make, message):
    path = tmp_path / "bad.npz"
    make(path)
    with pytest.raises(PrismapInputError, match=message) as info:
        load_map(path)
    assert "bad.npz" in str(info.value)


def test_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(PrismapInputError, match="no such map file"):
        load_map(tmp_path / "absent.npz")


def test_failed_write_leaves_the_old_file(tmp_path, monkeypatch):
    path = tmp_path / "m.npz"
    save_map(small_map(), path)
    before = path.read_bytes()

    def broken(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(_mapfile, "save_npz", broken)
    with pytest.raises(PrismapInputError, match=r"m.npz: cannot write \(disk full\)"):
        save_map(small_map(), path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["m.npz"]


def test_merging_maps_of_another_voxel_size_is_an_error(tmp_path):
    save_map(OccupancyMap(0.2, p0=0.5), tmp_path / "coarse.npz")
    with pytest.raises(PrismapInputError, match="voxel_size_m 0.1 != 0.2"):
        small_map().merge(load_map(tmp_path / "coarse.npz"))


def test_ply_holds_the_occupied_voxels(tmp_path):
    grid = small_map()
    n = write_ply(grid, tmp_path / "occ.ply")
    centers, prob = read_ply(tmp_path / "occ.ply")
    _, want_centers, want_prob = grid.occupied_voxels()
    assert n == len(want_prob) > 0
    np.testing.assert_allclose(centers, want_centers, rtol=1e-6)
    np.testing.assert_allclose(prob, want_prob, rtol=1e-6)
    assert (tmp_path / "occ.ply").read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
