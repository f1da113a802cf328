"""Studies of the inverse sensor models along one ray: profiles, PRISM sweeps, divergences, timings."""

from prismap.study._ray_models import (
    CAMERAS,
    ModelComparison,
    PerformanceTable,
    RayProfile,
    RaySetup,
    compare_models,
    divergence,
    influence_distances,
    prism_sweeps,
    ray_profile,
    single_noise_sigma,
    study_models,
    time_models,
)

__all__ = [
    "CAMERAS",
    "ModelComparison",
    "PerformanceTable",
    "RayProfile",
    "RaySetup",
    "compare_models",
    "divergence",
    "influence_distances",
    "prism_sweeps",
    "ray_profile",
    "single_noise_sigma",
    "study_models",
    "time_models",
]
