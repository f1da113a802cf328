"""Self-characterisation: a matcher's error model from a posed stereo sequence alone, no ground truth.

Each frame's reference disparity is the median of other frames' disparities carried into it (their points
triangulated, moved by the poses, fitted at its pixel centres with occlusion handling:
:func:`prismap.camera.fitted_disparity`). The frame's errors against that reference are characterised
exactly as against ground truth (:func:`characterise_matcher`, classes and all), and the reference's own
noise, measured from the references' disagreement, is taken out of every component's variance. Frames
whose errors repeat are kept out of each other's references: the smallest frame lag at which frames
disagree as much as distant ones do is measured first (:func:`lag_agreement`). The derivation and its
assumptions are docs/SENSOR_MODELS.md, "Self-characterisation".
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from prismap._progress import progress as progress_bar
from prismap._validate import check_integer
from prismap.camera import StereoCamera, fitted_disparity
from prismap.characterise._run import Characterisation, characterise_matcher
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.io._frame import StereoFrame
from prismap.stereo import StereoMatcher

DEFAULT_REFERENCES = 4
"""Frames whose disparities make each frame's reference (the nearest allowed ones)."""
DEFAULT_MAX_LAG = 4
"""Largest frame lag :func:`lag_agreement` measures."""
LAG_PLATEAU = 0.9
"""A lag is free of repeated errors once its disagreement reaches this share of the largest measured."""
GROSS_PX = 1.0
"""Disagreement (pixels) beyond which two frames disagree grossly, as ``frame_error_correlation`` counts gross."""
MAX_RESIDUAL_PX = 0.5
"""Largest RMS residual (pixels) of a reference frame's affine fit at a pixel (see :func:`fitted_disparity`)."""
MIN_SIGMA_SHARE = 0.5
"""Removing the reference noise never shrinks a component's sigma below this share of the fitted one."""
MIN_LAG_PIXELS = 2000
"""Fewest compared pixels for a lag's agreement to count in :func:`choose_min_lag`."""
LAG_PAIRS = 8
"""Frame pairs per lag that :func:`lag_agreement` measures (evenly spread)."""
FREE_SAMPLES = 8
"""Points on each carried pixel's ray checked to lie in space the carrying frame saw free."""
_MAD_TO_SIGMA = 1.482602218505602  # 1 / Phi^-1(3/4): the MAD of a Gaussian times this is its sigma


@dataclasses.dataclass(frozen=True)
class SelfCharacterisation:
    """Result of :func:`self_characterise`.

    Attributes
    ----------
    characterisation : Characterisation
        Histograms of the errors against the references and the error model with the reference noise
        removed (its ``source`` is ``"self"``).
    record : dict
        How it was made (JSON): the lag agreement, the chosen ``min_lag``, references per frame,
        reference coverage and noise; also stored in the model as ``provenance``.
    """

    characterisation: Characterisation
    record: dict


def carried_disparity(
    disparity_from,
    pose_from,
    pose_to,
    camera,
    shape,
    *,
    near_m=0.0,
    max_residual_px=MAX_RESIDUAL_PX,
    free_samples=FREE_SAMPLES,
    free_margin_px=GROSS_PX,
):
    """Frame ``from``'s computed disparity carried into frame ``to``'s pixels (NaN where none or unverified).

    The carried value of a pixel is the affine fit of ``from``'s points around it
    (:func:`prismap.camera.fitted_disparity`). It is kept only where frame ``from`` saw the pixel's ray in
    front of that surface point: ``free_samples`` points evenly spaced on the ray from ``near_m`` in front
    of ``to``'s camera to the surface project into ``from``'s image, each in front of ``from``'s own depth there (or where
    ``from`` has no disparity). A surface ``to`` sees but ``from`` never saw (outside its view or behind
    an object) cannot then be replaced by whatever ``from`` saw behind it.

    Parameters
    ----------
    disparity_from : (H, W) float, pixels, NaN = invalid
    pose_from, pose_to : (4, 4) float, T_world_cam of the two frames
    camera : StereoCamera
    shape : (H, W) of frame ``to``
    near_m : float >= 0, metres
        Depth in front of the camera assumed empty (no frame need have seen it free): nearer than the
        nearest surface the sequence shows, e.g. (see :func:`self_characterise`).
    max_residual_px : float, pixels
        See :func:`prismap.camera.fitted_disparity`.
    free_samples : int >= 1
    free_margin_px : float, pixels
        Disparity margin of the free-space test (a frame's own noise must not hide its free space).
    """
    disparity_from = np.asarray(disparity_from, np.float64)
    points = camera.triangulate(disparity_from)
    points = points[np.isfinite(points).all(axis=-1)]
    to_from = np.linalg.inv(pose_to) @ pose_from
    carried = fitted_disparity(
        points @ to_from[:3, :3].T + to_from[:3, 3], camera, shape, max_residual_px=max_residual_px
    )
    row, col = np.nonzero(np.isfinite(carried))
    depth = camera.depth_from_disparity(carried[row, col])
    rays = camera.pixel_rays(shape)[row, col] * depth[:, None]  # the surface points, frame ``to``
    from_to = np.linalg.inv(to_from)
    height, width = disparity_from.shape
    seen = np.isfinite(depth)
    start = np.minimum(near_m / depth, 1.0)
    for t in np.arange(1, free_samples + 1) / (free_samples + 1):
        sample = ((start + t * (1.0 - start))[:, None] * rays) @ from_to[:3, :3].T + from_to[:3, 3]
        u, v = camera.project(sample)
        c, r = np.floor(u + 0.5), np.floor(v + 0.5)
        inside = np.isfinite(u) & (c >= 0) & (c < width) & (r >= 0) & (r < height)
        there = np.full(row.size, np.nan)
        there[inside] = disparity_from[r[inside].astype(np.int64), c[inside].astype(np.int64)]
        seen &= inside & ~(there > camera.disparity_from_depth(sample[:, 2]) + free_margin_px)
    carried[row[~seen], col[~seen]] = np.nan
    return carried


