"""The error-model file: fitted mixtures of one matcher's errors, the selected G, and how they were made.

Format (JSON, ``format_version`` 1)::

    {"format": "prismap-error-model", "format_version": 1,
     "matcher": {"name": "sgbm", "params": {...}}, "dataset": "middlebury-motorcycle",
     "bin_width_px": 0.03125,
     "statistics": {"n_frames", "n_errors", "n_gt_valid", "n_outside_bins", "coverage", "bad_1px",
                    "bad_2px", "mean_abs_error_px"},
     "selection": {"criterion": "bic", "tolerance_nats_per_error": 0.01},
     "selected_components": 2,
     "models": [{"n_components": 1, "weights": [...], "means": [...], "sigmas": [...],
                 "log_likelihood": ..., "aic": ..., "bic": ..., "n_samples": ..., "n_iter": ...,
                 "converged": true}, ...]}

Means and sigmas are pixels; AIC and BIC use ``k = 3G - 1`` (see :class:`prismap.gmm.MixtureFit`).
"""

import json
from dataclasses import dataclass, field
from pathlib import Path

from prismap._files import write_text_atomic
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture, MixtureFit

FORMAT = "prismap-error-model"
FORMAT_VERSION = 1
TABLE_MIN_WEIGHT = 0.1
_FIT_FIELDS = ("log_likelihood", "aic", "bic", "n_samples", "n_iter", "converged")


@dataclass(frozen=True)
class ErrorModel:
    """A matcher's characterised disparity error: mixtures for G = 1..Gmax and the selected G.

    Attributes
    ----------
    matcher : str
    matcher_params : dict
    dataset : str
    bin_width : float, pixels
        Bin width of the fitted histogram.
    fits : tuple of MixtureFit
        One per G, ascending.
    selected_components : int
    selection : dict
        How G was selected: ``{"criterion": ..., "tolerance_nats_per_error": ...}``.
    statistics : dict
        Coverage, bad-pixel rates, mean absolute error, counts (see ``ErrorHistogram.statistics``).
    """

    matcher: str
    matcher_params: dict
    dataset: str
    bin_width: float
    fits: tuple
    selected_components: int
    selection: dict = field(default_factory=dict)
    statistics: dict = field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "fits", tuple(sorted(self.fits, key=lambda fit: fit.n_components)))
        self.fit(self.selected_components)

    def fit(self, n_components):
        """The :class:`MixtureFit` with ``n_components`` components."""
        for fit in self.fits:
            if fit.n_components == n_components:
                return fit
        raise PrismapInputError(
            f"error model has no {n_components}-component fit; it has G = {[f.n_components for f in self.fits]}"
        )

    @property
    def mixture(self):
        """The selected :class:`GaussianMixture` (pixels): what the sensor models use."""
        return self.fit(self.selected_components).mixture

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
            "models": [
                {"n_components": fit.n_components, **fit.mixture.to_dict(), **{k: getattr(fit, k) for k in _FIT_FIELDS}}
                for fit in self.fits
            ],
        }

    @classmethod
    def from_dict(cls, data, *, source="error model"):
        """Inverse of :meth:`to_dict`; ``source`` (a file name) starts every error message."""
        if not isinstance(data, dict):
            raise PrismapInputError(f"{source}: expected a JSON object; got {type(data).__name__}")
        if data.get("format") != FORMAT:
            raise PrismapInputError(f"{source}: not a prismap error model (field `format` is {data.get('format')!r})")
        if data.get("format_version") != FORMAT_VERSION:
            raise PrismapInputError(
                f"{source}: unsupported format_version {data.get('format_version')!r}; expected {FORMAT_VERSION}"
            )
        _require(data, ("matcher", "dataset", "bin_width_px", "selected_components", "models"), source)
        matcher = data["matcher"]
        if not isinstance(matcher, dict) or "name" not in matcher:
            raise PrismapInputError(f"{source}: field `matcher` must be an object with a `name`")
        if not isinstance(data["models"], list) or not data["models"]:
            raise PrismapInputError(f"{source}: field `models` must be a non-empty list")
        fits = []
        for index, entry in enumerate(data["models"]):
            where = f"{source}: models[{index}]"
            _require(entry, _FIT_FIELDS, where)
            mixture = GaussianMixture.from_dict(entry, source=where)
            try:
                fits.append(
                    MixtureFit(mixture, float(entry["log_likelihood"]), float(entry["aic"]), float(entry["bic"]),
                               float(entry["n_samples"]), int(entry["n_iter"]), bool(entry["converged"]))
                )
            except (TypeError, ValueError) as exc:
                raise PrismapInputError(f"{where}: a number field does not parse ({exc})") from None
        try:
            selected = int(data["selected_components"])
            bin_width = float(data["bin_width_px"])
        except (TypeError, ValueError) as exc:
            raise PrismapInputError(f"{source}: `selected_components` / `bin_width_px` must be numbers ({exc})") from None
        try:
            return cls(str(matcher["name"]), dict(matcher.get("params", {})), str(data["dataset"]), bin_width, fits,
                       selected, dict(data.get("selection", {})), dict(data.get("statistics", {})))
        except PrismapInputError as exc:
            raise PrismapInputError(f"{source}: {exc}") from None


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
        For a missing file, invalid JSON, a wrong format or version, or missing fields.
    """
    path = Path(path)
    if not path.is_file():
        raise PrismapInputError(f"error model {path}: no such file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PrismapInputError(f"error model {path}: not valid JSON ({exc})") from None
    return ErrorModel.from_dict(data, source=f"error model {path}")


def format_table(model):
    """Markdown table of the fits in the layout of the thesis's tables 3.1-3.3.

    One row per G with AIC, BIC and ``mu, sigma, w`` per component, heaviest component first. Like the
    thesis, rows with more than three components list only the components with weight > 0.1 (the
    rest are summed in a note); the selected G is marked.
    """
    stats = model.statistics
    lines = [
        f"# Disparity error model: {model.matcher} on {model.dataset}",
        "",
        f"Errors e = d_true - d_computed (px): {stats.get('n_errors', '?')} from {stats.get('n_frames', '?')} "
        f"frame(s); coverage {_percent(stats.get('coverage'))}, bad-1px {_percent(stats.get('bad_1px'))}, "
        f"bad-2px {_percent(stats.get('bad_2px'))}, mean |e| {_number(stats.get('mean_abs_error_px'))} px; "
        f"histogram bin width {model.bin_width:g} px.",
        "",
        f"Selected G = {model.selected_components} (marked *): the smallest G whose "
        f"{model.selection.get('criterion', 'bic').upper()} is within "
        f"{model.selection.get('tolerance_nats_per_error', 0)} nats per error of the best. "
        "AIC = 2k - 2 ln L and BIC = k ln N - 2 ln L with k = 3G - 1 (the thesis printed 2G as the AIC "
        f"penalty). Rows with G > 3 list only components with weight > {TABLE_MIN_WEIGHT}, as in the thesis.",
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
    return "\n".join(lines + ([""] + notes if notes else [])) + "\n"


def _components(mixture):
    order = sorted(range(mixture.n_components), key=lambda j: -mixture.weights[j])
    return [(mixture.means[j], mixture.sigmas[j], mixture.weights[j]) for j in order]


def _percent(value):
    return "?" if value is None else f"{100 * value:.1f} %"


def _number(value):
    return "?" if value is None else f"{value:.3f}"
