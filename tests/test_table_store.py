"""PRISM's table store on disk: tables read back equal the ones built byte for byte, maps do not depend on the store,
and foreign, damaged or mismatched entries are built again instead of read."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from prismap.camera import StereoCamera, integrate_disparity
from prismap.gmm import GaussianMixture
from prismap.grid import OccupancyMap
from prismap.sensor_models import (
    ConditionedModel,
    _kernels_pack,
    _table_store,
    conditioned_sensor_model,
    make_sensor_model,
    store_directory,
)
from prismap.sensor_models._table_store import TableStore, model_fingerprint
from support import assert_same_map, conditioned_error_model, planes_frame

STREET = GaussianMixture([0.9, 0.1], [0.02, 0.1], [0.25, 1.5], failure_weight=0.08, search_range_px=(0.0, 64.0))
KEYS = np.array([16 * d * (1 << 16) + r for d in (3, 7, 20, 41) for r in (0, 2)], dtype=np.int64)


def prism(mixture=STREET, **params):
    settings = {"focal_baseline": 525.0 * 0.1, "doffs_px": 0.0, "voxel_size_m": 0.1, "p0": 0.05} | params
    return make_sensor_model("prism", error_model=mixture, **settings)


@pytest.fixture
def store_dir(tmp_path, monkeypatch):
    """A fresh store directory for this test, and no store object left from another test in this process."""
    monkeypatch.setenv(_table_store.STORE_ENV, str(tmp_path / "tables"))
    monkeypatch.setattr(_table_store, "_STORES", {})
    return tmp_path / "tables"


def counted_builds(monkeypatch):
    """Count the tables ``prism_tables`` builds (``calls[0]``)."""
    calls = [0]
    real = _kernels_pack.prism_tables

    def counting(shifts, *args):
        calls[0] += shifts.size
        return real(shifts, *args)

    monkeypatch.setattr(_kernels_pack, "prism_tables", counting)
    return calls


def packed(nodes):
    return np.concatenate(nodes) if isinstance(nodes, list) else nodes


def tables_by_key(nodes, meta):
    """Each table's packed rows and meta row (offset zeroed), in the order of the keys."""
    nodes = packed(nodes)
    rows = []
    for row in meta:
        start, stored = int(row[_kernels_pack._OFFSET]), int(row[_kernels_pack._STORED])
        rows.append((nodes[start : start + stored].tobytes(), np.delete(row, _kernels_pack._OFFSET).tobytes()))
    return rows


def fresh_store():
    """The store a new process would open (nothing held from this one's)."""
    _table_store._STORES.clear()
    return _table_store.table_store()


