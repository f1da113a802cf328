"""A sensor model conditioned on each pixel's error class: one sub-model per class of a conditioned error model.

A conditioned error model (:class:`prismap.characterise.ErrorModel` with classes) gives every pixel a class
from its confidence features and one error mixture per class. :class:`ConditionedModel` holds one
inverse sensor model per class (PRISM with that class's mixture, so tables per class, in one cache; Andert and
convolution with that class's dominant sigma) and the plain model of the whole-image mixture for pixels
without a class (``-1``). Each ray is handed to the sub-model of its class, so on those rays the result
is exactly that sub-model's. Ideal and hit/miss do not use the error model and are never wrapped.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.sensor_models._base import (
    InverseSensorModel,
    check_cell_arrays,
    error_model_use,
    make_sensor_model,
)
from prismap.sensor_models._failure import failure_floor
from prismap.sensor_models._kernel_args import cell_runs
from prismap.sensor_models._prism_classes import PrismClasses

CLASS_PASS_THROUGH = "class_pass_through"
"""PRISM parameter of a conditioned run: one ``pass_through`` per class (the plain sub-model keeps ``pass_through``)."""


class CameraRig(Protocol):
    """What a sensor model takes from a camera (:class:`prismap.camera.StereoCamera` has it; this package
    does not import the camera's)."""

    @property
    def focal_baseline(self) -> float:
        """``f * b``, pixel-metres."""
        ...

    @property
    def doffs_px(self) -> float:
        """Disparity offset, pixels."""
        ...


class ClassedErrors(Protocol):
    """What a sensor model takes from an error model (:class:`prismap.characterise.ErrorModel` has it)."""

    @property
    def mixture(self) -> GaussianMixture:
        """The whole image's error mixture."""
        ...

    @property
    def class_mixtures(self) -> tuple[GaussianMixture, ...]:
        """One error mixture per class."""
        ...


@dataclass(frozen=True, eq=False)
class ConditionedModel(InverseSensorModel):
    """Dispatch rays by class to one sub-model per class; class ``-1`` (and no classes) to ``plain``.

    Parameters
    ----------
    plain : InverseSensorModel
        The model of the whole-image mixture.
    class_models : tuple of InverseSensorModel
        One per class, of ``plain``'s type (same camera, voxel size and prior).

    PRISM sub-models share one table cache, within one budget (the plain model's: ``table_memory_mb``, or the
    automatic one over the classes' tables together), and take a frame's rays of every class in one call
    (:class:`~prismap.sensor_models._prism_classes.PrismClasses`).
    """

    plain: InverseSensorModel
    class_models: tuple
    _classes: PrismClasses | None = field(default=None, init=False, repr=False)

    def __post_init__(self):
        models = tuple(self.class_models)
        if not models:
            raise PrismapInputError("ConditionedModel needs at least one class model")
        for k, model in enumerate(models):
            if type(model) is not type(self.plain):
                raise PrismapInputError(
                    f"ConditionedModel: class model {k} is {type(model).__name__}; expected {type(self.plain).__name__}"
                )
            shared = ("focal_baseline", "doffs_px", "voxel_size_m", "p0")
            if any(getattr(model, name, None) != getattr(self.plain, name, None) for name in shared):
                raise PrismapInputError(f"ConditionedModel: class model {k} differs from the plain model in {shared}")
        object.__setattr__(self, "class_models", models)
        object.__setattr__(self, "_classes", PrismClasses.of((self.plain, *models)))

    @property
    def name(self) -> str:
        """The sub-models' name (``prism``, ``andert``, ``convolution``)."""
        return self.plain.name

    @property
    def default_policy(self) -> str:
        """The sub-models' per-frame policy."""
        return self.plain.default_policy

    @property
    def takes_voxel_overhang(self) -> bool:
        """The sub-models' (PRISM's with ``overhang_fraction > 0``)."""
        return self.plain.takes_voxel_overhang

    @property
    def takes_map_prior(self) -> bool:
        """The sub-models' (PRISM's with ``prior="map"``)."""
        return self.plain.takes_map_prior

    @property
    def far_depth_m(self) -> float:
        """The farthest depth (metres) any sub-model reasons to; AttributeError for models without one (not PRISM)."""
        return max(model.far_depth_m for model in (self.plain, *self.class_models))

    @property
    def n_classes(self) -> int:
        """Number of classes (the plain model not counted)."""
        return len(self.class_models)

    def _model(self, k):
        return self.plain if k < 0 else self.class_models[k]

    def _check_classes(self, ray_class, n_rays):
        classes = np.asarray(ray_class)
        if classes.shape != (n_rays,) or not (np.issubdtype(classes.dtype, np.integer) or classes.size == 0):
            raise PrismapInputError(
                f"`ray_class` must be ({n_rays},) integers; got shape {classes.shape}, dtype {classes.dtype}"
            )
        if classes.size and (classes.min() < -1 or classes.max() >= self.n_classes):
            raise PrismapInputError(
                f"`ray_class` must lie in [-1, {self.n_classes - 1}]; got values in [{classes.min()}, {classes.max()}]"
            )
        return classes.astype(np.int64)

    def _class_rays(self, disparity_px, ray_norm, ray_class):
        """The rays' disparities and norms ((R,) float64) and classes ((R,) int64), checked."""
        disparity = np.asarray(disparity_px, dtype=np.float64)
        norm = np.asarray(ray_norm, dtype=np.float64)
        if disparity.ndim != 1 or norm.shape != disparity.shape:
            raise PrismapInputError(
                f"`disparity_px` and `ray_norm` must be 1-D of one length; got {disparity.shape} and {norm.shape}"
            )
        return disparity, norm, self._check_classes(ray_class, disparity.size)

    def cell_posteriors(
        self,
        disparity_px: npt.ArrayLike,
        ray_norm: npt.ArrayLike,
        ray_of_cell: npt.ArrayLike,
        depth_start_m: npt.ArrayLike,
        depth_end_m: npt.ArrayLike,
        *,
        ray_class: npt.ArrayLike | None = None,
        voxel_overhang_m: npt.ArrayLike | None = None,
        map_log_odds: npt.ArrayLike | None = None,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Posterior and increment per cell (see :class:`InverseSensorModel`), each ray by its class's model.

        Parameters
        ----------
        ray_class : (R,) int or None, keyword-only
            Class of each ray (:meth:`prismap.characterise.ErrorModel.classify` of its pixel), ``-1`` =
            no class (the plain model); None = every ray plain.
        voxel_overhang_m : (R,) float or None, keyword-only, metres
            Passed to the sub-models with each class's rays (when they :attr:`takes_voxel_overhang`).
        map_log_odds : (C,) float or None, keyword-only
            Each cell's map log-odds, passed to the sub-models with each class's cells (when they
            :attr:`takes_map_prior`).
        """
        use_overhang = voxel_overhang_m is not None and self.takes_voxel_overhang
        use_prior = map_log_odds is not None and self.takes_map_prior
        if ray_class is None:
            extra = {"voxel_overhang_m": voxel_overhang_m} if use_overhang else {}
            if use_prior:
                extra["map_log_odds"] = map_log_odds
            return self.plain.cell_posteriors(disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m, **extra)
        disparity, norm, rays, start, end = check_cell_arrays(
            disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m
        )
        classes = self._check_classes(ray_class, disparity.size)
        if self._classes is not None and self._classes.fused:  # every class in one look-up (models: class + 1)
            return self._classes.cell_posteriors(
                disparity, norm, rays, start, end, classes + 1, voxel_overhang_m if use_overhang else None
            )
        overhang_m = _ray_overhang(voxel_overhang_m if use_overhang else None, disparity.shape)
        prior_log = None
        if use_prior:
            prior_log = np.asarray(map_log_odds, dtype=np.float64)
            if prior_log.shape != start.shape:
                raise PrismapInputError(f"`map_log_odds` must have shape {start.shape}; got {prior_log.shape}")
        posterior = np.empty(start.size)
        increment = np.empty(start.size)
        for k, ray_index, cells, cell_ray in _split_by_class(classes, rays):
            extra = {} if overhang_m is None else {"voxel_overhang_m": overhang_m[ray_index]}
            if prior_log is not None:
                extra["map_log_odds"] = prior_log[cells]
            posterior[cells], increment[cells] = self._model(k).cell_posteriors(
                disparity[ray_index], norm[ray_index], cell_ray, start[cells], end[cells], **extra
            )
        return posterior, increment

    def influence_depth(
        self,
        disparity_px: npt.ArrayLike,
        ray_norm: npt.ArrayLike,
        *,
        ray_class: npt.ArrayLike | None = None,
        voxel_overhang_m: npt.ArrayLike | None = None,
    ) -> npt.NDArray[np.float64]:
        """Depth (metres) beyond which a ray's measurement changes no cell, by its class's model: (R,) float64
        (``voxel_overhang_m`` as :meth:`cell_posteriors` takes it)."""
        overhang = voxel_overhang_m if self.takes_voxel_overhang else None
        if ray_class is None:
            extra = {} if overhang is None else {"voxel_overhang_m": overhang}
            return self.plain.influence_depth(disparity_px, ray_norm, **extra)
        disparity, norm, classes = self._class_rays(disparity_px, ray_norm, ray_class)
        if self._classes is not None and self._classes.fused:
            return self._classes.influence_depth(disparity, norm, classes + 1, overhang)
        overhang = _ray_overhang(overhang, disparity.shape)
        depth = np.empty(disparity.size)
        for k in np.unique(classes):
            rays = np.flatnonzero(classes == k)
            own = {} if overhang is None else {"voxel_overhang_m": overhang[rays]}
            depth[rays] = self._model(int(k)).influence_depth(disparity[rays], norm[rays], **own)
        return depth

    def floor_depth(
        self,
        disparity_px: npt.ArrayLike,
        ray_norm: npt.ArrayLike,
        *,
        ray_class: npt.ArrayLike | None = None,
        voxel_overhang_m: npt.ArrayLike | None = None,
    ) -> npt.NDArray[np.float64] | None:
        """Per ray, by its class's model, the depth (metres) up to which its cells are at its failure floor
        (:meth:`PrismModel.floor_depth`); None unless the sub-models are PRISM models that share one look-up."""
        return self.influence_and_floor_depths(
            disparity_px, ray_norm, ray_class=ray_class, voxel_overhang_m=voxel_overhang_m
        )[1]

    def influence_and_floor_depths(
        self,
        disparity_px: npt.ArrayLike,
        ray_norm: npt.ArrayLike,
        *,
        ray_class: npt.ArrayLike | None = None,
        voxel_overhang_m: npt.ArrayLike | None = None,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64] | None]:
        """:meth:`influence_depth` and :meth:`floor_depth` of the rays, from one look-up of their tables where the
        classes share one (what ray mode asks: ``grid.SensorModel``)."""
        overhang = voxel_overhang_m if self.takes_voxel_overhang else None
        if ray_class is None:
            rule = getattr(self.plain, "influence_and_floor_depths", None)
            if rule is not None:
                return rule(disparity_px, ray_norm, voxel_overhang_m=overhang)
        elif self._classes is not None and self._classes.fused:
            disparity, norm, classes = self._class_rays(disparity_px, ray_norm, ray_class)
            return self._classes.influence_and_floor_depths(disparity, norm, classes + 1, overhang)
        return self.influence_depth(disparity_px, ray_norm, ray_class=ray_class, voxel_overhang_m=overhang), None

    def with_extra_noise(self, sigma_px: float) -> ConditionedModel:
        """A copy whose every sub-model (the plain one included) is widened by ``N(0, sigma_px^2)``."""
        return ConditionedModel(
            self.plain.with_extra_noise(sigma_px),
            tuple(model.with_extra_noise(sigma_px) for model in self.class_models),
        )


def _ray_overhang(voxel_overhang_m, shape):
    """``voxel_overhang_m`` as float64 of the rays' ``shape`` (checked), or None."""
    if voxel_overhang_m is None:
        return None
    overhang = np.asarray(voxel_overhang_m, dtype=np.float64)
    if overhang.shape != shape:
        raise PrismapInputError(f"`voxel_overhang_m` must have shape {shape}; got {overhang.shape}")
    return overhang


def _split_by_class(ray_class, ray_of_cell):
    """For each class with cells (:func:`cell_runs`): ``(class, its rays, its cells, each of those cells' ray among
    the class's rays)``; slices (no copies) when the cells come in runs, whose rays are then in class order."""
    order, runs = cell_runs(ray_class, ray_of_cell)
    local = None
    for c0, c1, k in zip(runs.first_cell[:-1], runs.first_cell[1:], runs.model):
        if order is None:  # ray_class is sorted: the class's rays are consecutive
            r0, r1 = np.searchsorted(ray_class, [k, k + 1])
            yield int(k), slice(r0, r1), slice(c0, c1), ray_of_cell[c0:c1] - r0 if r0 else ray_of_cell[c0:c1]
            continue
        rays = np.flatnonzero(ray_class == k)
        if local is None:
            local = np.empty(ray_class.size, dtype=np.int64)
        local[rays] = np.arange(rays.size)
        cells = order[c0:c1]
        yield int(k), rays, cells, local[ray_of_cell[cells]]


def model_for_mixture(
    name: str,
    mixture: GaussianMixture | None,
    *,
    focal_baseline: float,
    doffs_px: float,
    voxel_size_m: float,
    p0: float,
    **params: Any,
) -> InverseSensorModel:
    """The sensor model ``name`` for one error mixture: PRISM with it, convolution/Andert with its dominant sigma
    and, when it has a matcher-failure component, its :func:`~prismap.sensor_models.failure_floor`.

    ``params`` (the model's own parameters) win over what the mixture would set (``error_model``,
    ``sigma_px``, ``failure_floor``); other models ignore the mixture, and ``mixture=None`` sets nothing.
    """
    params = dict(params)
    use = error_model_use(name)
    if mixture is not None and use == "mixture":
        params.setdefault("error_model", mixture)
    elif mixture is not None and use == "sigma":
        params.setdefault("sigma_px", mixture.dominant_sigma())
        if mixture.failure_weight > 0:
            params.setdefault("failure_floor", failure_floor(mixture))
    try:
        return make_sensor_model(
            name, focal_baseline=focal_baseline, doffs_px=doffs_px, voxel_size_m=voxel_size_m, p0=p0, **params
        )
    except TypeError as exc:
        raise PrismapInputError(f"sensor model {name!r}: bad parameter(s) {sorted(params)}: {exc}") from None


def conditioned_sensor_model(
    name: str,
    camera: CameraRig,
    *,
    voxel_size_m: float,
    p0: float,
    error_model: ClassedErrors | GaussianMixture,
    **params: Any,
) -> InverseSensorModel:
    """The sensor model ``name`` for a (possibly conditioned) error model: what a mapping run builds.

    Parameters
    ----------
    name : str
        A name of :func:`prismap.sensor_models.model_names`.
    camera : StereoCamera
        Supplies ``focal_baseline`` (pixel-metres) and ``doffs_px``.
    voxel_size_m : float, metres
    p0 : float in (0, 1)
        Prior occupancy; must equal the map's.
    error_model : prismap.characterise.ErrorModel or GaussianMixture
        The matcher's characterised error. A conditioned model (with classes) gives a
        :class:`ConditionedModel` for ``prism``, ``convolution`` and ``andert``; a plain one, a mixture,
        or the models that ignore the error (``ideal``, ``hitmiss``) give the plain model.
    **params
        The model's own parameters (as for :func:`prismap.pipeline.build_sensor_model`). PRISM also takes
        ``class_pass_through`` (:data:`CLASS_PASS_THROUGH`): a sequence of one ``pass_through`` per class,
        measured like the whole one over each class's rays (``prismap.sim.Scene3D.pass_through_ratio`` with
        ``ray_classes``); class ``k``'s model gets value ``k``, the plain model ``pass_through``.

    Returns
    -------
    InverseSensorModel
        A :class:`ConditionedModel` takes ``ray_class=`` in :meth:`~ConditionedModel.cell_posteriors` and
        :meth:`~ConditionedModel.influence_depth`; the plain models do not.
    """
    if isinstance(error_model, GaussianMixture):
        whole, class_mixtures = error_model, ()
    elif isinstance(getattr(error_model, "mixture", None), GaussianMixture):
        whole = error_model.mixture
        class_mixtures = error_model.class_mixtures if getattr(error_model, "conditioned", False) else ()
    else:
        raise PrismapInputError(
            f"`error_model` must be an ErrorModel or a GaussianMixture; got {type(error_model).__name__}"
        )
    params = dict(params)
    per_class = params.pop(CLASS_PASS_THROUGH, None)
    build = {
        "focal_baseline": camera.focal_baseline,
        "doffs_px": camera.doffs_px,
        "voxel_size_m": voxel_size_m,
        "p0": p0,
        **params,
    }
    plain = model_for_mixture(name, whole, **build)
    if per_class is not None:
        if error_model_use(name) != "mixture" or not class_mixtures:
            raise PrismapInputError(
                f"`{CLASS_PASS_THROUGH}` needs PRISM with a conditioned error model; got model "
                f"{name!r} with {len(class_mixtures)} classes"
            )
        per_class = np.asarray(per_class, dtype=np.float64).reshape(-1)
        if per_class.size != len(class_mixtures):
            raise PrismapInputError(
                f"`{CLASS_PASS_THROUGH}` must hold one value per class ({len(class_mixtures)}); got {per_class.size}"
            )
        return ConditionedModel(
            plain,
            tuple(
                model_for_mixture(name, mixture, **{**build, "pass_through": float(m)})
                for mixture, m in zip(class_mixtures, per_class)
            ),
        )
    if not class_mixtures or error_model_use(name) is None:
        return plain
    return ConditionedModel(plain, tuple(model_for_mixture(name, mixture, **build) for mixture in class_mixtures))
