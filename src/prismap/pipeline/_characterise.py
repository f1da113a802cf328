"""A matcher's error histogram over a whole sequence, here or on Dask workers (histograms add up)."""

import math

from prismap._progress import progress as progress_bar
from prismap.characterise import ErrorHistogram
from prismap.characterise._histogram import DEFAULT_BIN_WIDTH, DEFAULT_LIMIT_PX
from prismap.errors import PrismapInputError
from prismap.pipeline._run import open_sequence
from prismap.stereo import make_matcher


def histogram_chunk(sequence_path, matcher_name, matcher_params, indices, bin_width, limit_px):
    """:class:`ErrorHistogram` of the frames ``indices`` of a sequence (what a Dask worker runs)."""
    sequence = open_sequence(sequence_path)
    matcher = make_matcher(matcher_name, **dict(matcher_params))
    histogram = ErrorHistogram.empty(bin_width=bin_width, limit_px=limit_px)
    for index in indices:
        frame = sequence[index]
        if frame.disparity_gt is None:
            raise PrismapInputError(f"{sequence.path / 'disp' / sequence.names[index]}: ground-truth disparity missing")
        histogram = histogram + ErrorHistogram.from_disparities(
            matcher.compute(frame.left, frame.right), frame.disparity_gt, bin_width=bin_width, limit_px=limit_px,
            name=frame.name,
        )
    return histogram


def characterise_sequence(sequence, matcher, *, matcher_params=None, frames=(0, None), bin_width=DEFAULT_BIN_WIDTH,
                          limit_px=DEFAULT_LIMIT_PX, client=None, chunk_frames=None, progress=True):
    """Histogram a matcher's disparity errors over a sequence with ground truth (``disp/``).

    Parameters
    ----------
    sequence : str or Path or Sequence
    matcher : str
        Matcher name (:func:`prismap.stereo.make_matcher`), built with ``matcher_params`` (dict).
    frames : (int, int or None)
        ``(start, stop)`` frame range, stop None = to the end.
    bin_width, limit_px : float, pixels
        See :class:`~prismap.characterise.ErrorHistogram`.
    client : distributed.Client or None
        Histogram chunks of frames on these Dask workers (each opens the sequence by path) and add
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
    sequence = open_sequence(sequence)
    start, stop = frames
    stop = len(sequence) if stop is None else min(int(stop), len(sequence))
    indices = list(range(int(start), stop))
    if not indices:
        raise PrismapInputError(f"frames {start}:{stop} select no frame of a sequence of {len(sequence)} frames")
    params = tuple(sorted((matcher_params or {}).items()))
    make_matcher(matcher, **dict(params))  # bad names or parameters fail here, not on a worker
    args = (matcher, params)
    enabled = None if progress else False
    if client is None:
        total = ErrorHistogram.empty(bin_width=bin_width, limit_px=limit_px)
        for index in progress_bar(indices, total=len(indices), desc=f"characterise {matcher}", unit="frame", enabled=enabled):
            total = total + histogram_chunk(sequence, *args, [index], bin_width, limit_px)
        return total
    n_workers = max(1, sum(client.nthreads().values()))
    size = int(chunk_frames) if chunk_frames else max(1, math.ceil(len(indices) / (4 * n_workers)))
    path = str(sequence.path.resolve())
    futures = [client.submit(histogram_chunk, path, *args, indices[i:i + size], bin_width, limit_px, pure=False)
               for i in range(0, len(indices), size)]
    total = ErrorHistogram.empty(bin_width=bin_width, limit_px=limit_px)
    with progress_bar(total=len(indices), desc=f"characterise {matcher}", unit="frame", enabled=enabled) as bar:
        for future in futures:
            part = future.result()
            total = total + part
            bar.update(part.n_frames)
    return total
