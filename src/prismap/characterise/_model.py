"""The error-model file: fitted mixtures of one matcher's errors, per class of pixels, and how they were made.

Format (JSON, ``format_version`` 2)::

    {"format": "prismap-error-model", "format_version": 2,
     "matcher": {"name": "sgbm", "params": {...}}, "dataset": "middlebury-motorcycle",
     "bin_width_px": 0.03125,
     "statistics": {"n_frames", "n_errors", "n_gt_valid", "n_outside_bins", "coverage", "bad_1px",
                    "bad_2px", "mean_abs_error_px"},
     "selection": {"criterion": "bic", "tolerance_nats_per_error": 0.01},  # or {"criterion": "held-out", "held_out": ...}
     "selected_components": 2,
     "models": [{"n_components": 1, "weights": [...], "means": [...], "sigmas": [...],
                 "log_likelihood": ..., "aic": ..., "bic": ..., "n_samples": ..., "n_iter": ...,
                 "converged": true}, ...],
     "features": {"names": ["edge_distance_px"], "units": {"edge_distance_px": "px"},
                  "edge_threshold_px": 1.0, "texture_window_px": 7},
     "classes": [{"bounds": {"edge_distance_px": [null, 2.0]}, "share": 0.12, "statistics": {...},
                  "selected_components": 3, "models": [...as above...],
                  "outlier": {"weight": 1e-4, "mean": 6.8, "sigma": 15.6}}, ...],
     "class_selection": {"held_out": "...", "plain_nats_per_error": ..., "conditioned_nats_per_error": ...,
                         "candidates": [...]}}

The top-level ``models`` / ``selected_components`` are the whole-image (plain) mixture: what version 1 held,
what a plain sensor model uses, and the model of pixels outside every class (class -1). ``classes`` tile
the space of the named features (see :class:`~prismap.characterise.ErrorClasses`; ``null`` is an infinite
bound); each has its own fits over G, selected G, and share of the characterised pixels, and optionally an
outlier component (the whole-image mixture's widest) mixed into its selected mixture with the given weight,
so no class is certain never to fail grossly (:func:`prismap.gmm.fit_outlier_weight`). A model without
features has one class equal to the plain model. A version-1 file loads as that one class.

Means and sigmas are pixels; AIC and BIC use ``k = 3G - 1`` (see :class:`prismap.gmm.MixtureFit`).
"""

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from prismap._files import write_text_atomic
from prismap.characterise._classes import ErrorClasses
from prismap.characterise._features import FEATURE_UNITS, LR_FEATURE, compute_features
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture, MixtureFit
from prismap.stereo._base import to_grey

FORMAT = "prismap-error-model"
FORMAT_VERSION = 2
READABLE_VERSIONS = (1, 2)
TABLE_MIN_WEIGHT = 0.1
MAX_COMPONENTS = 64
"""Largest G a file may hold (EM never fits more; the bound keeps a hostile file from building huge arrays)."""
MAX_CLASSES = 64
_FIT_FIELDS = ("log_likelihood", "aic", "bic", "n_samples", "n_iter", "converged")
_SHARE_TOLERANCE = 1e-6
HELD_OUT = "held-out"
"""``selection["criterion"]`` of a conditioned characterisation: every G (the whole image's and each class's)
chosen by the log-likelihood of held-out errors, as the classes are (:func:`prismap.characterise.choose_classes`)."""


def _find_fit(fits, n_components):
    for fit in fits:
        if fit.n_components == n_components:
            return fit
    raise PrismapInputError(
        f"error model has no {n_components}-component fit; it has G = {[f.n_components for f in fits]}"
    )


