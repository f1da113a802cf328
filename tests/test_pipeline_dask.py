"""Mapping and characterisation on local Dask clusters of 1-3 worker processes equal the sequential runs,
bit for bit (the grid's fixed-point log-odds make the merge order irrelevant)."""

import numpy as np
import pytest

from prismap.errors import PrismapInputError
from prismap.io import load_map, read_sequence
from prismap.pipeline import characterise_sequence, map_sequence
from prismap.pipeline._run import map_chunk, new_map
from support import conditioned_error_model, config, synthetic_sequence

distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def client():
    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
        distributed.Client(cluster) as dask_client,
    ):
        yield dask_client


def assert_identical_maps(a, b):
    """Every array of the two maps equal with np.array_equal (voxels in key order), and the same metadata."""
    keys_a, log_a, count_a = a.known_voxels()
    keys_b, log_b, count_b = b.known_voxels()
    order_a, order_b = np.lexsort(keys_a.T), np.lexsort(keys_b.T)
    for x, y in ((keys_a, keys_b), (log_a, log_b), (count_a, count_b)):
        assert x.dtype == y.dtype and np.array_equal(x[order_a], y[order_b])
    assert (a.n_frames, a.policies, a.p0, a.voxel_size_m) == (b.n_frames, b.policies, b.p0, b.voxel_size_m)


@pytest.fixture(scope="module")
def sequence_dir(tmp_path_factory):
    return synthetic_sequence(tmp_path_factory.mktemp("dask") / "seq", n_frames=7)


def test_dask_map_is_bit_identical_to_the_sequential_map_for_any_workers_and_chunks(sequence_dir, client):
    cfg = config(model="convolution")
    sequential = map_sequence(sequence_dir, cfg, progress=False)
    assert sequential.n_known > 1000
    for chunk_frames in (1, 3):  # 7 frames: chunks of 1, and 3+3+1, on 2 worker processes
        assert_identical_maps(
            map_sequence(sequence_dir, cfg, progress=False, client=client, chunk_frames=chunk_frames), sequential
        )
    for n_workers in (1, 3):  # thread workers: the merge order differs, the arithmetic is the same as processes'
        with (
            distributed.LocalCluster(
                n_workers=n_workers, threads_per_worker=1, processes=False, dashboard_address=None
            ) as cluster,
            distributed.Client(cluster) as other,
        ):
            assert_identical_maps(
                map_sequence(sequence_dir, cfg, progress=False, client=other, chunk_frames=2), sequential
            )


def test_dask_prism_map_is_bit_identical_to_the_sequential_map(sequence_dir, client):
    """PRISM's table caches differ between worker processes; the maps must not."""
    cfg = config(model="prism")
    assert_identical_maps(
        map_sequence(sequence_dir, cfg, progress=False, client=client, chunk_frames=3),
        map_sequence(sequence_dir, cfg, progress=False),
    )


def test_dask_conditioned_map_is_bit_identical_to_the_sequential_map(sequence_dir, client):
    """Workers compute each frame's features and classes themselves; the maps must not differ."""
    cfg = config(model="prism", error_model=conditioned_error_model(feature="texture", edges=(20.0, 30.0)))
    assert cfg.conditioned
    sequential = map_sequence(sequence_dir, cfg, progress=False)
    assert_identical_maps(map_sequence(sequence_dir, cfg, progress=False, client=client, chunk_frames=3), sequential)


def test_dask_map_with_matcher_and_checkpoints(sequence_dir, client, tmp_path):
    cfg = config(model="ideal", error_model=None, disparity_source="matcher", frames=(1, 7))
    checkpoint = tmp_path / "run.checkpoint.npz"
    parallel = map_sequence(sequence_dir, cfg, progress=False, client=client, checkpoint=checkpoint, checkpoint_every=2)
    assert load_map(checkpoint).n_frames == 4  # chunks of 2 frames: saved after 2 and 4, not after the last
    assert_identical_maps(parallel, map_sequence(sequence_dir, cfg, progress=False))
    resumed = map_sequence(sequence_dir, cfg, progress=False, client=client, checkpoint=checkpoint)
    assert_identical_maps(resumed, parallel)


def _assert_identical_histograms(a, b):
    np.testing.assert_array_equal(a.counts, b.counts)
    for name in ("n_below", "n_above", "n_gt_valid", "n_bad_1px", "n_bad_2px", "sum_abs_error_px", "n_frames"):
        assert getattr(a, name) == getattr(b, name), name


