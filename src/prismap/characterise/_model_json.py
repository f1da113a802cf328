"""Validation of an error-model file's JSON: every number, integer, object and field checked and named where it
fails, so a hostile or damaged file is refused with a message instead of building a broken model."""

import numpy as np

from prismap.characterise._class_model import ClassModel
from prismap.characterise._classes import ErrorClasses
from prismap.characterise._features import FEATURE_UNITS
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture, MixtureFit

MAX_COMPONENTS = 64
"""Largest G a file may hold (EM never fits more; the bound keeps a hostile file from building huge arrays)."""


MAX_CLASSES = 64


_FIT_FIELDS = ("log_likelihood", "aic", "bic", "n_samples", "n_iter", "converged")

MAX_ERROR_PX = 16384.0
"""Bound on every mixture mean and sigma (pixels) when the file's matcher parameters do not give its range:
the widest image ``MAX_IMAGE_PIXELS`` admits, as no disparity error can exceed the image width."""


def error_bound_px(params, image_width=None):
    """Largest ``|mean|`` and ``sigma`` (pixels) a mixture of this matcher and rig may have.

    An error is ``d_true - d_computed``. A matched disparity lies in ``[min_disparity, min_disparity +
    num_disparities)`` (OpenCV; ``max_disparity`` for the variational matcher), and a true disparity of a point
    both cameras see is below the image width, which may well exceed the search range (a near object). So with the
    rig's ``image_width`` recorded the bound is the larger of the search span and ``image_width + |min_disparity|``;
    without it, :data:`MAX_ERROR_PX` (the widest image there can be).
    """
    reach = params.get("num_disparities", params.get("max_disparity"))
    low = params.get("min_disparity", 0)
    if image_width is None or not (
        _is_number(reach) and _is_number(low) and 0 < reach < MAX_ERROR_PX and abs(low) < MAX_ERROR_PX
    ):
        return MAX_ERROR_PX
    return max(float(reach) + abs(float(low)), float(image_width) + abs(float(low)))


def check_mixture_range(means, sigmas, bound_px, where):
    """Refuse a mean beyond ``+-bound_px`` or a sigma above it, naming the first and the bound's origin."""
    for name, values in (("means", np.abs(means)), ("sigmas", np.asarray(sigmas))):
        if values.size and values.max() > bound_px:
            raise PrismapInputError(
                f"{where}: `{name}` reach {values.max():.6g} px; an error of this rig and matcher lies within "
                f"+-{bound_px:g} px (true disparities below the image width, matched ones within the search range)"
            )


def _fits_to_list(fits):
    return [
        {"n_components": fit.n_components, **fit.mixture.to_dict(), **{k: getattr(fit, k) for k in _FIT_FIELDS}}
        for fit in fits
    ]


def _fits_from_list(entries, where, bound_px=MAX_ERROR_PX):
    if not isinstance(entries, list) or not entries:
        raise PrismapInputError(f"{where}: must be a non-empty list")
    if len(entries) > MAX_COMPONENTS:
        raise PrismapInputError(f"{where}: holds {len(entries)} fits; at most {MAX_COMPONENTS} are allowed")
    fits = []
    for index, entry in enumerate(entries):
        at = f"{where}[{index}]"
        _require(entry, ("n_components", "weights", "means", "sigmas", *_FIT_FIELDS), at)
        n_components = _integer(entry["n_components"], f"{at}: `n_components`", 1, MAX_COMPONENTS)
        for name in ("weights", "means", "sigmas"):
            values = entry[name]
            if not isinstance(values, list) or not all(_is_number(v) for v in values):
                raise PrismapInputError(f"{at}: `{name}` must be a list of numbers")
            if len(values) != n_components:
                raise PrismapInputError(
                    f"{at}: `n_components` is {n_components} but `{name}` has {len(values)} value(s)"
                )
        mixture = GaussianMixture.from_dict(entry, source=at)
        check_mixture_range(mixture.means, mixture.sigmas, bound_px, at)
        if not isinstance(entry["converged"], bool):
            raise PrismapInputError(f"{at}: `converged` must be true or false; got {entry['converged']!r}")
        fits.append(
            MixtureFit(
                mixture,
                _number(entry["log_likelihood"], f"{at}: `log_likelihood`"),
                _number(entry["aic"], f"{at}: `aic`"),
                _number(entry["bic"], f"{at}: `bic`"),
                _number(entry["n_samples"], f"{at}: `n_samples`", low=0.0),
                _integer(entry["n_iter"], f"{at}: `n_iter`", 0, 10**9),
                entry["converged"],
            )
        )
    counts = [fit.n_components for fit in fits]
    if len(set(counts)) != len(counts):
        raise PrismapInputError(f"{where}: G = {counts} repeats a component count")
    return fits