@dataclass(frozen=True)
class ClassModel:
    """The fitted mixtures of one class of pixels.

    Attributes
    ----------
    fits : tuple of MixtureFit
        One per G, ascending.
    selected_components : int
    share : float in (0, 1]
        Share of the characterised pixels (with a computed value and ground truth) in this class.
    statistics : dict
        As ``ErrorHistogram.statistics`` of the class's errors.
    outlier : dict or None
        ``{"weight", "mean", "sigma"}`` (pixels): a component mixed into the selected fit; None = none.
    """

    fits: tuple
    selected_components: int
    share: float = 1.0
    statistics: dict = field(default_factory=dict)
    outlier: dict | None = None

    def __post_init__(self):
        object.__setattr__(self, "fits", tuple(sorted(self.fits, key=lambda fit: fit.n_components)))
        self.fit(self.selected_components)
        if self.outlier is not None:
            _ = self.mixture  # a bad outlier component fails here, not at first use

    def fit(self, n_components):
        """The :class:`MixtureFit` with ``n_components`` components."""
        return _find_fit(self.fits, n_components)

    @property
    def mixture(self):
        """The selected :class:`GaussianMixture` (pixels), with the outlier component if there is one."""
        fitted = self.fit(self.selected_components).mixture
        if self.outlier is None:
            return fitted
        return fitted.with_component(self.outlier["weight"], self.outlier["mean"], self.outlier["sigma"])


