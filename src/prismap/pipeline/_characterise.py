"""A matcher's error model over a dataset's frames, here or on Dask workers (histograms and samples add up)."""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Mapping
from typing import Any

from prismap.characterise import Characterisation, characterise_matcher
from prismap.errors import PrismapInputError
from prismap.io import GroundTruthFrames, open_ground_truth
from prismap.stereo import make_matcher


def _dask_map(client, function, chunks):
    """``function(chunk)`` of each chunk on the client's workers, yielded in chunk order."""
    futures = [client.submit(function, chunk, pure=False) for chunk in chunks]
    for future in futures:
        yield future.result()


def characterise_sequence(
    dataset: str | os.PathLike[str] | GroundTruthFrames,
    matcher: str,
    *,
    matcher_params: Mapping[str, Any] | None = None,
    frames: str | tuple[int | None, int | None] | None = None,
    every: int = 1,
    kitti_disparity: str = "noc",
    client: Any = None,
    chunk_frames: int | None = None,
    progress: bool = True,
    **options: Any,
) -> Characterisation:
    """Characterise a matcher's disparity errors over the frames of any dataset with ground truth.

    Parameters
    ----------
    dataset : str or Path or GroundTruthFrames
        Anything :func:`prismap.io.open_ground_truth` opens (a sequence with ``disp/``, KITTI stereo or
        odometry, Middlebury, New Tsukuba, ``"middlebury-motorcycle"``), or frames it opened (then
        ``frames``, ``every`` and ``kitti_disparity`` must stay at their defaults).
    matcher : str
        Matcher name (:func:`prismap.stereo.make_matcher`), built with ``matcher_params`` (dict).
    frames, every, kitti_disparity
        Frame selection and KITTI ground truth, see :func:`prismap.io.open_ground_truth`.
    client : distributed.Client or None
        Run chunks of frames on these Dask workers (each reads its own frames from disk) and merge
        them; None = here.
    chunk_frames : int or None
        Frames per Dask task; None = a quarter of the frames per worker.
    progress : bool
        Show frames and steps on stderr.
    **options
        Keyword options of :func:`prismap.characterise.characterise_matcher` (``conditioned``,
        ``bin_width``, ``max_classes``, ``max_samples``, ``search_frames``, ``seed``, ...); ``dataset``
        defaults to the dataset as given.

    Returns
    -------
    Characterisation
        The same whatever the workers and the chunking: its histograms' counts and sums add exactly
        and the class-search sample merges exactly (see :class:`prismap.characterise.PixelSample`).
    """
    if not isinstance(dataset, GroundTruthFrames):
        dataset = open_ground_truth(dataset, frames=frames, every=every, kitti_disparity=kitti_disparity)
    elif (frames, every, kitti_disparity) != (None, 1, "noc"):
        raise PrismapInputError(
            "`frames`, `every` and `kitti_disparity` select from a dataset path; "
            "GroundTruthFrames are already a selection"
        )
    stereo = make_matcher(matcher, **dict(matcher_params or {}))  # bad names or parameters fail here, not on a worker
    options.setdefault("dataset", str(dataset.source))
    if client is None:
        return characterise_matcher(dataset, stereo, progress=progress, **options)
    n_workers = max(1, sum(client.nthreads().values()))
    size = int(chunk_frames) if chunk_frames else max(1, math.ceil(len(dataset) / (4 * n_workers)))
    return characterise_matcher(
        dataset,
        stereo,
        progress=progress,
        map_chunks=functools.partial(_dask_map, client),
        chunk_frames=size,
        **options,
    )
