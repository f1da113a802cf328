"""What a mapping run is: one frozen configuration, and the sensor model it builds for a camera."""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prismap._validate import check_integer, check_positive, check_probability
from prismap.camera import StereoCamera
from prismap.characterise import ErrorModel, map_reading
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.grid import FLOOR_RAYS, MAP_READINGS, POLICIES, MapReading
from prismap.grid._floor_sampling import check_floor_rays
from prismap.sensor_models import (
    InverseSensorModel,
    conditioned_sensor_model,
    error_model_use,
    model_defaults,
    model_for_mixture,
    model_names,
)
from prismap.stereo import matcher_names

MODES = ("ray", "projective")
DISPARITY_FROM_MATCHER = "matcher"
DISPARITY_FROM_SEQUENCE = "sequence"
"""Models parametrised by one disparity noise ``sigma_px``: taken from the error model unless given."""
RESERVED_MODEL_PARAMS = {
    "voxel_size_m": "the map's voxel size (--voxel)",
    "p0": "the map's prior (--p0)",
    "error_model": "--error-model",
    "focal_baseline": "the camera",
    "doffs_px": "the camera",
    "measurement": "the camera (disparities)",
}
"""Sensor model arguments the run sets itself, with where they come from; a model parameter may not set them."""


def _check_model_params(params, option):
    reserved = sorted(set(params) & set(RESERVED_MODEL_PARAMS))
    if reserved:
        name = reserved[0]
        raise PrismapInputError(
            f"{option} {name}: cannot be set as a model parameter; it comes from {RESERVED_MODEL_PARAMS[name]}"
        )


def _as_mixture(error_model):
    if error_model is None or isinstance(error_model, GaussianMixture):
        return error_model
    mixture = getattr(error_model, "mixture", None)
    if isinstance(mixture, GaussianMixture):
        return mixture
    raise PrismapInputError(
        f"`error_model` must be a GaussianMixture or an error model with `.mixture`; got {type(error_model).__name__}"
    )


def _check_error_model(error_model):
    """``error_model`` unchanged if it is None, a GaussianMixture or an :class:`ErrorModel`; else raise."""
    if error_model is None or isinstance(error_model, (GaussianMixture, ErrorModel)):
        return error_model
    raise PrismapInputError(
        f"`error_model` must be an ErrorModel, a GaussianMixture or None; got {type(error_model).__name__}"
    )


def needs_error_model(name, params):
    """Whether the sensor model ``name`` with its ``params`` needs a matcher's error model: PRISM always,
    convolution and Andert unless ``params`` give ``sigma_px`` (each model's ``error_model_use``)."""
    use = error_model_use(name)
    return use == "mixture" or (use == "sigma" and "sigma_px" not in params)


def build_sensor_model(
    name: str,
    camera: StereoCamera,
    *,
    voxel_size_m: float,
    p0: float,
    error_model: ErrorModel | GaussianMixture | None = None,
    **params: Any,
) -> InverseSensorModel:
    """The inverse sensor model ``name`` for ``camera`` on a map of ``voxel_size_m`` and prior ``p0``.

    Parameters
    ----------
    name : str
        A name of :func:`prismap.sensor_models.model_names` (``ideal``, ``hitmiss``, ``convolution``,
        ``andert``, ``prism``).
    camera : StereoCamera
        Supplies ``focal_baseline`` (pixel-metres) and ``doffs_px``.
    voxel_size_m : float, metres
    p0 : float in (0, 1)
        Prior occupancy; must equal the map's.
    error_model : GaussianMixture or object with ``.mixture`` or None
        The matcher's disparity error ``e = d_true - d_computed`` (pixels). ``prism`` uses the whole
        mixture; ``convolution`` and ``andert`` its dominant sigma (:meth:`GaussianMixture.dominant_sigma`)
        unless ``sigma_px`` is in ``params``; ``ideal`` and ``hitmiss`` ignore it (see
        :func:`prismap.sensor_models.model_for_mixture`, which builds the model).
    **params
        The model's own parameters (e.g. ``p_hit``, ``eta``, ``near_m``).

    Returns
    -------
    InverseSensorModel
    """
    if name not in model_names():
        raise PrismapInputError(f"unknown sensor model {name!r}; expected one of {list(model_names())}")
    mixture = _as_mixture(error_model)
    params = dict(params)
    _check_model_params(params, "model parameter")
    if mixture is None and needs_error_model(name, params):
        raise PrismapInputError(
            f"sensor model {name!r} needs an error model (`error_model`)"
            + (" or an explicit sigma_px" if error_model_use(name) == "sigma" else "")
        )
    return model_for_mixture(
        name,
        mixture,
        focal_baseline=camera.focal_baseline,
        doffs_px=camera.doffs_px,
        voxel_size_m=voxel_size_m,
        p0=p0,
        **params,
    )