@dataclass(frozen=True)
class ErrorModel:
    """A matcher's characterised disparity error: mixtures for G = 1..Gmax, the selected G, and its classes.

    Attributes
    ----------
    matcher : str
    matcher_params : dict
    dataset : str
    bin_width : float, pixels
        Bin width of the fitted histogram.
    fits : tuple of MixtureFit
        Whole-image fits, one per G, ascending.
    selected_components : int
    selection : dict
        How G was selected: ``{"criterion": "bic" or "aic", "tolerance_nats_per_error": ...}`` (the smallest G
        within the tolerance of the best criterion), or ``{"criterion": HELD_OUT, "held_out": ...}``.
    statistics : dict
        Coverage, bad-pixel rates, mean absolute error, counts (see ``ErrorHistogram.statistics``).
    classes : ErrorClasses or None
        How pixels split into classes; None = one class (the plain model).
    class_models : tuple of ClassModel
        One per class; empty = the whole-image fits as the one class.
    feature_settings : dict
        ``edge_threshold_px`` and ``texture_window_px`` the features were computed with.
    class_selection : dict
        How the classes were chosen: held-out data, held-out log-likelihoods (nats per error).
    """

    matcher: str
    matcher_params: dict
    dataset: str
    bin_width: float
    fits: tuple
    selected_components: int
    selection: dict = field(default_factory=dict)
    statistics: dict = field(default_factory=dict)
    classes: ErrorClasses | None = None
    class_models: tuple = ()
    feature_settings: dict = field(default_factory=dict)
    class_selection: dict = field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "fits", tuple(sorted(self.fits, key=lambda fit: fit.n_components)))
        self.fit(self.selected_components)
        classes = ErrorClasses.single() if self.classes is None else self.classes
        class_models = tuple(self.class_models) or (
            ClassModel(self.fits, self.selected_components, 1.0, dict(self.statistics)),
        )
        if len(class_models) != classes.n_classes:
            raise PrismapInputError(
                f"error model has {classes.n_classes} class(es) but {len(class_models)} class mixture(s)"
            )
        for k, model in enumerate(class_models):
            if not model.share > 0 or model.statistics.get("n_errors", 1) == 0:
                raise PrismapInputError(f"error class {k} ({_describe(classes, k)}) has no pixels")
        total = sum(model.share for model in class_models)
        if abs(total - 1.0) > _SHARE_TOLERANCE:
            raise PrismapInputError(f"the shares of the error classes must sum to 1; got {total}")
        object.__setattr__(self, "classes", classes)
        object.__setattr__(self, "class_models", class_models)

    def fit(self, n_components):
        """The whole-image :class:`MixtureFit` with ``n_components`` components."""
        return _find_fit(self.fits, n_components)

    @property
    def mixture(self):
        """The selected whole-image :class:`GaussianMixture` (pixels): what the plain sensor models use."""
        return self.fit(self.selected_components).mixture

    @property
    def n_classes(self):
        """Number of error classes (1 for a plain model)."""
        return self.classes.n_classes

    @property
    def conditioned(self):
        """Whether the classes split pixels by features (False: one class, the plain model)."""
        return bool(self.classes.features)

    @property
    def class_mixtures(self):
        """The selected mixture of each class, in class order: tuple of GaussianMixture (pixels)."""
        return tuple(model.mixture for model in self.class_models)

    def check_usable(self, matcher, *, left_right_check):
        """Raise unless a run with this matcher can compute the features the classes need.

        Parameters
        ----------
        matcher : str
            The run's matcher name. A conditioned model was fitted to one matcher's failure pattern
            (its edges, its left-right disagreement), so it refuses another; a plain model accepts any.
        left_right_check : bool
            Whether the run's matcher runs its left-right check (needed for ``lr_disagreement_px``).
        """
        if not self.conditioned:
            return
        if matcher != self.matcher:
            raise PrismapInputError(
                f"the conditioned error model was fitted to matcher {self.matcher!r}; this run uses {matcher!r} "
                "(characterise that matcher, or use the plain model)"
            )
        if LR_FEATURE in self.classes.features and not left_right_check:
            raise PrismapInputError(
                f"the conditioned error model's classes use {LR_FEATURE}, which needs the matcher's left-right "
                "check; this run has it off (turn on left_right_check, or use the plain model)"
            )

    def classify(self, features):
        """Class of each pixel of one frame.

        Parameters
        ----------
        features : PixelFeatures
            From :func:`prismap.characterise.compute_features` with this model's :attr:`feature_settings`.

        Returns
        -------
        (H, W) int32: class index, ``-1`` where the disparity is invalid (or a used feature is NaN).
        """
        if self.conditioned:
            settings = {k: features.settings.get(k) for k in self.feature_settings}
            if settings != self.feature_settings:
                raise PrismapInputError(
                    f"the features were computed with {settings}; the error model needs {self.feature_settings}"
                )
        return self.classes.assign(features.values, features.valid)

    def classify_frame(self, left, right, disparity, lr_disagreement=None):
        """Class of each pixel of a stereo frame: its features (this model's :attr:`feature_settings`) from the
        images and the computed disparity, then :meth:`classify`.

        Parameters
        ----------
        left, right : (H, W) or (H, W, 3) uint8, the rectified images
        disparity : (H, W) float, pixels, NaN = invalid; the matcher's output
        lr_disagreement : (H, W) float, pixels, or None; the matcher's left-right disagreement

        Returns
        -------
        (H, W) int32, as :meth:`classify`.
        """
        features = compute_features(to_grey(left), to_grey(right), disparity, lr_disagreement, **self.feature_settings)
        return self.classify(features)

    def to_dict(self):
        """The JSON form documented in this module."""
        return {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "matcher": {"name": self.matcher, "params": self.matcher_params},
            "dataset": self.dataset,
            "bin_width_px": self.bin_width,
            "statistics": self.statistics,
            "selection": self.selection,
            "selected_components": self.selected_components,
            "models": _fits_to_list(self.fits),
            "features": {"names": list(self.classes.features),
                         "units": {name: FEATURE_UNITS[name] for name in self.classes.features},
                         **self.feature_settings},
            "classes": [
                {"bounds": bounds, "share": model.share, "statistics": model.statistics,
                 "selected_components": model.selected_components, "models": _fits_to_list(model.fits),
                 **({} if model.outlier is None else {"outlier": model.outlier})}
                for bounds, model in zip(self.classes.to_list(), self.class_models)
            ],
            "class_selection": self.class_selection,
        }

    @classmethod
    def from_dict(cls, data, *, source="error model"):
        """Inverse of :meth:`to_dict` (also reads format version 1); ``source`` starts every error message."""
        if not isinstance(data, dict):
            raise PrismapInputError(f"{source}: expected a JSON object; got {type(data).__name__}")
        if data.get("format") != FORMAT:
            raise PrismapInputError(f"{source}: not a prismap error model (field `format` is {data.get('format')!r})")
        version = data.get("format_version")
        if isinstance(version, bool) or version not in READABLE_VERSIONS or not isinstance(version, int):
            raise PrismapInputError(
                f"{source}: unsupported format_version {version!r}; expected one of {list(READABLE_VERSIONS)}"
            )
        _require(data, ("matcher", "dataset", "bin_width_px", "selected_components", "models"), source)
        matcher = data["matcher"]
        if not isinstance(matcher, dict) or not isinstance(matcher.get("name"), str):
            raise PrismapInputError(f"{source}: field `matcher` must be an object with a string `name`")
        params = matcher.get("params", {})
        if not isinstance(params, dict):
            raise PrismapInputError(f"{source}: field `matcher.params` must be an object; got {type(params).__name__}")
        if not isinstance(data["dataset"], str):
            raise PrismapInputError(f"{source}: field `dataset` must be a string; got {type(data['dataset']).__name__}")
        bin_width = _number(data["bin_width_px"], f"{source}: `bin_width_px`", low=0.0, high=8.0, open_low=True)
        selected = _integer(data["selected_components"], f"{source}: `selected_components`", 1, MAX_COMPONENTS)
        fits = _fits_from_list(data["models"], f"{source}: models")
        selection = _object(data.get("selection", {}), f"{source}: `selection`")
        statistics = _object(data.get("statistics", {}), f"{source}: `statistics`")
        extra = {}
        if version >= 2:
            extra = _classes_from_dict(data, source)
        try:
            return cls(matcher["name"], dict(params), data["dataset"], bin_width, fits, selected, selection,
                       statistics, **extra)
        except PrismapInputError as exc:
            raise PrismapInputError(f"{source}: {exc}") from None


