"""Every inverse sensor model on one ray, judged against PRISM (SENSOR_MODELS.md section 6).

The study evaluates models with ``cell_posteriors`` on equal cells along one ray of norm 1 (depth =
distance along the ray): cell ``k`` covers ``[k D, (k + 1) D]`` for the ``k`` with ``k D >= near_m``.
A measured distance ``s`` becomes the disparity ``f b / s - doffs`` rounded to OpenCV's 1/16 px, and
the profile is drawn at the distance of that rounded disparity, as a matcher would report it.

Models with a single Gaussian noise (``convolution``, ``andert``: any model with a ``sigma_px``) take the
sigma of the error mixture's dominant (largest-weight) component: the core of the matcher's errors, as
the mapping pipeline configures them, and the failure floor of the mixture's matcher-failure component
(:func:`prismap.sensor_models.failure_floor`) when it has one. PRISM takes the whole mixture.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.special import rel_entr

from prismap._depth import depth_from_disparity
from prismap._validate import check_positive, check_probability
from prismap.camera import KITTI_CAMERA, MOTORCYCLE_CAMERA, TSUKUBA_CAMERA
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.sensor_models import InverseSensorModel, failure_floor, make_sensor_model, model_names


def _rig(camera):
    return {"focal_px": camera.focal_px, "baseline_m": camera.baseline_m, "doffs_px": camera.doffs_px}


CAMERAS = {
    "middlebury-motorcycle": _rig(MOTORCYCLE_CAMERA),
    "kitti": _rig(KITTI_CAMERA),
    "tsukuba": _rig(TSUKUBA_CAMERA),
}
"""Rigs of the study: Middlebury 2014 Motorcycle at scikit-image's quarter resolution, KITTI 2011_09_26
(cameras 2 and 3, as in KITTI stereo 2015), New Tsukuba."""

DISPARITY_STEP_PX = 1.0 / 16.0
KL_CLIP = 1e-12
"""Model posteriors are clipped to ``[KL_CLIP, 1 - KL_CLIP]`` in the KL so a hard 0 or 1 stays finite."""


@dataclass(frozen=True, kw_only=True)
class RaySetup:
    """Camera, map cell and prior shared by every model of one study.

    Parameters
    ----------
    focal_baseline : float, pixel-metres
    doffs_px : float, pixels
    voxel_size_m : float, metres
        Cell length ``D`` along the ray.
    p0 : float in (0, 1)
        Prior occupancy of one cell of ``voxel_size_m``.
    near_m : float, metres
        First cell boundary (PRISM's ``z0``).
    epsilon : float, log-odds
        PRISM's influence bound: cells with ``|increment| < epsilon`` carry no information.
    """

    focal_baseline: float
    doffs_px: float = 0.0
    voxel_size_m: float = 0.1
    p0: float = 0.05
    near_m: float = 0.1
    epsilon: float = 1e-3

    def __post_init__(self):
        for name in ("focal_baseline", "voxel_size_m", "near_m", "epsilon"):
            object.__setattr__(self, name, check_positive(getattr(self, name), name))
        object.__setattr__(self, "p0", check_probability(self.p0, "p0"))
        if not np.isfinite(self.doffs_px):
            raise PrismapInputError(f"`doffs_px` must be finite; got {self.doffs_px!r}")
        object.__setattr__(self, "doffs_px", float(self.doffs_px))

    def with_cell_size(self, cell_m: float) -> RaySetup:
        """The same environment with cells of ``cell_m``: ``p0' = 1 - (1 - p0)^(cell_m / D)`` keeps PRISM's rate."""
        cell = check_positive(cell_m, "cell_m")
        p0 = -np.expm1(np.log1p(-self.p0) * cell / self.voxel_size_m)
        return dataclasses.replace(self, voxel_size_m=cell, p0=float(p0))

    def disparity_at(self, distance_m: float) -> float:
        """Disparity (pixels, 1/16 px steps) a matcher reports for a surface at ``distance_m`` on a ray of norm 1."""
        distance = check_positive(distance_m, "distance_m")
        disparity = np.round((self.focal_baseline / distance - self.doffs_px) / DISPARITY_STEP_PX) * DISPARITY_STEP_PX
        if disparity + self.doffs_px <= 0:
            raise PrismapInputError(f"distance {distance} m is beyond the disparity resolution of this camera")
        return float(disparity)

    def distance_of(self, disparity_px: float) -> float:
        """Measured distance (metres) of a disparity on a ray of norm 1 (+inf where ``d + doffs <= 0``)."""
        return float(depth_from_disparity(disparity_px, self.focal_baseline, self.doffs_px, invalid=np.inf))


def single_noise_sigma(mixture: GaussianMixture) -> float:
    """Sigma (pixels) of the mixture's largest-weight component: the noise of single-Gaussian models."""
    return float(mixture.sigmas[int(np.argmax(mixture.weights))])


def study_models(
    mixture: GaussianMixture, *, setup: RaySetup, names: Sequence[str] | None = None, prism_method: str = "direct"
) -> dict[str, InverseSensorModel]:
    """Build the models to compare, all with the setup's camera, cell size and prior.

    Parameters
    ----------
    mixture : GaussianMixture
        Disparity error model (pixels).
    setup : RaySetup
    names : sequence of str or None
        Registered model names; None = every registered model.
    prism_method : {"direct", "table"}
        PRISM's evaluation (``direct`` is the reference quadrature).

    Returns
    -------
    dict of str -> InverseSensorModel
    """
    if not isinstance(mixture, GaussianMixture):
        raise PrismapInputError(f"`mixture` must be a GaussianMixture; got {type(mixture).__name__}")
    common = {
        "focal_baseline": setup.focal_baseline,
        "doffs_px": setup.doffs_px,
        "voxel_size_m": setup.voxel_size_m,
        "p0": setup.p0,
    }
    models = {}
    for name in model_names() if names is None else names:
        if name == "prism":
            model = make_sensor_model(
                name,
                error_model=mixture,
                near_m=setup.near_m,
                method=prism_method,
                influence_epsilon=setup.epsilon,
                **common,
            )
        else:
            model = make_sensor_model(name, **common)
            if hasattr(model, "sigma_px"):
                model = dataclasses.replace(model, sigma_px=single_noise_sigma(mixture))
            if hasattr(model, "failure_floor"):  # the same share of failures PRISM's mixture has
                model = dataclasses.replace(model, failure_floor=failure_floor(mixture))
        models[name] = model
    return models


@dataclass(frozen=True)
class RayProfile:
    """Posteriors of several models on the cells of one ray (norm 1).

    Attributes
    ----------
    disparity_px : float, pixels
    measured_m : float, metres
    prior : float
        Prior of one cell (``p0`` of the setup).
    edges_m : (n + 1,) float64, metres
        Cell boundaries along the ray.
    posterior, increment : dict of str -> (n,) float64
        ``P(m | d^)`` and ``logit(P) - logit(prior)`` per model.
    influence_m : dict of str -> float, metres
        Each model's ``influence_depth``.
    """

    disparity_px: float
    measured_m: float
    prior: float
    edges_m: np.ndarray
    posterior: dict
    increment: dict
    influence_m: dict


def ray_profile(
    models: Mapping[str, InverseSensorModel], disparity_px: float, *, setup: RaySetup, end_m: float | None = None
) -> RayProfile:
    """Every model's posterior on the cells of one ray, from ``near_m`` to ``end_m``.

    ``end_m`` defaults to one cell past the largest influence depth of the models (capped at 1000 cells
    past the measurement), so every cell any model updates is included.
    """
    disparity = np.array([float(disparity_px)])
    norm = np.ones(1)
    influence = {name: float(model.influence_depth(disparity, norm)[0]) for name, model in models.items()}
    measured = setup.distance_of(disparity[0])
    cell = setup.voxel_size_m
    if end_m is None:
        end_m = min(max(influence.values()) + cell, measured + 1000 * cell)
    first = int(np.ceil(setup.near_m / cell - 1e-9))
    last = max(int(np.ceil(end_m / cell - 1e-9)), first + 1)
    edges = np.arange(first, last + 1) * cell
    start, end = edges[:-1], edges[1:]
    rays = np.zeros(start.size, dtype=np.int64)
    posterior, increment = {}, {}
    for name, model in models.items():
        posterior[name], increment[name] = model.cell_posteriors(disparity, norm, rays, start, end)
    return RayProfile(float(disparity[0]), float(measured), setup.p0, edges, posterior, increment, influence)


def divergence(profile: RayProfile, name: str, *, reference: str = "prism") -> dict[str, float | int]:
    """How far model ``name`` is from ``reference`` on one ray.

    Over the cells that either model updates (cell start below the larger of their influence depths):

    - ``mad``: mean ``|P_model - P_ref|`` per cell;
    - ``kl``: mean Bernoulli ``KL(P_ref || P_model)`` per cell (nats), model clipped to ``[1e-12, 1 - 1e-12]``;
    - ``cleared``: ``sum P_ref`` over the cells the model pushes toward free (increment < 0): the expected
      number of occupied cells, by the reference, that the model's update clears.

    Returns
    -------
    dict with float values ``mad``, ``kl``, ``cleared`` and int ``n_cells``.
    """
    for key in (name, reference):
        if key not in profile.posterior:
            raise PrismapInputError(f"model {key!r} is not in the profile; it has {list(profile.posterior)}")
    end = max(profile.influence_m[name], profile.influence_m[reference])
    cells = profile.edges_m[:-1] < end
    cells[0] = True
    p = profile.posterior[reference][cells]
    q = np.clip(profile.posterior[name][cells], KL_CLIP, 1.0 - KL_CLIP)
    kl = rel_entr(p, q) + rel_entr(1.0 - p, 1.0 - q)
    cleared = profile.increment[name][cells] < 0
    return {
        "mad": float(np.abs(p - q).mean()),
        "kl": float(kl.mean()),
        "cleared": float(p[cleared].sum()),
        "n_cells": int(cells.sum()),
    }


@dataclass(frozen=True)
class ModelComparison:
    """Profiles of every model at several measured distances and their divergences from PRISM.

    Attributes
    ----------
    setup : RaySetup
    distances_m : (D,) float64, metres, the requested distances
    profiles : tuple of RayProfile, one per distance
    divergences : dict of str -> dict of str -> (D,) float64
        ``divergences[model][metric]`` for ``metric`` in ``mad``, ``kl``, ``cleared`` (see :func:`divergence`).
    noise_sigma_px : float, pixels
        Sigma given to the single-noise models.
    """

    setup: RaySetup
    distances_m: np.ndarray
    profiles: tuple
    divergences: dict
    noise_sigma_px: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form: setup, distances, divergences and PRISM's influence depths."""
        return {
            "setup": dataclasses.asdict(self.setup),
            "noise_sigma_px": self.noise_sigma_px,
            "distances_m": self.distances_m.tolist(),
            "measured_m": [p.measured_m for p in self.profiles],
            "disparity_px": [p.disparity_px for p in self.profiles],
            "influence_m": {
                name: [p.influence_m[name] for p in self.profiles] for name in self.profiles[0].influence_m
            },
            "divergences": {
                name: {k: v.tolist() for k, v in metrics.items()} for name, metrics in self.divergences.items()
            },
        }

    def to_markdown(self) -> str:
        """Markdown table: one row per model and distance with MAD, KL and cleared occupancy."""
        lines = [
            "| model | distance (m) | mean abs. diff. of P | mean KL(PRISM \\|\\| model) (nats) | "
            "cleared occupancy (cells) |",
            "|---|---:|---:|---:|---:|",
        ]
        for name, metrics in self.divergences.items():
            for i, profile in enumerate(self.profiles):
                lines.append(
                    f"| {name} | {profile.measured_m:.2f} | {metrics['mad'][i]:.4f} | "
                    f"{metrics['kl'][i]:.4f} | {metrics['cleared'][i]:.3f} |"
                )
        return "\n".join(lines) + "\n"


def _distances(distances_m):
    distances = np.atleast_1d(np.asarray(distances_m, dtype=np.float64))
    if distances.ndim != 1 or distances.size == 0 or not np.all(np.isfinite(distances)) or np.any(distances <= 0):
        raise PrismapInputError(f"`distances_m` must be a non-empty list of positive distances; got {distances_m!r}")
    return distances


def compare_models(
    mixture: GaussianMixture, distances_m: npt.ArrayLike, *, setup: RaySetup, names: Sequence[str] | None = None
) -> ModelComparison:
    """Profiles of every model (PRISM direct as the reference) at each distance, and their divergences.

    Parameters
    ----------
    mixture : GaussianMixture
        Disparity error model (pixels).
    distances_m : (D,) float, metres
        Measured distances along the ray.
    setup : RaySetup
    names : sequence of str or None
        Models to compare (must include ``"prism"``); None = every registered model.

    Returns
    -------
    ModelComparison
    """
    distances = _distances(distances_m)
    models = study_models(mixture, setup=setup, names=names)
    if "prism" not in models:
        raise PrismapInputError(f"the comparison needs 'prism' among the models; got {list(models)}")
    profiles = tuple(ray_profile(models, setup.disparity_at(s), setup=setup) for s in distances)
    divergences = {}
    for name in models:
        if name == "prism":
            continue
        rows = [divergence(profile, name) for profile in profiles]
        divergences[name] = {key: np.array([row[key] for row in rows]) for key in ("mad", "kl", "cleared")}
    return ModelComparison(setup, distances, profiles, divergences, single_noise_sigma(mixture))


def influence_distances(
    mixture: GaussianMixture, distances_m: npt.ArrayLike, *, setup: RaySetup
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """PRISM's reach behind the measurement, per measured distance.

    Returns
    -------
    measured_m : (D,) float64, metres, distance of the rounded disparity
    bound_m : (D,) float64, metres
        ``influence_depth - measured``: the bound PRISM gives ray casting.
    observed_m : (D,) float64, metres
        End of the last cell whose ``|increment| >= epsilon`` (direct evaluation) minus the measured distance.
    """
    distances = _distances(distances_m)
    prism = study_models(mixture, setup=setup, names=["prism"])
    measured, bound, observed = [], [], []
    for s in distances:
        profile = ray_profile(prism, setup.disparity_at(s), setup=setup)
        informative = np.nonzero(np.abs(profile.increment["prism"]) >= setup.epsilon)[0]
        last = profile.edges_m[informative[-1] + 1] if informative.size else profile.edges_m[0]
        measured.append(profile.measured_m)
        bound.append(profile.influence_m["prism"] - profile.measured_m)
        observed.append(last - profile.measured_m)
    return np.array(measured), np.array(bound), np.array(observed)


def prism_sweeps(
    mixture: GaussianMixture,
    *,
    setup: RaySetup,
    distances_m: Sequence[float] = (2.0, 5.0, 10.0, 20.0),
    reference_m: float = 10.0,
    noise_scales: Sequence[float] = (0.5, 1.0, 2.0, 4.0),
    cell_sizes_m: Sequence[float] = (0.05, 0.1, 0.2, 0.4),
    mixtures_by_components: Mapping[int, GaussianMixture] | None = None,
) -> dict[str, list[tuple[str, RayProfile]]]:
    """PRISM's profile as one thing changes at a time (thesis figs 5.11-5.15).

    Parameters
    ----------
    mixture : GaussianMixture
        The error model (pixels).
    setup : RaySetup
    distances_m : sequence of float, metres
        Measured distances of the ``distance`` sweep.
    reference_m : float, metres
        Measured distance of the other sweeps.
    noise_scales : sequence of float
        Factors on every sigma of the mixture (``noise`` sweep).
    cell_sizes_m : sequence of float, metres
        Cell lengths (``cell size`` sweep); ``p0`` follows so the surface rate stays the same.
    mixtures_by_components : dict of int -> GaussianMixture or None
        Fits with G components (``components`` sweep); None = no such sweep.

    Returns
    -------
    dict of str -> list of (label, RayProfile)
        Keys ``distance``, ``noise``, ``cell size`` and (if given) ``components``.
    """

    def prism_profile(mix, ray_setup, distance):
        models = study_models(mix, setup=ray_setup, names=["prism"])
        return ray_profile(models, ray_setup.disparity_at(distance), setup=ray_setup)

    reference = check_positive(reference_m, "reference_m")
    sweeps = {
        "distance": [(f"{s:g} m", prism_profile(mixture, setup, s)) for s in _distances(distances_m)],
        "noise": [(f"sigma x {k:g}", prism_profile(_scaled(mixture, k), setup, reference)) for k in noise_scales],
        "cell size": [(f"{c:g} m", prism_profile(mixture, setup.with_cell_size(c), reference)) for c in cell_sizes_m],
    }
    if mixtures_by_components:
        sweeps["components"] = [
            (f"G = {g}", prism_profile(mix, setup, reference)) for g, mix in sorted(mixtures_by_components.items())
        ]
    return sweeps


def _scaled(mixture, factor):
    return GaussianMixture(
        mixture.weights,
        mixture.means,
        mixture.sigmas * check_positive(factor, "noise scale"),
        mixture.failure_weight,
        mixture.search_range_px,
    )
