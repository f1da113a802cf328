"""Hostile input, round two (issue 25, item 1): Dask maps equal the sequential map bit for bit even where
the evidence drives voxels far beyond the old +-2048 saturation (conditioned PRISM saturates in one frame
here, and SGBM's outliers add evidence of the other sign), for ray and projective integration, 1-3 workers
and chunks of 1-7 frames."""

import numpy as np
import pytest
from test_pipeline_dask import assert_identical_maps

from prismap.pipeline import map_sequence
from support import conditioned_error_model, config, synthetic_sequence

distributed = pytest.importorskip("distributed")

CHUNKS_BY_WORKERS = {1: (1, 4), 2: (2, 5, 7), 3: (3, 6)}
"""Chunk sizes (frames per task) tried on each cluster size: every size 1-7 once."""


@pytest.fixture(scope="module")
def sequence_dir(tmp_path_factory):
    return synthetic_sequence(tmp_path_factory.mktemp("dask25") / "seq", n_frames=7, truth=False)


@pytest.mark.parametrize("mode", ["ray", "projective"])
def test_dask_conditioned_prism_is_bit_identical_whatever_the_chunking(sequence_dir, mode):
    cfg = config(
        model="prism",
        error_model=conditioned_error_model(feature="texture", edges=(20.0, 30.0)),
        mode=mode,
        disparity_source="matcher",
    )  # SGBM's outliers put occupied evidence where free evidence saturates
    assert cfg.conditioned
    sequential = map_sequence(sequence_dir, cfg, progress=False)
    log = sequential.known_voxels()[1]
    assert log.min() < -2048 and log.max() > 0  # evidence of both signs beyond the old +-2048 saturation
    for n_workers, chunks in CHUNKS_BY_WORKERS.items():
        with (
            distributed.LocalCluster(
                n_workers=n_workers, threads_per_worker=1, processes=False, dashboard_address=None
            ) as cluster,
            distributed.Client(cluster) as client,
        ):
            for chunk_frames in chunks:
                merged = map_sequence(sequence_dir, cfg, progress=False, client=client, chunk_frames=chunk_frames)
                assert_identical_maps(merged, sequential)
                assert np.array_equal(merged.occupied_voxels()[0], sequential.occupied_voxels()[0])