def _robust_sigma(values):
    """``1.4826 * MAD``: the sigma of the values' Gaussian core (NaN for none)."""
    if values.size == 0:
        return float("nan")
    return float(_MAD_TO_SIGMA * np.median(np.abs(values - np.median(values))))


def lag_agreement(
    frames: Sequence[StereoFrame],
    disparities: Sequence[npt.ArrayLike],
    camera: StereoCamera,
    *,
    max_lag: int = DEFAULT_MAX_LAG,
    pairs: int = LAG_PAIRS,
    near_m: float = 0.0,
) -> list[dict[str, Any]]:
    """How much frames ``lag`` apart disagree at the same pixels, for lag = 1..``max_lag``.

    For frame pairs ``(k, k + lag)`` the later frame's disparity is carried into the earlier one and
    compared with its own. With independent errors the difference of two errors has twice an error's
    variance whatever the lag; errors that repeat at short lags cancel in the difference, so the
    disagreement grows with the lag until the errors are independent (geometry adds a slower growth).

    Parameters
    ----------
    frames : sequence of StereoFrame
        With ``T_world_cam``.
    disparities : sequence of (H, W) float, pixels
        The matcher's disparity of each frame.
    camera : StereoCamera
    max_lag : int >= 1
    pairs : int >= 1
        Frame pairs measured per lag (evenly spread).
    near_m : float, metres
        See :func:`carried_disparity`.

    Returns
    -------
    list of dict
        Per lag: ``lag``, ``n_pixels``, ``core_sigma_px`` (robust sigma of the difference divided by
        sqrt 2: one error's core if independent) and ``gross_rate`` (share of differences beyond
        :data:`GROSS_PX`).
    """
    rows = []
    for lag in range(1, max_lag + 1):
        if lag >= len(frames):
            break
        starts = sorted({round(x) for x in np.linspace(0, len(frames) - 1 - lag, min(pairs, len(frames) - lag))})
        differences = []
        for k in starts:
            carried = carried_disparity(
                disparities[k + lag],
                frames[k + lag].T_world_cam,
                frames[k].T_world_cam,
                camera,
                np.shape(disparities[k]),
                near_m=near_m,
            )
            difference = carried - disparities[k]
            differences.append(difference[np.isfinite(difference)])
        difference = np.concatenate(differences)
        rows.append(
            {
                "lag": lag,
                "n_pixels": int(difference.size),
                "core_sigma_px": _robust_sigma(difference) / np.sqrt(2.0),
                "gross_rate": float(np.mean(np.abs(difference) > GROSS_PX)) if difference.size else float("nan"),
            }
        )
    return rows