def _classes_from_dict(data, source, bound_px=MAX_ERROR_PX):
    """The class fields of a version-2 file as keyword arguments of :class:`ErrorModel`."""
    _require(data, ("features", "classes"), source)
    features = _object(data["features"], f"{source}: `features`")
    _require(features, ("names",), f"{source}: `features`")
    names = features["names"]
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names) or len(names) > len(FEATURE_UNITS):
        raise PrismapInputError(f"{source}: `features.names` must be a list of feature names")
    unknown = [n for n in names if n not in FEATURE_UNITS]
    if unknown:
        raise PrismapInputError(f"{source}: unknown feature(s) {unknown}; known: {list(FEATURE_UNITS)}")
    settings = {}
    if names:
        _require(features, ("edge_threshold_px", "texture_window_px"), f"{source}: `features`")
        settings = {
            "edge_threshold_px": _number(
                features["edge_threshold_px"],
                f"{source}: `features.edge_threshold_px`",
                low=0.0,
                open_low=True,
                high=1e6,
            ),
            "texture_window_px": _integer(
                features["texture_window_px"], f"{source}: `features.texture_window_px`", 1, 10**4
            ),
        }
    entries = data["classes"]
    if not isinstance(entries, list) or not entries:
        raise PrismapInputError(f"{source}: `classes` must be a non-empty list")
    if len(entries) > MAX_CLASSES:
        raise PrismapInputError(f"{source}: `classes` holds {len(entries)} classes; at most {MAX_CLASSES} are allowed")
    lower, upper, models = [], [], []
    for k, entry in enumerate(entries):
        at = f"{source}: classes[{k}]"
        _require(entry, ("bounds", "share", "selected_components", "models"), at)
        bounds = _object(entry["bounds"], f"{at}: `bounds`")
        if sorted(bounds) != sorted(names):
            raise PrismapInputError(f"{at}: `bounds` must name exactly the features {names}; got {sorted(bounds)}")
        low, high = [], []
        for name in names:
            pair = bounds[name]
            if not isinstance(pair, list) or len(pair) != 2 or not all(v is None or _is_number(v) for v in pair):
                raise PrismapInputError(f"{at}: bounds of {name!r} must be [lower or null, upper or null]")
            low.append(-np.inf if pair[0] is None else _number(pair[0], f"{at}: lower bound of {name!r}"))
            high.append(np.inf if pair[1] is None else _number(pair[1], f"{at}: upper bound of {name!r}"))
        lower.append(low)
        upper.append(high)
        fits = _fits_from_list(entry["models"], f"{at}: models", bound_px)
        selected = _integer(entry["selected_components"], f"{at}: `selected_components`", 1, MAX_COMPONENTS)
        share = _number(entry["share"], f"{at}: `share`", low=0.0, high=1.0)
        statistics = _object(entry.get("statistics", {}), f"{at}: `statistics`")
        outlier = None
        if "outlier" in entry:
            outlier = _object(entry["outlier"], f"{at}: `outlier`")
            _require(outlier, ("weight", "mean", "sigma"), f"{at}: `outlier`")
            outlier = {
                "weight": _number(outlier["weight"], f"{at}: `outlier.weight`", low=0.0, high=0.999999),
                "mean": _number(outlier["mean"], f"{at}: `outlier.mean`"),
                "sigma": _number(outlier["sigma"], f"{at}: `outlier.sigma`", low=0.0, open_low=True),
            }
            check_mixture_range(np.array([outlier["mean"]]), np.array([outlier["sigma"]]), bound_px, f"{at}: `outlier`")
        try:
            models.append(ClassModel(fits, selected, share, statistics, outlier))
        except PrismapInputError as exc:
            raise PrismapInputError(f"{at}: {exc}") from None
    try:
        classes = ErrorClasses(
            tuple(names),
            np.array(lower).reshape(len(entries), len(names)),
            np.array(upper).reshape(len(entries), len(names)),
        )
    except PrismapInputError as exc:
        raise PrismapInputError(f"{source}: {exc}") from None
    return {
        "classes": classes,
        "class_models": tuple(models),
        "feature_settings": settings,
        "class_selection": _object(data.get("class_selection", {}), f"{source}: `class_selection`"),
    }


