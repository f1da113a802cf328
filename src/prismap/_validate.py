"""Shared argument checks, so every public function words its errors the same way."""

import numpy as np

from prismap.errors import PrismapInputError


def as_float_array(value, name, *, ndim=None, shape=None, dtype=np.float64, allow_nan=True):
    """Return ``value`` as a contiguous float array, or raise naming ``name``.

    ``shape`` may contain ``None`` for a free axis. ``allow_nan=False`` also rejects infinities.
    """
    try:
        array = np.ascontiguousarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise PrismapInputError(f"`{name}` must be numeric; got {type(value).__name__}: {exc}") from None
    if ndim is not None and array.ndim != ndim:
        raise PrismapInputError(f"`{name}` must be {ndim}-D; got shape {array.shape}")
    if shape is not None:
        if array.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, array.shape)):
            expected = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
            raise PrismapInputError(f"`{name}` must have shape {expected}; got {array.shape}")
    if not allow_nan and not np.all(np.isfinite(array)):
        raise PrismapInputError(f"`{name}` must be finite; it contains NaN or infinity")
    return array


def check_positive(value, name):
    """Return ``float(value)`` if it is a finite number > 0, else raise naming ``name``."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise PrismapInputError(f"`{name}` must be a number > 0; got {value!r}") from None
    if not np.isfinite(number) or number <= 0:
        raise PrismapInputError(f"`{name}` must be a finite number > 0; got {value!r}")
    return number


def check_probability(value, name, *, open_interval=True):
    """Return ``float(value)`` if it lies in (0, 1) (or [0, 1]), else raise naming ``name``."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise PrismapInputError(f"`{name}` must be a probability; got {value!r}") from None
    ok = 0.0 < number < 1.0 if open_interval else 0.0 <= number <= 1.0
    if not ok:
        interval = "(0, 1)" if open_interval else "[0, 1]"
        raise PrismapInputError(f"`{name}` must lie in {interval}; got {value!r}")
    return number


def check_integer(value, name, *, expected="an integer", condition=None):
    """Return ``int(value)`` if ``value`` is an integer (not a bool) meeting ``condition``, else raise.

    ``expected`` words the requirement in the message, e.g. ``"a positive multiple of 16"``.
    """
    try:
        number = int(value)
    except (TypeError, ValueError, OverflowError):
        number = None
    if (
        number is None
        or isinstance(value, (bool, np.bool_))
        or number != value
        or (condition is not None and not condition(number))
    ):
        raise PrismapInputError(f"`{name}` must be {expected}; got {value!r}")
    return number


def check_real(value, name, *, minimum=-np.inf):
    """Return ``float(value)`` if it is a finite real number >= ``minimum``, else raise naming ``name``."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = np.nan
    if isinstance(value, (bool, np.bool_, str)) or not np.isfinite(number) or number < minimum:
        expected = "a finite number" + ("" if minimum == -np.inf else f" >= {minimum:g}")
        raise PrismapInputError(f"`{name}` must be {expected}; got {value!r}")
    return number


def parse_frame_range(text, name):
    """``"A:B"`` (Python-style: either side may be empty or negative) as ``(start, stop)``, None for an empty side.

    The one reader of frame ranges; each caller then checks the range against what it selects from. ``name``
    is the range's name in the message (``"--frames"``, ``"`frames`"``).
    """
    first, sep, last = str(text).partition(":")
    try:
        if not sep or ":" in last:
            raise ValueError
        return (int(first) if first.strip() else None, int(last) if last.strip() else None)
    except ValueError:
        raise PrismapInputError(
            f"{name} must look like A:B with integers A and B (either may be omitted); got {text!r}"
        ) from None


def check_classes(value, name, shape):
    """``value`` as a contiguous int32 array of ``shape``, every class >= -1 (-1 = no class), or raise."""
    array = np.asarray(value)
    if array.shape != tuple(shape) or not np.issubdtype(array.dtype, np.integer):
        raise PrismapInputError(
            f"`{name}` must be an integer array of shape {tuple(shape)}; got {array.dtype} {array.shape}"
        )
    if array.size and (array.min() < -1 or array.max() > np.iinfo(np.int32).max):
        raise PrismapInputError(
            f"`{name}` must hold classes >= 0 or -1 (no class); got values in [{array.min()}, {array.max()}]"
        )
    return np.ascontiguousarray(array, dtype=np.int32)


#: Largest ``max |R^T R - I|`` a pose's rotation may show (text files round to ~1e-6; KITTI to ~1e-9).
ROTATION_TOLERANCE = 1e-3


def check_pose(value, name):
    """Return ``value`` as a (4, 4) float64 rigid transform, or raise naming ``name``.

    The one pose check of prismap: every pose source (``poses.txt``, KITTI ``poses/NN.txt``,
    :class:`prismap.io.StereoFrame`) calls it. The rotation must be orthonormal within
    :data:`ROTATION_TOLERANCE` with det +1 (a scaled matrix or a reflection is refused), the translation
    finite and the last row ``[0, 0, 0, 1]``.

    Parameters
    ----------
    value : (4, 4) array_like, metres
    name : str
        The pose's name in messages, e.g. ``"poses.txt line 3"`` or ``"`T_world_cam`"``.
    """
    pose = as_float_array(value, name, shape=(4, 4), allow_nan=False)
    rotation = pose[:3, :3]
    error = float(np.abs(rotation.T @ rotation - np.eye(3)).max())
    if not error <= ROTATION_TOLERANCE or np.linalg.det(rotation) < 0:
        raise PrismapInputError(
            f"{name}: rotation is not orthonormal with det +1 (max |R^T R - I| = {error:.3g}, "
            f"det = {np.linalg.det(rotation):.3g})"
        )
    if not np.array_equal(pose[3], [0.0, 0.0, 0.0, 1.0]):
        raise PrismapInputError(f"{name}: the last row of a pose must be [0, 0, 0, 1]; got {pose[3].tolist()}")
    return pose
