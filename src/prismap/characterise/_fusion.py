"""The error model's fusion block: how a matcher's failures repeat across views, fitted and stored.

Fitted from the characterisation frames (never from scored maps): consecutive frames of a drive are paired at
the same surface points (:func:`~prismap.characterise.frame_error_correlation`), the share of gross errors is
the failure state's rate ``r`` and the share of gross errors after a gross error its persistence ``q``
(:class:`prismap.grid.PersistentFailure`). JSON form, the ``"fusion"`` field of an error model::

    {"model": "persistent-failure", "rate": r, "persistence": q, "gross_px": 3.0, "n_pairs": N}

``{"model": "independent"}`` (or no field) is today's independent sum.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from prismap.camera import StereoCamera
from prismap.characterise._correlation import frame_error_correlation
from prismap.errors import PrismapInputError
from prismap.grid import MAP_READINGS, READINGS, MapReading, PersistentFailure
from prismap.io._frame import StereoFrame

FUSION_MODELS = ("independent", "persistent-failure")
"""The fusion block's ``model`` values."""

FUSION_GROSS_PX = 3.0
"""An error beyond this many pixels counts as a failed view: beyond the Gaussians of every characterised matcher
(their widest sigma is 1-4 px), so a failure is what the per-frame mixture does not explain."""

MIN_PAIRS = 100
"""Fewest paired surface points a fit accepts: fewer cannot estimate a rate of a few per cent."""


def fit_fusion(
    frames: Sequence[StereoFrame],
    disparities: Sequence[npt.ArrayLike],
    camera: StereoCamera,
    *,
    gross_px: float = FUSION_GROSS_PX,
) -> dict[str, Any]:
    """The persistent-failure block of a matcher from characterisation frames with truth and poses.

    Parameters
    ----------
    frames : sequence of StereoFrame
        Each with ``disparity_gt`` and ``T_world_cam``; paired in the order of the camera's path (a greedy chain
        of nearest positions from the first frame), so frames of a drive and frames from the positions between
        its own may come in any order.
    disparities : sequence of (H, W) float, pixels, NaN = invalid
        The matcher's disparity of each frame.
    camera : StereoCamera
    gross_px : float, pixels
        Errors beyond it are failed views.

    Returns
    -------
    dict
        The fusion block (module docstring); ``persistence`` is at least ``rate`` (a failure never makes the
        next one rarer than its base rate) and is the rate itself when no gross error had a successor.
    """
    frames, disparities = list(frames), list(disparities)
    if len(disparities) != len(frames) or len(frames) < 2:
        raise PrismapInputError(
            f"fusion fit: needs at least 2 frames and one disparity image per frame; got "
            f"{len(frames)} frames and {len(disparities)} disparity images"
        )
    for index, frame in enumerate(frames):
        if frame.T_world_cam is None:
            raise PrismapInputError(f"fusion fit: frame {index} ({frame.name or 'unnamed'}) has no pose `T_world_cam`")
    order = path_order(np.array([frame.T_world_cam[:3, 3] for frame in frames]))
    correlation = frame_error_correlation(
        [frames[i] for i in order],
        [disparities[i] for i in order],
        camera,
        lag=1,
        gross_px=gross_px,
        limit_px=max(gross_px, 3.0),
    )
    if correlation.n_pairs < MIN_PAIRS:
        raise PrismapInputError(
            f"fusion fit: {correlation.n_pairs} surface points seen in consecutive frames; "
            f"need at least {MIN_PAIRS} (more or closer characterisation frames)"
        )
    rate = correlation.gross_rate
    repeat = correlation.gross_repeat
    persistence = rate if math.isnan(repeat) else max(repeat, rate)
    return {
        "model": "persistent-failure",
        "rate": rate,
        "persistence": persistence,
        "gross_px": float(gross_px),
        "n_pairs": correlation.n_pairs,
    }


def path_order(positions):
    """Indices of ``positions`` ((N, 3), metres) along a greedy chain of nearest positions from the first."""
    order, left = [0], set(range(1, len(positions)))
    while left:
        here = positions[order[-1]]
        nearest = min(left, key=lambda i: float(np.sum((positions[i] - here) ** 2)))
        order.append(nearest)
        left.remove(nearest)
    return order


def fusion_from_block(block: dict[str, Any] | None, *, source: str = "error model") -> PersistentFailure | None:
    """The :class:`~prismap.grid.PersistentFailure` of a fusion block, or None for independent fusion.

    Raises
    ------
    PrismapInputError
        An unknown ``model``, a missing or invalid rate or persistence; the message starts with ``source``.
    """
    if block is None:
        return None
    if not isinstance(block, dict) or block.get("model") not in FUSION_MODELS:
        raise PrismapInputError(
            f"{source}: field 'fusion' must be an object with 'model' one of {list(FUSION_MODELS)}; got {block!r:.80}"
        )
    if block["model"] == "independent":
        return None
    try:
        return PersistentFailure(block["rate"], block["persistence"])
    except KeyError as exc:
        raise PrismapInputError(f"{source}: field 'fusion' lacks {exc}") from None
    except PrismapInputError as exc:
        raise PrismapInputError(f"{source}: field 'fusion': {exc}") from None


def fusion_block(fusion: PersistentFailure | None, **fit: Any) -> dict[str, Any]:
    """The JSON block of ``fusion`` (a :class:`~prismap.grid.PersistentFailure` or None); ``fit`` adds what
    the fit recorded (``gross_px``, ``n_pairs``)."""
    if fusion is None:
        return {"model": "independent"}
    return {"model": "persistent-failure", **fusion.to_dict(), **fit}


def map_reading(block: dict[str, Any] | None, reading: str) -> MapReading | None:
    """The map reading named ``reading`` (one of :data:`MAP_READINGS`) of a fusion block; None = independent.

    ``"persistent-failure"`` is the block's :class:`~prismap.grid.PersistentFailure`; ``"failure-mixture"`` and
    ``"failure-clamp"`` hold the independent sum within its one-view bound (:class:`~prismap.grid.FailureMixture`,
    :class:`~prismap.grid.FailureClamp` of its rate). A block that says "independent", or none, reads every way
    as the independent sum.
    """
    if reading not in MAP_READINGS:
        raise PrismapInputError(f"`fusion` must be one of {list(MAP_READINGS)}; got {reading!r}")
    failure = fusion_from_block(block)
    if failure is None or reading == "independent":
        return None
    return failure if reading == failure.name else READINGS[reading](failure.rate)
