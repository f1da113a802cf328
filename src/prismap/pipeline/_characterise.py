"""A matcher's error histogram over a dataset's frames, here or on Dask workers (histograms add up)."""

import math

from prismap._progress import progress as progress_bar
from prismap.characterise import ErrorHistogram
from prismap.characterise._histogram import DEFAULT_BIN_WIDTH, DEFAULT_LIMIT_PX
from prismap.errors import PrismapInputError
from prismap.io import GroundTruthFrames, open_ground_truth
from prismap.stereo import make_matcher


def histogram_chunk(frames, matcher_name, matcher_params, positions, bin_width, limit_px):
    """:class:`ErrorHistogram` of the frames at ``positions`` of ``frames`` (what a Dask worker runs).

    ``frames`` is a :class:`~prismap.io.GroundTruthFrames`; it pickles as paths and calibrations, and
    the worker reads its frames from disk one at a time.
    """
    matcher = make_matcher(matcher_name, **dict(matcher_params))
    histogram = ErrorHistogram.empty(bin_width=bin_width, limit_px=limit_px)
    for position in positions:
        frame = frames[position]
        histogram = histogram + ErrorHistogram.from_disparities(
            matcher.compute(frame.left, frame.right), frame.disparity_gt, bin_width=bin_width, limit_px=limit_px,
            name=frame.name,
        )
    return histogram


def characterise_sequence(dataset, matcher, *, matcher_params=None, frames=None, every=1, kitti_disparity="noc",
                          bin_width=DEFAULT_BIN_WIDTH, limit_px=DEFAULT_LIMIT_PX, client=None, chunk_frames=None,
                          progress=True):
    """Histogram a matcher's disparity errors over the frames of any dataset with ground truth.

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
    bin_width, limit_px : float, pixels
        See :class:`~prismap.characterise.ErrorHistogram`.
    client : distributed.Client or None
        Histogram chunks of frames on these Dask workers (each reads its own frames from disk) and add
        them up; None = here.
    chunk_frames : int or None
        Frames per Dask task; None = a quarter of the frames per worker.

    Returns
    -------
    ErrorHistogram
        Equal to the sequential histogram whatever the chunking (integer counts add exactly;
        ``sum_abs_error_px`` up to float rounding). Fit it with
        :func:`prismap.gmm.fit_mixtures` or pass it on to the characterisation tables.
    """
    if not isinstance(dataset, GroundTruthFrames):
        dataset = open_ground_truth(dataset, frames=frames, every=every, kitti_disparity=kitti_disparity)
    elif (frames, every, kitti_disparity) != (None, 1, "noc"):
        raise PrismapInputError("`frames`, `every` and `kitti_disparity` select from a dataset path; "
                                "GroundTruthFrames are already a selection")
    params = tuple(sorted((matcher_params or {}).items()))
    make_matcher(matcher, **dict(params))  # bad names or parameters fail here, not on a worker
    args = (matcher, params)
    positions = list(range(len(dataset)))
    enabled = None if progress else False
    total = ErrorHistogram.empty(bin_width=bin_width, limit_px=limit_px)
    if client is None:
        for position in progress_bar(positions, total=len(positions), desc=f"characterise {matcher}", unit="frame",
                                     enabled=enabled):
            total = total + histogram_chunk(dataset, *args, [position], bin_width, limit_px)
        return total
    n_workers = max(1, sum(client.nthreads().values()))
    size = int(chunk_frames) if chunk_frames else max(1, math.ceil(len(positions) / (4 * n_workers)))
    futures = [client.submit(histogram_chunk, dataset, *args, positions[i:i + size], bin_width, limit_px,
                             pure=False)
               for i in range(0, len(positions), size)]
    with progress_bar(total=len(positions), desc=f"characterise {matcher}", unit="frame", enabled=enabled) as bar:
        for future in futures:
            part = future.result()
            total = total + part
            bar.update(part.n_frames)
    return total