def _describe(classes, k):
    bounds = classes.bounds(k)
    return ", ".join(f"{name} in [{lo:g}, {hi:g})" for name, (lo, hi) in bounds.items()) or "all pixels"


def _fits_to_list(fits):
    return [{"n_components": fit.n_components, **fit.mixture.to_dict(), **{k: getattr(fit, k) for k in _FIT_FIELDS}}
            for fit in fits]


def _fits_from_list(entries, where):
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
        if not isinstance(entry["converged"], bool):
            raise PrismapInputError(f"{at}: `converged` must be true or false; got {entry['converged']!r}")
        fits.append(MixtureFit(
            mixture,
            _number(entry["log_likelihood"], f"{at}: `log_likelihood`"),
            _number(entry["aic"], f"{at}: `aic`"),
            _number(entry["bic"], f"{at}: `bic`"),
            _number(entry["n_samples"], f"{at}: `n_samples`", low=0.0),
            _integer(entry["n_iter"], f"{at}: `n_iter`", 0, 10**9),
            entry["converged"],
        ))
    counts = [fit.n_components for fit in fits]
    if len(set(counts)) != len(counts):
        raise PrismapInputError(f"{where}: G = {counts} repeats a component count")
    return fits


def _classes_from_dict(data, source):
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
            "edge_threshold_px": _number(features["edge_threshold_px"], f"{source}: `features.edge_threshold_px`",
                                         low=0.0, open_low=True, high=1e6),
            "texture_window_px": _integer(features["texture_window_px"], f"{source}: `features.texture_window_px`",
                                          1, 10**4),
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
        fits = _fits_from_list(entry["models"], f"{at}: models")
        selected = _integer(entry["selected_components"], f"{at}: `selected_components`", 1, MAX_COMPONENTS)
        share = _number(entry["share"], f"{at}: `share`", low=0.0, high=1.0)
        statistics = _object(entry.get("statistics", {}), f"{at}: `statistics`")
        outlier = None
        if "outlier" in entry:
            outlier = _object(entry["outlier"], f"{at}: `outlier`")
            _require(outlier, ("weight", "mean", "sigma"), f"{at}: `outlier`")
            outlier = {"weight": _number(outlier["weight"], f"{at}: `outlier.weight`", low=0.0, high=0.999999),
                       "mean": _number(outlier["mean"], f"{at}: `outlier.mean`"),
                       "sigma": _number(outlier["sigma"], f"{at}: `outlier.sigma`", low=0.0, open_low=True)}
        try:
            models.append(ClassModel(fits, selected, share, statistics, outlier))
        except PrismapInputError as exc:
            raise PrismapInputError(f"{at}: {exc}") from None
    try:
        classes = ErrorClasses(tuple(names), np.array(lower).reshape(len(entries), len(names)),
                               np.array(upper).reshape(len(entries), len(names)))
    except PrismapInputError as exc:
        raise PrismapInputError(f"{source}: {exc}") from None
    return {"classes": classes, "class_models": tuple(models), "feature_settings": settings,
            "class_selection": _object(data.get("class_selection", {}), f"{source}: `class_selection`")}


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


