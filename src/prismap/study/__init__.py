"""Studies of the inverse sensor models along one ray: profiles, PRISM sweeps, divergences, and the ``models compare`` workflow."""

from prismap.study._compare import COMPARE_FILES, ModelsCompareRun, run_models_compare
from prismap.study._ray_models import (
    CAMERAS,
    ModelComparison,
    RayProfile,
    RaySetup,
    compare_models,
    divergence,
    influence_distances,
    prism_sweeps,
    ray_profile,
    single_noise_sigma,
    study_models,
)

__all__ = [
    "CAMERAS",
    "COMPARE_FILES",
    "ModelComparison",
    "ModelsCompareRun",
    "RayProfile",
    "RaySetup",
    "compare_models",
    "divergence",
    "influence_distances",
    "prism_sweeps",
    "ray_profile",
    "run_models_compare",
    "single_noise_sigma",
    "study_models",
]
