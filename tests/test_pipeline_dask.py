"""Mapping and characterisation on a local Dask cluster of 2 worker processes equal the sequential runs."""

import numpy as np
import pytest

from prismap.errors import PrismapInputError
from prismap.io import load_map
from prismap.pipeline import characterise_sequence, map_sequence
from support import assert_same_map, config, synthetic_sequence

distributed = pytest.importorskip("distributed")

MERGE_ATOL = 2e-5
"""Log-odds tolerance of chunked merges against one sequential sum (float32 rounding, a few 1e-6 per merge)."""


@pytest.fixture(scope="module")
def client():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as dask_client:
        yield dask_client


@pytest.fixture(scope="module")
def sequence_dir(tmp_path_factory):
    return synthetic_sequence(tmp_path_factory.mktemp("dask") / "seq", n_frames=7)


def test_dask_map_equals_the_sequential_map(sequence_dir, client):
    cfg = config(model="convolution")
    sequential = map_sequence(sequence_dir, cfg, progress=False)
    parallel = map_sequence(sequence_dir, cfg, progress=False, client=client, chunk_frames=3)
    assert parallel.n_frames == 7 and parallel.policies == sequential.policies
    assert_same_map(parallel, sequential, atol=MERGE_ATOL)


def test_dask_map_with_matcher_and_checkpoints(sequence_dir, client, tmp_path):
    cfg = config(model="ideal", error_model=None, disparity_source="matcher", frames=(1, 7))
    checkpoint = tmp_path / "run.checkpoint.npz"
    parallel = map_sequence(sequence_dir, cfg, progress=False, client=client, checkpoint=checkpoint,
                            checkpoint_every=2)
    assert load_map(checkpoint).n_frames == 4  # chunks of 2 frames: saved after 2 and 4, not after the last
    assert_same_map(parallel, map_sequence(sequence_dir, cfg, progress=False), atol=MERGE_ATOL)
    resumed = map_sequence(sequence_dir, cfg, progress=False, client=client, checkpoint=checkpoint)
    assert_same_map(resumed, parallel, atol=MERGE_ATOL)


def test_dask_characterisation_equals_the_sequential_histogram(sequence_dir, client):
    params = {"num_disparities": 16, "block_size": 5}
    sequential = characterise_sequence(sequence_dir, "sgbm", matcher_params=params, progress=False)
    parallel = characterise_sequence(sequence_dir, "sgbm", matcher_params=params, client=client, chunk_frames=2,
                                     progress=False)
    assert parallel.n_frames == sequential.n_frames == 7
    np.testing.assert_array_equal(parallel.counts, sequential.counts)
    for name in ("n_below", "n_above", "n_gt_valid", "n_bad_1px", "n_bad_2px"):
        assert getattr(parallel, name) == getattr(sequential, name)
    assert parallel.sum_abs_error_px == pytest.approx(sequential.sum_abs_error_px, rel=1e-12)
    assert sequential.counts.sum() > 0.5 * sequential.n_gt_valid  # the matcher found most pixels


def test_characterisation_errors_are_raised_before_any_task(sequence_dir, client):
    with pytest.raises(PrismapInputError, match="unknown matcher 'census'"):
        characterise_sequence(sequence_dir, "census", client=client)
    with pytest.raises(PrismapInputError, match="9 lies outside the 7 frames"):
        characterise_sequence(sequence_dir, "bm", frames=(9, None), client=client)


def test_map_cli_on_a_running_scheduler_writes_the_sequential_map(sequence_dir, client, tmp_path, capsys):
    from prismap.cli import main

    out = tmp_path / "map.npz"
    argv = ["map", "--sequence", str(sequence_dir), "--model", "ideal", "--voxel", "0.2", "--max-range", "8",
            "--disparity-dir", str(sequence_dir / "disp"), "--out", str(out)]
    assert main([*argv, "--scheduler", client.scheduler.address, "--chunk-frames", "2"]) == 0
    assert "7 frames" in capsys.readouterr().out
    cfg = config(model="ideal", error_model=None)
    assert_same_map(load_map(out), map_sequence(sequence_dir, cfg, progress=False), atol=MERGE_ATOL)
    assert main([*argv, "--scheduler", "bogus://nowhere:1"]) == 2
    assert "--scheduler bogus://nowhere:1: cannot connect" in capsys.readouterr().err