def choose_min_lag(agreement, *, plateau=LAG_PLATEAU):
    """The smallest lag whose core sigma and gross rate both reach ``plateau`` of their largest measured values.

    Only lags with at least :data:`MIN_LAG_PIXELS` compared pixels count.

    Parameters
    ----------
    agreement : list of dict
        From :func:`lag_agreement`.
    plateau : float in (0, 1]
    """
    measured = [row for row in agreement if row["n_pixels"] >= MIN_LAG_PIXELS]
    if not measured:
        raise PrismapInputError(
            f"no lag up to {len(agreement)} has {MIN_LAG_PIXELS} pixels that two frames see: the "
            "frames share too little surface to self-characterise (closer frames, or give min_lag)"
        )
    sigma = max(row["core_sigma_px"] for row in measured)
    gross = max(row["gross_rate"] for row in measured)
    for row in measured:
        if row["core_sigma_px"] >= plateau * sigma and row["gross_rate"] >= plateau * gross:
            return row["lag"]
    return measured[-1]["lag"]


def reference_frames(k, n_frames, min_lag, n_references):
    """The ``n_references`` frames nearest to ``k`` at least ``min_lag`` from it (nearest first, earlier first on ties)."""
    candidates = [j for j in range(n_frames) if abs(j - k) >= min_lag]
    return sorted(candidates, key=lambda j: (abs(j - k), j))[:n_references]


def median_variance(n, *, draws=200_000):
    """Variance of the median of ``n`` independent standard normal values (seeded Monte Carlo, 0.5 % accurate).

    The reference of a pixel is the median of ``n`` frames' values; its noise variance is this times one
    frame's. (For large ``n`` it tends to ``pi / (2 n)``; for ``n = 3`` it is 0.449, not 0.524.)
    """
    rng = np.random.default_rng(0)
    return float(np.var(np.median(rng.standard_normal((draws, int(n))), axis=1)))


def self_characterise(
    frames: Sequence[StereoFrame],
    matcher: StereoMatcher,
    *,
    min_lag: int | None = None,
    max_lag: int = DEFAULT_MAX_LAG,
    n_references: int = DEFAULT_REFERENCES,
    min_references: int = 2,
    dataset: str = "",
    progress: bool = True,
    **options: Any,
) -> SelfCharacterisation:
    """Characterise ``matcher`` on a posed stereo sequence without ground truth (module docstring).

    Parameters
    ----------
    frames : sequence of StereoFrame
        In sequence order, each with ``T_world_cam``, one camera; ``disparity_gt`` is ignored.
    matcher : prismap.stereo.StereoMatcher
    min_lag : int >= 1 or None
        Fewest frames between a frame and its reference frames; None = :func:`choose_min_lag` of
        :func:`lag_agreement` up to ``max_lag``.
    max_lag : int >= 1
    n_references : int >= 1
        Frames whose carried disparities make a reference (their median).
    min_references : int >= 1
        Fewest carried values a pixel needs for a reference (2: the median of two is their mean, so one
        gross value moves it; 3 outvotes it).
    dataset : str
        Name recorded in the model.
    progress : bool
    **options
        Keyword options of :func:`characterise_matcher` (``conditioned``, ``max_components``, ``seed``, ...).

    Returns
    -------
    SelfCharacterisation
    """
    frames = list(frames)
    max_lag = check_integer(max_lag, "max_lag", expected="an integer >= 1", condition=lambda n: n >= 1)
    n_references = check_integer(n_references, "n_references", expected="an integer >= 1", condition=lambda n: n >= 1)
    min_references = check_integer(
        min_references,
        "min_references",
        expected=f"an integer in [1, {n_references}]",
        condition=lambda n: 1 <= n <= n_references,
    )
    if len(frames) < 2:
        raise PrismapInputError(f"self-characterisation needs at least 2 posed frames; got {len(frames)}")
    for index, frame in enumerate(frames):
        if frame.T_world_cam is None:
            raise PrismapInputError(
                f"frame {index} ({frame.name or 'unnamed'}): has no pose (`T_world_cam`); "
                "self-characterisation carries disparities between frames by their poses"
            )
        if frame.camera != frames[0].camera:
            raise PrismapInputError(f"frame {index} ({frame.name or 'unnamed'}): its camera differs from frame 0's")
    camera = frames[0].camera
    enabled = None if progress else False
    disparities = [
        np.asarray(matcher.compute(frame.left, frame.right), np.float64)
        for frame in progress_bar(
            frames, total=len(frames), desc=f"self {matcher.name}: match", unit="frame", enabled=enabled
        )
    ]
    largest = max((float(np.nanmax(d)) for d in disparities if np.isfinite(d).any()), default=np.nan)
    if not largest > 0:
        raise PrismapInputError(f"matcher {matcher.name!r} found no positive disparity in any frame")
    near_m = float(camera.depth_from_disparity(largest))
    agreement = lag_agreement(frames, disparities, camera, max_lag=min(max_lag, len(frames) - 1), near_m=near_m)
    if min_lag is None:
        min_lag = choose_min_lag(agreement)
    min_lag = check_integer(
        min_lag, "min_lag", expected=f"an integer in [1, {len(frames) - 1}]", condition=lambda n: 1 <= n < len(frames)
    )
    reference_frames_, pair_differences, counts, unreferenced = [], [], [], []
    for k, frame in enumerate(
        progress_bar(frames, total=len(frames), desc=f"self {matcher.name}: references", unit="frame", enabled=enabled)
    ):
        shape = np.shape(disparities[k])
        carried = np.stack(
            [
                carried_disparity(
                    disparities[j], frames[j].T_world_cam, frame.T_world_cam, camera, shape, near_m=near_m
                )
                for j in reference_frames(k, len(frames), min_lag, n_references)
            ]
            or [np.full(shape, np.nan)]
        )
        count = np.isfinite(carried).sum(axis=0)
        reference = np.full(shape, np.nan)
        enough = count >= min_references
        if enough.any():
            reference[enough] = np.nanmedian(carried[:, enough], axis=0)
        both = np.isfinite(carried[:2]).all(axis=0) if len(carried) >= 2 else np.zeros(shape, bool)
        pair_differences.append((carried[0] - carried[1])[both] if both.any() else np.empty(0))
        counts.append(count[enough & np.isfinite(disparities[k])])
        if counts[-1].size:
            reference_frames_.append(dataclasses.replace(frame, disparity_gt=reference.astype(np.float32)))
        else:
            unreferenced.append(k)
    counts = np.concatenate(counts)
    if counts.size == 0:
        raise PrismapInputError(
            f"no pixel of any frame has a reference from {min_references} other frame(s) at least "
            f"{min_lag} frame(s) away: the frames see no common surface"
        )
    carried_sigma = _robust_sigma(np.concatenate(pair_differences)) / np.sqrt(2.0)
    values, shares = np.unique(counts, return_counts=True)
    factor = float(sum(share * median_variance(n) for n, share in zip(values, shares)) / counts.size)
    reference_variance = factor * carried_sigma**2 if np.isfinite(carried_sigma) else 0.0
    options.setdefault("search_frames", len(reference_frames_))
    result = characterise_matcher(
        reference_frames_, matcher, dataset=dataset, progress=progress, source="self", **options
    )
    record = {
        "method": "median of other frames' disparities carried by the poses (docs/SENSOR_MODELS.md, "
        "Self-characterisation)",
        "n_frames": len(frames),
        "frames_without_reference": unreferenced,
        "near_m": near_m,
        "lag_agreement": agreement,
        "min_lag": int(min_lag),
        "n_references": n_references,
        "min_references": min_references,
        "mean_references": float(counts.mean()),
        "carried_sigma_px": carried_sigma,
        "reference_variance_px2": reference_variance,
        "min_sigma_share": MIN_SIGMA_SHARE,
    }
    model = dataclasses.replace(remove_reference_noise(result.model, reference_variance), provenance=record)
    return SelfCharacterisation(dataclasses.replace(result, model=model), record)