def test_the_store_directory_follows_the_environment(monkeypatch, tmp_path):
    for off in ("off", "0", "", " OFF "):
        monkeypatch.setenv("PRISMAP_TABLE_CACHE", off)
        assert store_directory() is None and _table_store.table_store() is None
    monkeypatch.setenv("PRISMAP_TABLE_CACHE", str(tmp_path / "here"))
    assert store_directory() == tmp_path / "here"
    monkeypatch.delenv("PRISMAP_TABLE_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert store_directory() == tmp_path / "xdg" / "prismap" / "tables"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert store_directory() == Path.home() / ".cache" / "prismap" / "tables"


def test_tables_read_back_equal_the_built_ones_byte_for_byte(store_dir, monkeypatch):
    model = prism()
    built = tables_by_key(*model._new_tables(*inputs(model, KEYS)))
    first = model._build_tables(KEYS)  # an empty store: built, held, then written
    assert tables_by_key(*first) == built
    _table_store.flush_table_stores()
    assert len(list(store_dir.glob("seg-*.bin"))) == 1 and not list(store_dir.glob(".*"))
    assert _table_store.table_store().written == KEYS.size
    store = fresh_store()
    builds = counted_builds(monkeypatch)
    again = model._build_tables(KEYS[::-1])  # another order, read
    assert builds[0] == 0 and store.found == KEYS.size
    assert tables_by_key(*again) == built[::-1]
    mixed = np.concatenate([KEYS[:3], KEYS[:3] + 16 * (1 << 16)])  # three stored, three new
    tables = model._build_tables(mixed)
    assert builds[0] == 3
    assert tables_by_key(*tables) == tables_by_key(*model._new_tables(*inputs(model, mixed)))


def inputs(model, keys):
    """``(shift, lam, log_far)`` of untagged ``keys``, as :meth:`PrismModel._build_tables` computes them."""
    from prismap.sensor_models._prism_cache import _KEY_L_SPAN, _LAMBDA_STEP

    key_d, key_l = np.divmod(keys, _KEY_L_SPAN)
    disparity = key_d * model.disparity_step_px
    lam = model.rate_per_m * np.exp(_kernels_pack.rate_key_centre(key_l, _LAMBDA_STEP))
    return disparity + model.doffs_px, lam, model._log_far(disparity)


def test_a_map_is_the_same_without_the_store_with_an_empty_one_and_a_full_one(store_dir, monkeypatch):
    camera, pose, depth = planes_frame(160, 120)
    disparity = camera.focal_baseline / depth
    model_args = {"focal_baseline": camera.focal_baseline, "doffs_px": camera.doffs_px, "voxel_size_m": 0.1}

    def mapped(error_model=STREET):
        grid = OccupancyMap(0.1, p0=0.05)
        model = prism(error_model, **model_args)
        for mode in ("ray", "projective"):
            integrate_disparity(grid, disparity, camera, pose, model, mode=mode, max_range_m=12.0)
        _table_store.flush_table_stores()
        return grid

    monkeypatch.setenv("PRISMAP_TABLE_CACHE", "off")
    without = mapped()
    monkeypatch.setenv("PRISMAP_TABLE_CACHE", str(store_dir))
    builds = counted_builds(monkeypatch)
    assert_same_map(mapped(), without)  # an empty store: every table built and written
    assert builds[0] > 0
    fresh_store()
    builds[0] = 0
    assert_same_map(mapped(), without)  # a full one: every table read
    assert builds[0] == 0
    other = GaussianMixture([0.8, 0.2], [0.0, 0.3], [0.3, 2.0])
    mapped(other)  # another mixture: another fingerprint, built again
    assert builds[0] > 0


def test_a_conditioned_model_stores_each_class_under_its_own_fingerprint(store_dir, monkeypatch):
    camera = StereoCamera(100.0, 59.5, 39.5, 0.12, width=120, height=80)

    def conditioned():
        return conditioned_sensor_model(
            "prism", camera, voxel_size_m=0.1, p0=0.05, error_model=conditioned_error_model()
        )

    model = conditioned()
    assert isinstance(model, ConditionedModel)
    fingerprints = {m._store_fingerprint for m in (model.plain, *model.class_models)}
    assert len(fingerprints) == 1 + len(model.class_models)
    rng = np.random.default_rng(0)
    disparity = rng.uniform(2.0, 30.0, 500)
    ray_class = rng.integers(-1, len(model.class_models), 500)
    norm = np.ones(500)
    depth = model.influence_depth(disparity, norm, ray_class=ray_class)
    _table_store.flush_table_stores()
    fresh_store()
    builds = counted_builds(monkeypatch)
    np.testing.assert_array_equal(conditioned().influence_depth(disparity, norm, ray_class=ray_class), depth)
    assert builds[0] == 0


def test_fingerprints_change_with_every_table_input_and_the_kernels_sources(monkeypatch):
    model = prism()
    geometry, spec, mixture = model._geometry(), model._table_spec, model._mixture()
    key_inputs, errors = (1.0, 0.0, 1 / 16, 0.1, 80.0), STREET.to_dict()
    base = model_fingerprint(geometry, spec, mixture, key_inputs, errors)
    assert model_fingerprint(geometry, spec, mixture, key_inputs, errors) == base
    assert model_fingerprint(geometry._replace(z_max=geometry.z_max + 1.0), spec, mixture, key_inputs, errors) != base
    assert model_fingerprint(geometry, spec._replace(h=spec.h * 2), mixture, key_inputs, errors) != base
    assert model_fingerprint(geometry, spec, mixture._replace(sigmas=mixture.sigmas * 1.01), key_inputs, errors) != base
    assert model_fingerprint(geometry, spec, mixture, (1.0, 0.5, 1 / 16, 0.1, 80.0), errors) != base
    assert (
        model_fingerprint(geometry, spec, mixture, key_inputs, STREET.with_failure(0.1, (0.0, 64.0)).to_dict()) != base
    )
    assert prism()._store_fingerprint == model._store_fingerprint
    assert len({prism(p0=p0)._store_fingerprint for p0 in (0.05, 0.2)}) == 2  # another rate per metre
    assert prism(doffs_px=1.5)._store_fingerprint != model._store_fingerprint
    monkeypatch.setattr(_table_store, "_SOURCE_DIGEST", b"another kernel")
    assert model_fingerprint(geometry, spec, mixture, key_inputs, errors) != base


def test_a_table_whose_rate_or_shift_differs_is_built_again(store_dir, monkeypatch):
    first = prism()
    first._build_tables(KEYS)
    _table_store.flush_table_stores()
    shifted = prism(doffs_px=1.5)  # other shifts for the same keys, filed under the first model's fingerprint
    object.__setattr__(shifted, "_store_fingerprint", first._store_fingerprint)  # as a hash collision would
    fresh_store()
    builds = counted_builds(monkeypatch)
    tables = shifted._build_tables(KEYS)
    assert builds[0] == KEYS.size
    assert tables_by_key(*tables) == tables_by_key(*shifted._new_tables(*inputs(shifted, KEYS)))


def test_damaged_and_foreign_segments_are_ignored(store_dir, monkeypatch):
    model = prism()
    model._build_tables(KEYS)
    _table_store.flush_table_stores()
    (segment,) = store_dir.glob("seg-*.bin")
    data = segment.read_bytes()
    (store_dir / "seg-truncated.bin").write_bytes(data[: len(data) // 2])
    (store_dir / "seg-foreign.bin").write_bytes(b"not a table segment at all" * 10)
    (store_dir / "seg-empty.bin").write_bytes(b"")
    (store_dir / ".seg-half-written.bin.tmp").write_bytes(data[:100])
    segment.unlink()
    fresh_store()
    builds = counted_builds(monkeypatch)
    tables = model._build_tables(KEYS)
    assert builds[0] == KEYS.size  # nothing readable: all built
    assert tables_by_key(*tables) == tables_by_key(*model._new_tables(*inputs(model, KEYS)))


def test_processes_writing_at_once_keep_every_segment(store_dir):
    script = (
        "import sys, numpy as np; sys.path.insert(0, {tests!r}); from test_table_store import prism, KEYS;"
        "from prismap.sensor_models import flush_table_stores;"
        "prism(p0={p0})._build_tables(KEYS); flush_table_stores()"
    )
    env = {**os.environ, "PRISMAP_TABLE_CACHE": str(store_dir)}
    tests = str(Path(__file__).parent)
    runs = [subprocess.Popen([sys.executable, "-c", script.format(tests=tests, p0=p0)], env=env) for p0 in (0.05, 0.2)]
    assert [run.wait(timeout=300) for run in runs] == [0, 0]
    assert len(list(store_dir.glob("seg-*.bin"))) == 2
    store = fresh_store()
    for p0 in (0.05, 0.2):
        model = prism(p0=p0)
        shift, lam, _ = inputs(model, KEYS)
        found, _, _ = store.fetch(model._store_fingerprint, KEYS, lam, shift)
        assert found.all()


def test_a_full_store_writes_no_more(store_dir, monkeypatch):
    monkeypatch.setattr(_table_store, "STORE_BUDGET_BYTES", 1000)
    prism()._build_tables(KEYS)
    _table_store.flush_table_stores()
    assert not store_dir.exists() or not list(store_dir.glob("seg-*.bin"))


def test_held_tables_are_written_once_they_reach_the_flush_size(store_dir, monkeypatch):
    monkeypatch.setattr(_table_store, "FLUSH_BYTES", 1)
    store = TableStore(store_dir)
    model = prism()
    nodes, meta = model._new_tables(*inputs(model, KEYS))
    store.add(model._store_fingerprint, KEYS, nodes, meta)
    assert len(list(store_dir.glob("seg-*.bin"))) == 1


def test_tables_a_full_cache_drops_are_written_first_and_read_back(store_dir, monkeypatch):
    model = prism(table_memory_mb=0.001)  # a budget below one table: each call drops the one before's
    first, second = KEYS[:4], KEYS[4:]

    def ask(keys):
        return model._tables_for(keys // (1 << 16) / 16.0, np.exp((keys % (1 << 16) + 0.5) * 0.1))

    ask(first)
    builds = counted_builds(monkeypatch)
    ask(second)
    assert builds[0] == second.size and len(model._cache) == second.size  # the first call's tables dropped
    assert _table_store.table_store().written == KEYS.size  # written to disk before the eviction, both calls' tables
    ask(first)
    assert builds[0] == second.size  # read back, not built


def test_a_store_that_cannot_be_written_maps_all_the_same(tmp_path, monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    monkeypatch.setenv("PRISMAP_TABLE_CACHE", str(blocker / "tables"))  # under a file: mkdir fails
    monkeypatch.setattr(_table_store, "_STORES", {})
    monkeypatch.setattr(_table_store, "FLUSH_BYTES", 1)  # every build tries to write
    model = prism()
    tables = model._build_tables(KEYS)
    assert tables_by_key(*tables) == tables_by_key(*model._new_tables(*inputs(model, KEYS)))
    store = _table_store.table_store()
    assert store.written == 0 and not list(tmp_path.glob("**/seg-*"))
    model._build_tables(KEYS + 16 * (1 << 16))  # and it stops trying
    assert store._pending == []
    monkeypatch.setenv("PRISMAP_TABLE_CACHE", str(blocker))  # the file itself
    assert tables_by_key(*prism()._build_tables(KEYS)) == tables_by_key(*tables)
    assert blocker.read_text() == "not a directory"