def write_error_model(model, path):
    """Write ``model`` as JSON to ``path`` atomically (the file appears whole or not at all)."""
    write_text_atomic(path, json.dumps(model.to_dict(), indent=2, default=_plain) + "\n")


def _plain(value):
    """numpy scalars and arrays in matcher parameters become plain JSON numbers and lists."""
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"cannot write {type(value).__name__} to an error model")


def load_error_model(path):
    """Read an error-model JSON file; ``.mixture`` of the result is the selected mixture.

    Raises
    ------
    PrismapInputError
        For a missing file, invalid JSON, a wrong format or version, missing fields, a field of the wrong
        type or out of range, component counts that disagree with their arrays, classes that overlap,
        leave gaps or hold no pixels.
    """
    path = Path(path)
    if not path.is_file():
        raise PrismapInputError(f"error model {path}: no such file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except RecursionError:
        raise PrismapInputError(f"error model {path}: JSON nested too deeply to be an error model") from None
    except (UnicodeDecodeError, ValueError) as exc:  # JSONDecodeError, and integers too long to convert
        raise PrismapInputError(f"error model {path}: not valid JSON ({str(exc)[:120]})") from None
    return ErrorModel.from_dict(data, source=f"error model {path}")


def format_table(model):
    """Markdown table of the fits in the layout of the thesis's tables 3.1-3.3.

    One row per G with AIC, BIC and ``mu, sigma, w`` per component, heaviest component first. Like the
    thesis, rows with more than three components list only the components with weight > 0.1 (the
    rest are summed in a note); the selected G is marked. A conditioned model adds a per-class table:
    each class's bounds, share of pixels, bad-2px rate and selected mixture, and the held-out
    log-likelihoods that chose the classes.
    """
    stats = model.statistics
    lines = [
        f"# Disparity error model: {model.matcher} on {model.dataset}",
        "",
        (f"Errors e = d_true - d_computed (px): {stats.get('n_errors', '?')} from {stats.get('n_frames', '?')} "
         f"frame(s); coverage {_percent(stats.get('coverage'))}, bad-1px {_percent(stats.get('bad_1px'))}, "
         f"bad-2px {_percent(stats.get('bad_2px'))}, mean |e| {_decimal(stats.get('mean_abs_error_px'))} px; "
         f"histogram bin width {model.bin_width:g} px."),
        "",
        (f"Selected G = {model.selected_components} (marked *): " + _selection_rule(model.selection) + " "
         "AIC = 2k - 2 ln L and BIC = k ln N - 2 ln L with k = 3G - 1 (the thesis printed 2G as the AIC "
         f"penalty). Rows with G > 3 list only components with weight > {TABLE_MIN_WEIGHT}, as in the thesis."),
        "",
    ]
    shown = []
    for fit in model.fits:
        components = _components(fit.mixture)
        if fit.n_components > 3:
            components = [c for c in components if c[2] > TABLE_MIN_WEIGHT]
        shown.append((fit, components))
    width = max(len(components) for _, components in shown)
    header = ["G", "AIC", "BIC"] + [f"{s}{j + 1}" for j in range(width) for s in ("µ", "σ", "w")]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    notes = []
    for fit, components in shown:
        mark = "*" if fit.n_components == model.selected_components else ""
        cells = [f"{fit.n_components}{mark}", f"{fit.aic:.6g}", f"{fit.bic:.6g}"]
        for mu, sigma, weight in components:
            cells += [f"{mu:.2f}", f"{sigma:.2f}", f"{weight:.2f}"]
        cells += [""] * (len(header) - len(cells))
        lines.append("| " + " | ".join(cells) + " |")
        hidden = fit.n_components - len(components)
        if hidden:
            rest = 1.0 - sum(c[2] for c in components)
            notes.append(f"G = {fit.n_components}: {hidden} component(s) with weight <= {TABLE_MIN_WEIGHT} "
                         f"(together {rest:.2f}) not shown.")
    return "\n".join(lines + ([""] + notes if notes else []) + _class_lines(model)) + "\n"


def _selection_rule(selection):
    """How G was selected, in words."""
    if selection.get("criterion") == HELD_OUT:
        return (f"the G with the highest log-likelihood of held-out errors ({selection.get('held_out', '?')}), "
                "as for each class.")
    return (f"the smallest G whose {selection.get('criterion', 'bic').upper()} is within "
            f"{selection.get('tolerance_nats_per_error', 0)} nats per error of the best.")


def _class_lines(model):
    """The per-class view: bounds, share, bad pixels and the selected mixture of each class."""
    record = model.class_selection
    lines = []
    if record:
        lines += ["", "## Error classes", "",
                  (f"Chosen by held-out log-likelihood ({record.get('held_out', '?')}): plain "
                   f"{_decimal(record.get('plain_nats_per_error'))} nats per error, chosen classes "
                   f"{_decimal(record.get('conditioned_nats_per_error'))} nats per error over "
                   f"{record.get('n_held_out_errors', '?')} held-out errors.")]
    if not model.conditioned:
        return lines + (["", "The plain model predicts held-out errors best: one class."] if record else [])
    units = {name: FEATURE_UNITS[name] for name in model.classes.features}
    lines += ["", "Features: " + ", ".join(f"{name} ({unit})" for name, unit in units.items()) + "."
              + (" G \"+ 1\": the whole-image mixture's widest component mixed in with weight w."
                 if any(m.outlier is not None for m in model.class_models) else ""), ""]
    width = max(m.mixture.n_components for m in model.class_models)
    header = ["class", "bounds", "share", "bad-2px", "G"] + [f"{s}{j + 1}" for j in range(width) for s in ("µ", "σ", "w")]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for k, class_model in enumerate(model.class_models):
        cells = [str(k), _describe(model.classes, k), _percent(class_model.share),
                 _percent(class_model.statistics.get("bad_2px")),
                 str(class_model.selected_components)
                 + ("" if class_model.outlier is None else f" + 1 (w {class_model.outlier['weight']:.1e})")]
        for mu, sigma, weight in _components(class_model.mixture):
            cells += [f"{mu:.2f}", f"{sigma:.2f}", f"{weight:.2f}"]
        cells += [""] * (len(header) - len(cells))
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _components(mixture):
    order = sorted(range(mixture.n_components), key=lambda j: -mixture.weights[j])
    return [(mixture.means[j], mixture.sigmas[j], mixture.weights[j]) for j in order]


def _percent(value):
    return "?" if value is None else f"{100 * value:.1f} %"


def _decimal(value):
    return "?" if value is None else f"{value:.3f}"