@pytest.mark.parametrize("conditioned", [False, True])
def test_dask_characterisation_is_bit_identical_to_the_sequential_one(sequence_dir, client, conditioned):
    """Plain and conditioned; the conditioned run samples 3 of the 7 frames and keeps 16000 of their pixels."""
    params = {"num_disparities": 16, "block_size": 5}
    options = {
        "matcher_params": params,
        "progress": False,
        "conditioned": conditioned,
        "max_components": 2,
        "max_samples": 16000,
        "search_frames": 3,
        "max_classes": 3,
    }
    sequential = characterise_sequence(sequence_dir, "sgbm", **options)
    assert sequential.histogram.n_frames == 7
    assert sequential.histogram.counts.sum() > 0.5 * sequential.histogram.n_gt_valid  # the matcher found most pixels
    if conditioned:
        record = sequential.model.class_selection
        assert (record["n_search_frames"], record["n_samples"]) == (3, 16000) and record["n_search_pixels"] > 16000
        assert sequential.model.conditioned and len(sequential.class_histograms) >= 2
    for chunk_frames in (2, 3):
        parallel = characterise_sequence(sequence_dir, "sgbm", client=client, chunk_frames=chunk_frames, **options)
        _assert_identical_histograms(parallel.histogram, sequential.histogram)
        assert len(parallel.class_histograms) == len(sequential.class_histograms)
        for a, b in zip(parallel.class_histograms, sequential.class_histograms):
            _assert_identical_histograms(a, b)
        assert parallel.model.to_dict() == sequential.model.to_dict()


def test_characterisation_errors_are_raised_before_any_task(sequence_dir, client):
    with pytest.raises(PrismapInputError, match="unknown matcher 'census'"):
        characterise_sequence(sequence_dir, "census", client=client)
    with pytest.raises(PrismapInputError, match="9 lies outside the 7 frames"):
        characterise_sequence(sequence_dir, "bm", frames=(9, None), client=client)


def test_map_cli_on_a_running_scheduler_writes_the_sequential_map(sequence_dir, client, tmp_path, capsys):
    from prismap.cli import main

    out = tmp_path / "map.npz"
    argv = [
        "map",
        "--sequence",
        str(sequence_dir),
        "--model",
        "ideal",
        "--voxel",
        "0.2",
        "--max-range",
        "8",
        "--disparity-dir",
        str(sequence_dir / "disp"),
        "--out",
        str(out),
    ]
    assert main([*argv, "--scheduler", client.scheduler.address, "--chunk-frames", "2"]) == 0
    assert "7 frames" in capsys.readouterr().out
    cfg = config(model="ideal", error_model=None)
    assert_identical_maps(load_map(out), map_sequence(sequence_dir, cfg, progress=False))
    assert main([*argv, "--scheduler", "bogus://nowhere:1"]) == 2
    assert "--scheduler bogus://nowhere:1: cannot connect" in capsys.readouterr().err


def test_dask_map_keeps_the_persistent_failure_reading(sequence_dir, client):
    """Chunk maps carry the config's fusion, so they merge, and the Dask map reads as the sequential one."""
    from dataclasses import replace

    from prismap.characterise import ErrorModel
    from prismap.gmm import MixtureFit
    from support import MIXTURE

    block = {"model": "persistent-failure", "rate": 0.05, "persistence": 0.6}
    error_model = ErrorModel(
        "sgbm", {}, "test", 1 / 32, (MixtureFit(MIXTURE, -1.0, 1.0, 1.0, 100.0, 3, True),), 2, fusion=block
    )
    cfg = replace(config(error_model=error_model), fusion="persistent-failure")
    sequential = map_sequence(sequence_dir, cfg, progress=False)
    chunked = map_sequence(sequence_dir, cfg, progress=False, client=client, chunk_frames=3)
    assert_identical_maps(chunked, sequential)
    assert chunked.fusion == sequential.fusion == error_model.persistent_failure
    keys = sequential.known_voxels()[0]
    np.testing.assert_array_equal(chunked.probability_at_keys(keys), sequential.probability_at_keys(keys))


def test_each_worker_builds_the_prism_tables_once_for_all_its_chunks(sequence_dir, client):
    """The model ``map_sequence`` scatters is one object on a worker: the tables a chunk builds serve the next, so a
    worker mapping frames one per chunk builds what one model mapping them all in one go builds."""
    cfg = config(model="prism")
    camera = read_sequence(sequence_dir).camera
    alone = cfg.sensor_model(camera)
    whole = map_chunk(str(sequence_dir), cfg, alone, 0, 7)
    assert alone._cache.hits > 0  # the frames share tables
    worker = sorted(client.scheduler_info()["workers"])[0]
    # One replica, on that worker: with one on each, Dask's active memory manager may drop this worker's between
    # tasks (ReduceReplicas) and the next task fetch a fresh copy, with an empty cache, from the other worker
    model = client.scatter(cfg.sensor_model(camera), workers=[worker], hash=False)
    merged = new_map(cfg)
    for frame in range(7):  # one after the other: the same order of table builds as the single model's
        merged.merge(
            client.submit(map_chunk, str(sequence_dir), cfg, model, frame, frame + 1, workers=[worker]).result()
        )
    builds = client.run(lambda dask_worker: dask_worker.data[model.key]._cache.builds, workers=[worker])
    assert builds == {worker: alone._cache.builds}
    assert_identical_maps(merged, whole)
