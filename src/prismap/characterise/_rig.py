"""The rig an error model was made on, and the check that a run uses the same one.

A disparity error model holds for one camera and one matcher setting: the focal length and baseline set how
disparity relates to depth, the image size and the matcher's parameters (block size, smoothness penalties,
search range) how the matcher fails. A model characterised on another rig (Middlebury's Motorcycle, used on
a street camera) gives PRISM wrong likelihoods without any sign of it, so the mapping commands compare the
model's recorded rig with their own and warn, naming both, or refuse with ``--strict-rig``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from prismap.camera import StereoCamera
from prismap.characterise._model import ErrorModel
from prismap.errors import PrismapInputError

RIG_RTOL = 0.01
"""Relative difference of focal length or baseline beyond which two rigs differ."""

_NUMBERS = (("focal_px", "focal length", "px"), ("baseline_m", "baseline", "m"))
_SIZES = (("width", "image width", "px"), ("height", "image height", "px"))


def describe_rig(
    camera: StereoCamera, shape: tuple[int, int] | None, matcher: str | None, matcher_params: Mapping[str, Any] | None
) -> dict[str, Any]:
    """The rig record of an error model (JSON): camera, image size and matcher.

    Parameters
    ----------
    camera : StereoCamera
    shape : (H, W) or None
        Image size; None = the camera's own ``(height, width)`` (None where it has none).
    matcher : str or None
        Matcher name; None = unknown (disparities made elsewhere).
    matcher_params : dict or None
        The matcher's full parameters (``StereoMatcher.params()``); None = unknown.
    """
    height, width = shape if shape is not None else (camera.height, camera.width)
    return {
        "focal_px": float(camera.focal_px),
        "baseline_m": float(camera.baseline_m),
        "width": None if width is None else int(width),
        "height": None if height is None else int(height),
        "matcher": matcher,
        "matcher_params": None if matcher_params is None else dict(matcher_params),
    }


def rig_differences(recorded: Mapping[str, Any], current: Mapping[str, Any], *, rtol: float = RIG_RTOL) -> list[str]:
    """What differs between two rig records, in words (empty when they agree).

    Focal length and baseline differ beyond ``rtol`` (relative); image sizes, the matcher and each matcher
    parameter must be equal. A field missing (None) on either side is not compared.
    """
    found = []
    for name, label, unit in _NUMBERS:
        a, b = recorded.get(name), current.get(name)
        if a is not None and b is not None and not math.isclose(a, b, rel_tol=rtol):
            found.append(f"{label} {a:g} {unit} vs {b:g} {unit}")
    for name, label, unit in _SIZES:
        a, b = recorded.get(name), current.get(name)
        if a is not None and b is not None and a != b:
            found.append(f"{label} {a} {unit} vs {b} {unit}")
    a, b = recorded.get("matcher"), current.get("matcher")
    if a is not None and b is not None and a != b:
        found.append(f"matcher {a} vs {b}")
    elif recorded.get("matcher_params") is not None and current.get("matcher_params") is not None:
        mine, theirs = recorded["matcher_params"], current["matcher_params"]
        for key in sorted(set(mine) | set(theirs)):
            if mine.get(key) != theirs.get(key):
                found.append(f"matcher parameter {key} {mine.get(key)!r} vs {theirs.get(key)!r}")
    return found


def check_rig(model: ErrorModel, current: Mapping[str, Any], *, strict: bool, where: str = "error model") -> str | None:
    """Compare ``model``'s recorded rig with the run's: the warning to print, or raise when ``strict``.

    Parameters
    ----------
    model : ErrorModel
        Its ``rig`` and ``dataset`` name the model's side. A model made before rigs were recorded (``rig``
        None) passes unless ``strict``: then nothing says it fits, and it is refused.
    current : dict
        :func:`describe_rig` of the run.
    strict : bool
        Raise :class:`PrismapInputError` instead of warning.
    where : str
        Names the model in the message (its file).

    Returns
    -------
    str or None
        The one-line warning naming both rigs and what differs, or None when the rigs agree.
    """
    if model.rig is None:
        if not strict:
            return None
        message = (
            f"{where} ({model.dataset}) records no rig, so it cannot be checked against this run's "
            f"({_summary(current)}); characterise this rig to be sure"
        )
    else:
        found = rig_differences(model.rig, current)
        if not found:
            return None
        message = (
            f"{where} was made on another rig ({model.dataset}: {_summary(model.rig)}) than this run's "
            f"({_summary(current)}): " + "; ".join(found)
        )
    if strict:
        raise PrismapInputError(message + " (--strict-rig)")
    return message


def _summary(rig):
    """``f 721.5 px, b 0.54 m, 1242x375, sgbm`` from a rig record."""
    size = f"{rig.get('width')}x{rig.get('height')}" if rig.get("width") is not None else "size unknown"
    return (
        f"f {rig.get('focal_px', float('nan')):g} px, b {rig.get('baseline_m', float('nan')):g} m, {size}, "
        f"{rig.get('matcher') or 'matcher unknown'}"
    )