def _frozen_params(value, name):
    """A mapping as a sorted tuple of (key, value) pairs: hashable, picklable, order-free."""
    if value is None:
        return ()
    items = value.items() if isinstance(value, dict) else value
    try:
        pairs = tuple(sorted((str(k), v) for k, v in items))
    except (TypeError, ValueError):
        raise PrismapInputError(f"`{name}` must be a mapping of parameter names to values; got {value!r}") from None
    return pairs


def default_fusion(model: str, error_model: ErrorModel | GaussianMixture | None) -> str:
    """``MappingConfig.fusion``'s default: ``"failure-mixture"`` when ``model`` takes the error model and that has a
    fusion block (the matcher's failure rate), else ``"independent"``."""
    takes_it = getattr(error_model, "fusion", None) is not None and error_model_use(model) is not None
    return MAP_READINGS[0] if takes_it else "independent"


@dataclass(frozen=True, eq=False)
class MappingConfig:
    """Everything that decides a map, apart from the input sequence.

    Parameters
    ----------
    model : str
        Inverse sensor model name (see :func:`build_sensor_model`).
    voxel_size_m : float, metres, > 0
    p0 : float in (0, 1)
        Prior occupancy of a voxel (the scene's occupancy ratio at this voxel size).
    error_model : ErrorModel or GaussianMixture or None
        The matcher's disparity error model, pixels (needed by ``prism``, and by ``convolution`` and
        ``andert`` without an explicit ``sigma_px``). A GaussianMixture is a plain model.
    conditioned : bool or None
        Give each pixel the error mixture of its class (:meth:`ErrorModel.classify` of its confidence
        features, computed per frame) instead of the whole-image mixture. None = True when the error
        model has more than one class. True needs such a model; it changes only the models that use
        the error model (``prism``, ``convolution``, ``andert``).
    model_params : dict
        Extra parameters of the sensor model.
    matcher : str
        Stereo matcher name (:func:`prismap.stereo.make_matcher`), used when ``disparity_source`` is
        ``"matcher"``.
    matcher_params : dict
        Its parameters (e.g. ``num_disparities``).
    disparity_source : str
        ``"matcher"`` (match the sequence's images), ``"sequence"`` (the sequence's own ``disp/``) or
        the path of a directory of uint16 PNG disparities (value / 256 = pixels, 0 = invalid) named like
        the sequence's images.
    mode : {"ray", "projective"}
    policy : str or None
        Per-frame policy; None = the model's default.
    max_range_m : float, metres
        Distance along a ray beyond which nothing is updated (inf = no limit).
    subsample : int >= 1
        Use every ``subsample``-th pixel in both directions.
    floor_rays : int >= 0
        Ray mode: rays a voxel each way, at least, that cast the cells at their ray's failure floor (the others skip
        them; :meth:`prismap.grid.OccupancyMap.integrate`); 0 = every ray casts every cell.
    frames : (int, int or None)
        ``(start, stop)``: the frames ``start <= i < stop`` of the sequence (stop None or beyond the
        sequence = to its end).
    fusion : {"failure-mixture", "failure-clamp", "persistent-failure", "independent"} or None
        How the map reads its stored sums (:func:`prismap.characterise.map_reading`; docs/SENSOR_MODELS.md
        section 9): averaged with ``p0`` by the matcher's failure rate or clamped to its one-view bound, under its
        persistent failure state, or as the independent sum of the frames' evidence. The first three need the
        error model's ``fusion`` block (:func:`prismap.characterise.fit_fusion`). None (the default) is
        ``"failure-mixture"`` when the model takes the error model and that has a fusion block, else
        ``"independent"``. The stored map is the same.

    Notes
    -----
    Mappings are stored as sorted ``(key, value)`` tuples, so a config is picklable (Dask ships it to
    workers); :attr:`model_options` and :attr:`matcher_options` give them as dicts. Configs compare and
    hash by :meth:`fingerprint` (the error model by value).
    """

    model: str = "prism"
    voxel_size_m: float = 0.1
    p0: float = 0.05
    error_model: ErrorModel | GaussianMixture | None = None
    conditioned: bool | None = None
    model_params: tuple = ()
    matcher: str = "sgbm"
    matcher_params: tuple = ()
    disparity_source: str = DISPARITY_FROM_MATCHER
    mode: str = "ray"
    policy: str | None = None
    max_range_m: float = math.inf
    subsample: int = 1
    floor_rays: int = FLOOR_RAYS
    frames: tuple = (0, None)
    fusion: str | None = None

    def __post_init__(self):
        def set_(name, value):
            object.__setattr__(self, name, value)

        if self.model not in model_names():
            raise PrismapInputError(f"unknown sensor model {self.model!r}; expected one of {list(model_names())}")
        if self.matcher not in matcher_names():
            raise PrismapInputError(f"unknown matcher {self.matcher!r}; expected one of {list(matcher_names())}")
        set_("voxel_size_m", check_positive(self.voxel_size_m, "voxel_size_m"))
        set_("p0", check_probability(self.p0, "p0"))
        set_("error_model", _check_error_model(self.error_model))
        set_("conditioned", _check_conditioned(self.conditioned, self.error_model))
        set_("model_params", _frozen_params(self.model_params, "model_params"))
        _check_model_params(dict(self.model_params), "model_params")
        set_("matcher_params", _frozen_params(self.matcher_params, "matcher_params"))
        if not isinstance(self.disparity_source, str) or not self.disparity_source:
            raise PrismapInputError(
                f"`disparity_source` must be 'matcher', 'sequence' or a directory; got {self.disparity_source!r}"
            )
        if self.mode not in MODES:
            raise PrismapInputError(f"`mode` must be one of {list(MODES)}; got {self.mode!r}")
        if self.policy is not None and self.policy not in POLICIES:
            raise PrismapInputError(f"`policy` must be one of {list(POLICIES)} or None; got {self.policy!r}")
        max_range = float(self.max_range_m)
        set_("max_range_m", max_range if max_range == math.inf else check_positive(max_range, "max_range_m"))
        set_(
            "subsample",
            check_integer(self.subsample, "subsample", expected="an integer >= 1", condition=lambda n: n >= 1),
        )
        set_("floor_rays", check_floor_rays(self.floor_rays))
        set_("frames", _check_frames(self.frames))
        block = getattr(self.error_model, "fusion", None)
        if self.fusion is None:
            set_("fusion", default_fusion(self.model, self.error_model))
        if self.fusion not in MAP_READINGS:
            raise PrismapInputError(f"`fusion` must be one of {list(MAP_READINGS)}; got {self.fusion!r}")
        if self.fusion != "independent" and block is None:
            raise PrismapInputError(
                f"`fusion` {self.fusion!r} needs an error model with a fusion block (characterised "
                "on frames with poses; see prismap.characterise.fit_fusion)"
            )

    @property
    def map_reading(self) -> MapReading | None:
        """How the map reads its sums (:class:`~prismap.grid.MapReading`), or None (the independent sum)."""
        return map_reading(getattr(self.error_model, "fusion", None), self.fusion)

    @property
    def model_options(self) -> dict[str, Any]:
        """Sensor model parameters as a dict."""
        return dict(self.model_params)

    @property
    def matcher_options(self) -> dict[str, Any]:
        """Matcher parameters as a dict."""
        return dict(self.matcher_params)

    @property
    def mixture(self) -> GaussianMixture | None:
        """The whole-image error mixture (GaussianMixture, pixels) or None: what a plain model uses."""
        return _as_mixture(self.error_model)

    def sensor_model(self, camera: StereoCamera) -> InverseSensorModel:
        """The configured sensor model for ``camera``: :func:`build_sensor_model` when plain, else
        :func:`prismap.sensor_models.conditioned_sensor_model`: a ConditionedModel for the models that use the
        error model, whose rays then need ``ray_class``; the plain model for ``ideal`` and ``hitmiss``."""
        if self.conditioned:
            return conditioned_sensor_model(
                self.model,
                camera,
                voxel_size_m=self.voxel_size_m,
                p0=self.p0,
                error_model=self.error_model,
                **self.model_options,
            )
        return build_sensor_model(
            self.model,
            camera,
            voxel_size_m=self.voxel_size_m,
            p0=self.p0,
            error_model=self.mixture,
            **self.model_options,
        )

    @property
    def label(self) -> str:
        """What the run maps with, for progress lines: model, variant, disparities, e.g.
        ``"prism conditioned, sgbm"`` or ``"hit_miss, disparities from sgbm/disparity"``.

        The variant (``plain``: the whole-image mixture; ``conditioned``: each pixel's class mixture) is
        named when the model uses the run's error model (``prism``, ``convolution``, ``andert``).
        """
        uses_error_model = self.error_model is not None and error_model_use(self.model) is not None
        variant = (" conditioned" if self.conditioned else " plain") if uses_error_model else ""
        if self.disparity_source == DISPARITY_FROM_MATCHER:
            source = self.matcher
        elif self.disparity_source == DISPARITY_FROM_SEQUENCE:
            source = "the sequence's disparities"
        else:
            folder = Path(self.disparity_source)
            source = f"disparities from {folder.parent.name}/{folder.name}"
        return f"{self.model}{variant}, {source}"

    def frame_indices(self, n_frames: int) -> range:
        """``range`` of the frames of a sequence of ``n_frames`` this config maps; raises if empty."""
        start, stop = self.frames
        stop = n_frames if stop is None else min(stop, n_frames)
        if start >= stop:
            raise PrismapInputError(
                f"frames {start}:{'' if self.frames[1] is None else self.frames[1]} select no frame "
                f"of a sequence of {n_frames} frames"
            )
        return range(start, stop)

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form: the error model as its weights, means and sigmas, with its classes when they are used.

        A plain run records only the whole-image mixture, so it fingerprints the same whether it was
        given that mixture or the whole error model. ``model_params`` holds the model's defaults
        (:func:`prismap.sensor_models.model_defaults`, without what the run sets) under the given ones,
        so a checkpoint of an older default is not resumed with a newer one.
        """
        error_model = self.error_model if self.conditioned else self.mixture
        defaults = {k: v for k, v in model_defaults(self.model).items() if k not in RESERVED_MODEL_PARAMS}
        return {
            "model": self.model,
            "model_params": {**defaults, **self.model_options},
            "conditioned": self.conditioned,
            "error_model": None if error_model is None else error_model.to_dict(),
            "voxel_size_m": self.voxel_size_m,
            "p0": self.p0,
            "matcher": self.matcher,
            "matcher_params": self.matcher_options,
            "disparity_source": self.disparity_source,
            "mode": self.mode,
            "policy": self.policy,
            "max_range_m": None if math.isinf(self.max_range_m) else self.max_range_m,
            "subsample": self.subsample,
            **({"floor_rays": self.floor_rays} if self.mode == "ray" else {}),
            "frames": list(self.frames),
            **({} if self.fusion == "independent" else {"fusion": {"reading": self.fusion, **self.error_model.fusion}}),
        }

    def fingerprint(self) -> str:
        """SHA-256 (hex) of :meth:`to_dict`: equal configs give equal fingerprints."""
        text = json.dumps(self.to_dict(), sort_keys=True, default=repr)
        return hashlib.sha256(text.encode("utf-8")).hexdigest()

    def __eq__(self, other):
        return isinstance(other, MappingConfig) and self.fingerprint() == other.fingerprint()

    def __hash__(self):
        return hash(self.fingerprint())


def _check_conditioned(conditioned, error_model):
    """The ``conditioned`` flag resolved against the error model (None = whether it has classes)."""
    has_classes = isinstance(error_model, ErrorModel) and error_model.n_classes > 1
    if conditioned is None:
        return has_classes
    if not isinstance(conditioned, (bool, np.bool_)):
        raise PrismapInputError(f"`conditioned` must be True, False or None; got {conditioned!r}")
    if conditioned and not has_classes:
        raise PrismapInputError(
            "`conditioned` needs an error model with more than one class (prismap characterise, conditioned); "
            f"this one has {error_model.n_classes if isinstance(error_model, ErrorModel) else 'no'} classes"
        )
    return bool(conditioned)


def _check_frames(frames):
    try:
        start, stop = frames
    except (TypeError, ValueError):
        raise PrismapInputError(f"`frames` must be (start, stop); got {frames!r}") from None
    for value in (start, stop):
        if value is not None and (not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 0):
            raise PrismapInputError(f"`frames` must hold integers >= 0 (stop may be None); got {frames!r}")
    start = 0 if start is None else int(start)
    stop = None if stop is None else int(stop)
    if stop is not None and stop <= start:
        raise PrismapInputError(f"`frames` {start}:{stop} is empty: stop must exceed start")
    return (start, stop)