def _narrowed(mixture, variance):
    """``mixture`` with ``variance`` (px^2) taken from every component, sigma kept >= MIN_SIGMA_SHARE of its own."""
    sigmas = np.sqrt(np.maximum(mixture.sigmas**2 - variance, (MIN_SIGMA_SHARE * mixture.sigmas) ** 2))
    return GaussianMixture(mixture.weights, mixture.means, sigmas)


def remove_reference_noise(model, variance):
    """The error model with the reference's noise variance ``variance`` (px^2) removed from every fitted component.

    Errors against a reference are ``e_k - e_ref``; with ``e_ref`` independent and Gaussian of variance
    ``s^2`` their density is the true mixture with every component's variance grown by ``s^2``, so each
    fitted ``sigma^2`` less ``s^2`` is the frame's own (floored, see :data:`MIN_SIGMA_SHARE`). Outlier
    components mixed into classes are left as fitted: their width dwarfs ``s``.
    """
    variance = float(variance)
    if variance < 0 or not np.isfinite(variance):
        raise PrismapInputError(f"`variance` must be a finite number >= 0 (px^2); got {variance!r}")

    def narrowed_fits(fits):
        return tuple(dataclasses.replace(fit, mixture=_narrowed(fit.mixture, variance)) for fit in fits)

    class_models = tuple(dataclasses.replace(m, fits=narrowed_fits(m.fits)) for m in model.class_models)
    if not model.conditioned:
        class_models = ()
    return dataclasses.replace(model, fits=narrowed_fits(model.fits), class_models=class_models)
