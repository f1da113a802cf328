"""The error-model file: fitted mixtures of one matcher's errors, per class of pixels, and how they were made.

Format (JSON, ``format_version`` 3)::

    {"format": "prismap-error-model", "format_version": 3,
     "matcher": {"name": "sgbm", "params": {...}}, "dataset": "middlebury-motorcycle",
     "bin_width_px": 0.03125,
     "statistics": {"n_frames", "n_errors", "n_gt_valid", "n_outside_bins", "coverage", "bad_1px",
                    "bad_2px", "mean_abs_error_px"},
     "selection": {"criterion": "bic", "tolerance_nats_per_error": 0.01},  # or {"criterion": "held-out", "held_out": ...}
     "selected_components": 2,
     "models": [{"n_components": 1, "weights": [...], "means": [...], "sigmas": [...],
                 "failure_weight": 0.004, "search_range_px": [0.0, 96.0],
                 "log_likelihood": ..., "aic": ..., "bic": ..., "n_samples": ..., "n_iter": ...,
                 "converged": true}, ...],
     "features": {"names": ["edge_distance_px"], "units": {"edge_distance_px": "px"},
                  "edge_threshold_px": 1.0, "texture_window_px": 7},
     "classes": [{"bounds": {"edge_distance_px": [null, 2.0]}, "share": 0.12, "statistics": {...},
                  "selected_components": 3, "models": [...as above...],
                  "outlier": {"weight": 1e-4, "mean": 6.8, "sigma": 15.6}}, ...],
     "class_selection": {"held_out": "...", "plain_nats_per_error": ..., "conditioned_nats_per_error": ...,
                         "candidates": [...]},
     "source": "ground-truth",  # or "lidar", "self": what the errors were measured against
     "rig": {"focal_px": 721.5, "baseline_m": 0.54, "width": 1242, "height": 375, "matcher": "sgbm",
             "matcher_params": {...}},  # or null: the rig it was made on (see characterise/_rig.py)
     "provenance": {...},  # how a self-characterised model was made (min_lag, references, ...)
     "fusion": {"model": "persistent-failure", "rate": ..., "persistence": ..., ...}}  # optional

The top-level ``models`` / ``selected_components`` are the whole-image (plain) mixture: what version 1 held,
what a plain sensor model uses, and the model of pixels outside every class (class -1). ``classes`` tile
the space of the named features (see :class:`~prismap.characterise.ErrorClasses`; ``null`` is an infinite
bound); each has its own fits over G, selected G, and share of the characterised pixels, and optionally an
outlier component (the whole-image mixture's widest) mixed into its selected mixture with the given weight,
so no class is certain never to fail grossly (:func:`prismap.gmm.fit_outlier_weight`). A model without
features has one class equal to the plain model. A version-1 file loads as that one class. The optional
``fusion`` block says how the matcher's failures repeat across views (:mod:`prismap.characterise._fusion`);
without it maps fuse frames independently.

Version 3 gives every mixture the matcher-failure component (:class:`prismap.gmm.GaussianMixture`):
``failure_weight`` ``w_f`` and the matcher's ``search_range_px`` over which failures are uniform; its classes
need no ``outlier`` then (docs/SENSOR_MODELS.md section 8). Files of versions 1 and 2 have no failure
component and map exactly as they did; a failure component in them is refused.

Means and sigmas are pixels; AIC and BIC use ``k = 3G - 1``, ``3G`` with a failure component (see
:class:`prismap.gmm.MixtureFit`). ``source``, ``rig`` and ``provenance`` are optional (a file without them was
measured against ground truth on an unrecorded rig).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from prismap._files import write_text_atomic
from prismap.characterise._class_model import ClassModel, _describe, _find_fit
from prismap.characterise._classes import ErrorClasses
from prismap.characterise._features import FEATURE_UNITS, LR_FEATURE, PixelFeatures, compute_features
from prismap.characterise._fusion import fusion_from_block
from prismap.characterise._model_json import (
    MAX_COMPONENTS,
    _classes_from_dict,
    _fits_from_list,
    _fits_to_list,
    _integer,
    _number,
    _object,
    _provenance_from_dict,
    _require,
    error_bound_px,
)
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture, MixtureFit
from prismap.grid import PersistentFailure
from prismap.io._text import read_text
from prismap.stereo._base import to_grey

FORMAT = "prismap-error-model"


FORMAT_VERSION = 3


READABLE_VERSIONS = (1, 2, 3)


_SHARE_TOLERANCE = 1e-6


SOURCES = ("ground-truth", "lidar", "self")
"""What an error model's errors were measured against: exact disparity, a LiDAR's, or the sequence's own frames."""


