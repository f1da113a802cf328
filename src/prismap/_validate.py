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