def _provenance_from_dict(data, source):
    """The optional ``source``, ``rig`` and ``provenance`` fields as keyword arguments of :class:`ErrorModel`."""
    extra = {}
    if "source" in data:
        if not isinstance(data["source"], str):
            raise PrismapInputError(f"{source}: `source` must be a string; got {_short(data['source'])}")
        extra["source"] = data["source"]
    rig = data.get("rig")
    if rig is not None:
        rig = _object(rig, f"{source}: `rig`")
        _require(rig, ("focal_px", "baseline_m"), f"{source}: `rig`")
        checked = {
            name: _number(rig[name], f"{source}: `rig.{name}`", low=0.0, open_low=True)
            for name in ("focal_px", "baseline_m")
        }
        for name in ("width", "height"):
            value = rig.get(name)
            checked[name] = None if value is None else _integer(value, f"{source}: `rig.{name}`", 1, 10**6)
        matcher = rig.get("matcher")
        if matcher is not None and not isinstance(matcher, str):
            raise PrismapInputError(f"{source}: `rig.matcher` must be a string or null; got {_short(matcher)}")
        params = rig.get("matcher_params")
        checked.update(
            matcher=matcher,
            matcher_params=None if params is None else _object(params, f"{source}: `rig.matcher_params`"),
        )
        extra["rig"] = checked
    if "provenance" in data:
        extra["provenance"] = _object(data["provenance"], f"{source}: `provenance`")
    return extra


def _is_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _number(value, where, *, low=-np.inf, high=np.inf, open_low=False):
    """``float(value)`` for a finite JSON number in range, else a one-line error naming ``where``."""
    if not _is_number(value):
        raise PrismapInputError(f"{where} must be a number; got {type(value).__name__} {_short(value)}")
    try:
        number = float(value)
    except OverflowError:
        number = np.inf
    if not np.isfinite(number) or number < low or number > high or (open_low and number == low):
        interval = f"{'(' if open_low else '['}{low:g}, {high:g}]"
        raise PrismapInputError(f"{where} must be a finite number in {interval}; got {_short(value)}")
    return number


def _integer(value, where, low, high):
    """``int(value)`` for a whole JSON number in ``[low, high]`` (2.0 is 2; 2.7 and "2" are errors)."""
    if not _is_number(value) or (isinstance(value, float) and not (np.isfinite(value) and value.is_integer())):
        raise PrismapInputError(f"{where} must be a whole number; got {_short(value)}")
    number = int(value)
    if not low <= number <= high:
        raise PrismapInputError(f"{where} must lie in [{low}, {high}]; got {_short(value)}")
    return number


def _object(value, where):
    if not isinstance(value, dict):
        raise PrismapInputError(f"{where} must be a JSON object; got {type(value).__name__}")
    return dict(value)


def _short(value):
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _require(data, fields, source):
    if not isinstance(data, dict):
        raise PrismapInputError(f"{source}: expected a JSON object; got {type(data).__name__}")
    missing = [name for name in fields if name not in data]
    if missing:
        raise PrismapInputError(f"{source}: missing field(s) {missing}")