HELD_OUT = "held-out"
"""``selection["criterion"]`` of a conditioned characterisation: every G (the whole image's and each class's)
chosen by the log-likelihood of held-out errors, as the classes are (:func:`prismap.characterise.choose_classes`)."""


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
    source : str
        One of :data:`SOURCES`.
    rig : dict or None
        The rig it was made on (:func:`prismap.characterise.describe_rig`); None = not recorded.
    provenance : dict
        How it was made beyond the fields above (a self-characterisation's record).
    fusion : dict or None
        The fusion block (:func:`prismap.characterise.fit_fusion`): how the matcher's failures repeat across
        views; None = not measured (independent fusion).
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
    source: str = "ground-truth"
    rig: dict | None = None
    provenance: dict = field(default_factory=dict)
    fusion: dict | None = None

    def __post_init__(self):
        if self.source not in SOURCES:
            raise PrismapInputError(f"error model `source` must be one of {list(SOURCES)}; got {self.source!r}")
        fusion_from_block(self.fusion)
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

    def fit(self, n_components: int) -> MixtureFit:
        """The whole-image :class:`MixtureFit` with ``n_components`` components."""
        return _find_fit(self.fits, n_components)

    @property
    def mixture(self) -> GaussianMixture:
        """The selected whole-image :class:`GaussianMixture` (pixels): what the plain sensor models use."""
        return self.fit(self.selected_components).mixture

    @property
    def n_classes(self) -> int:
        """Number of error classes (1 for a plain model)."""
        return self.classes.n_classes

    @property
    def conditioned(self) -> bool:
        """Whether the classes split pixels by features (False: one class, the plain model)."""
        return bool(self.classes.features)

    @property
    def class_mixtures(self) -> tuple[GaussianMixture, ...]:
        """The selected mixture of each class, in class order: tuple of GaussianMixture (pixels)."""
        return tuple(model.mixture for model in self.class_models)

    def check_usable(self, matcher: str, *, left_right_check: bool) -> None:
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

    def classify(self, features: PixelFeatures) -> npt.NDArray[np.int32]:
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

    def classify_frame(
        self,
        left: np.ndarray,
        right: np.ndarray,
        disparity: npt.ArrayLike,
        lr_disagreement: npt.ArrayLike | None = None,
    ) -> npt.NDArray[np.int32]:
        """Class of each pixel of a stereo frame: the features its classes use (this model's
        :attr:`feature_settings`) from the images and the computed disparity, then :meth:`classify`.

        Parameters
        ----------
        left, right : (H, W) or (H, W, 3) uint8, the rectified images
        disparity : (H, W) float, pixels, NaN = invalid; the matcher's output
        lr_disagreement : (H, W) float, pixels, or None; the matcher's left-right disagreement

        Returns
        -------
        (H, W) int32, as :meth:`classify`.
        """
        features = compute_features(
            to_grey(left),
            to_grey(right),
            disparity,
            lr_disagreement,
            names=self.classes.features,
            **self.feature_settings,
        )  # only what the classes use
        return self.classify(features)

    def to_dict(self) -> dict[str, Any]:
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
            "features": {
                "names": list(self.classes.features),
                "units": {name: FEATURE_UNITS[name] for name in self.classes.features},
                **self.feature_settings,
            },
            "classes": [
                {
                    "bounds": bounds,
                    "share": model.share,
                    "statistics": model.statistics,
                    "selected_components": model.selected_components,
                    "models": _fits_to_list(model.fits),
                    **({} if model.outlier is None else {"outlier": model.outlier}),
                }
                for bounds, model in zip(self.classes.to_list(), self.class_models)
            ],
            "class_selection": self.class_selection,
            "source": self.source,
            "rig": self.rig,
            "provenance": self.provenance,
            **({} if self.fusion is None else {"fusion": self.fusion}),
        }

    @property
    def persistent_failure(self) -> PersistentFailure | None:
        """The :class:`prismap.grid.PersistentFailure` of the fusion block, or None (independent fusion)."""
        return fusion_from_block(self.fusion)

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, source: str = "error model") -> ErrorModel:
        """Inverse of :meth:`to_dict` (also reads format versions 1 and 2); ``source`` starts every error message."""
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
        extra = _provenance_from_dict(data, source)
        bound_px = error_bound_px(params, (extra.get("rig") or {}).get("width"))
        fits = _fits_from_list(data["models"], f"{source}: models", bound_px)
        selection = _object(data.get("selection", {}), f"{source}: `selection`")
        statistics = _object(data.get("statistics", {}), f"{source}: `statistics`")
        if version >= 2:
            extra.update(_classes_from_dict(data, source, bound_px))
        mixtures = [fit.mixture for fit in fits] + [
            fit.mixture for model in extra.get("class_models", ()) for fit in model.fits
        ]
        if version < 3 and any(mixture.search_range_px is not None for mixture in mixtures):
            raise PrismapInputError(
                f"{source}: a failure component (`failure_weight`, `search_range_px`) needs "
                f"format_version 3; this file says {version}"
            )
        if data.get("fusion") is not None:
            fusion_from_block(data["fusion"], source=source)
            extra["fusion"] = dict(data["fusion"])
        try:
            return cls(
                matcher["name"],
                dict(params),
                data["dataset"],
                bin_width,
                fits,
                selected,
                selection,
                statistics,
                **extra,
            )
        except PrismapInputError as exc:
            raise PrismapInputError(f"{source}: {exc}") from None


def write_error_model(model: ErrorModel, path: str | os.PathLike[str]) -> None:
    """Write ``model`` as JSON to ``path`` atomically (the file appears whole or not at all)."""
    write_text_atomic(path, json.dumps(model.to_dict(), indent=2, default=_plain) + "\n")


def _plain(value):
    """numpy scalars and arrays in matcher parameters become plain JSON numbers and lists."""
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"cannot write {type(value).__name__} to an error model")


def load_error_model(path: str | os.PathLike[str]) -> ErrorModel:
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
        data = json.loads(read_text(path, "error model"))
    except RecursionError:
        raise PrismapInputError(f"error model {path}: JSON nested too deeply to be an error model") from None
    except (UnicodeDecodeError, ValueError) as exc:  # JSONDecodeError, and integers too long to convert
        raise PrismapInputError(f"error model {path}: not valid JSON ({str(exc)[:120]})") from None
    return ErrorModel.from_dict(data, source=f"error model {path}")
