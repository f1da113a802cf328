"""The sensor-model study along one ray: setup, profiles, divergences, PRISM sweeps, influence, timings."""

import numpy as np
import pytest

from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.sensor_models import prism_discrete_posteriors
from prismap.study import (
    CAMERAS,
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

# Close to SGBM on Middlebury Motorcycle (quarter resolution), as `prismap characterise` fits it.
MOTORCYCLE_SGBM = GaussianMixture([0.84, 0.10, 0.06], [0.01, -0.04, -10.4], [0.24, 0.92, 13.6])
RIG = CAMERAS["middlebury-motorcycle"]
SETUP = RaySetup(
    focal_baseline=RIG["focal_px"] * RIG["baseline_m"], doffs_px=RIG["doffs_px"], voxel_size_m=0.1, p0=0.05
)
CLASSIC = ("ideal", "hitmiss", "convolution", "andert")


@pytest.fixture(scope="module")
def comparison():
    return compare_models(MOTORCYCLE_SGBM, [2.0, 5.0, 10.0, 20.0], setup=SETUP)


def test_cell_size_change_keeps_the_surface_rate():
    for cell in (0.05, 0.2, 0.4):
        other = SETUP.with_cell_size(cell)
        assert other.voxel_size_m == cell
        assert -np.log1p(-other.p0) / cell == pytest.approx(-np.log1p(-SETUP.p0) / SETUP.voxel_size_m, rel=1e-12)


def test_disparity_is_rounded_to_sixteenths_and_maps_back_to_distance():
    for distance in (1.0, 2.0, 7.3, 20.0):
        d = SETUP.disparity_at(distance)
        assert d * 16 == pytest.approx(round(d * 16), abs=1e-9)
        # rounding moves the disparity by at most 1/32 px: |ds| <= s^2 / (32 f b)
        assert abs(SETUP.distance_of(d) - distance) <= distance**2 / (32 * SETUP.focal_baseline) * 1.01
    with pytest.raises(PrismapInputError, match="beyond the disparity resolution"):
        RaySetup(focal_baseline=61.5).disparity_at(3000.0)  # 0.0205 px rounds to 0


def test_single_noise_models_take_the_dominant_component_sigma():
    assert single_noise_sigma(MOTORCYCLE_SGBM) == 0.24
    assert single_noise_sigma(GaussianMixture([0.3, 0.7], [0.0, 1.0], [5.0, 0.5])) == 0.5
    models = study_models(MOTORCYCLE_SGBM, setup=SETUP, names=list(CLASSIC) + ["prism"])
    assert models["convolution"].sigma_px == models["andert"].sigma_px == 0.24
    assert models["prism"].error_model == MOTORCYCLE_SGBM
    for model in models.values():
        assert (model.focal_baseline, model.doffs_px, model.voxel_size_m, model.p0) == (
            SETUP.focal_baseline,
            SETUP.doffs_px,
            0.1,
            0.05,
        )


def test_prism_profile_matches_the_discrete_reference():
    """Direct PRISM on the study's cells against the thesis's discrete form on the same edges."""
    setup = RaySetup(focal_baseline=61.5, voxel_size_m=0.1, p0=0.05, near_m=0.1)
    models = study_models(MOTORCYCLE_SGBM, setup=setup, names=["prism"])
    d = setup.disparity_at(4.0)
    profile = ray_profile(models, d, setup=setup)
    assert profile.edges_m[0] == pytest.approx(0.1)
    assert np.allclose(np.diff(profile.edges_m), 0.1)
    reference = prism_discrete_posteriors(d, profile.edges_m, MOTORCYCLE_SGBM, focal_baseline=61.5, p0=0.05)
    # the continuous form also lets surfaces lie beyond the last edge (up to 200 m): compare in front of the end
    inside = profile.edges_m[1:] < profile.measured_m + 1.0
    assert np.allclose(profile.posterior["prism"][inside], reference[inside], atol=2e-3)
    assert profile.influence_m["prism"] <= profile.edges_m[-1]


def _by_hand(p, q, inc_model, n):
    kl = [
        pi * np.log(pi / qi) + (1 - pi) * np.log((1 - pi) / (1 - qi)) if pi > 0 else -np.log(1 - qi)
        for pi, qi in zip(p[:n], q[:n])
    ]
    cleared = sum(pi for pi, inc in zip(p[:n], inc_model[:n]) if inc < 0)
    return np.mean(np.abs(p[:n] - q[:n])), np.mean(kl), cleared


def test_divergence_against_hand_computed_values():
    edges = np.arange(1.0, 2.01, 0.1)
    p = np.array([0.0, 0.01, 0.02, 0.3, 0.6, 0.05, 0.05, 0.05, 0.05, 0.05])
    q = np.array([0.03, 0.03, 0.03, 0.03, 0.1, 0.05, 0.05, 0.2, 0.2, 0.2])
    inc_q = np.log(q / (1 - q)) - np.log(0.05 / 0.95)
    profile = RayProfile(
        10.0, 1.45, 0.05, edges, {"prism": p, "m": q}, {"prism": p * 0, "m": inc_q}, {"prism": 1.7, "m": 1.55}
    )
    result = divergence(profile, "m")
    n = 7  # cells starting below max(1.7, 1.55)
    mad, kl, cleared = _by_hand(p, q, inc_q, n)
    assert result["n_cells"] == n
    assert result["mad"] == pytest.approx(mad, rel=1e-12)
    assert result["kl"] == pytest.approx(kl, rel=1e-12)
    assert result["cleared"] == pytest.approx(cleared, rel=1e-12)
    assert divergence(profile, "prism", reference="prism")["kl"] == pytest.approx(0.0, abs=1e-10)
    with pytest.raises(PrismapInputError, match="'other' is not in the profile"):
        divergence(profile, "other")


def test_hard_zero_model_posterior_keeps_the_kl_finite():
    edges = np.array([1.0, 1.1, 1.2])
    profile = RayProfile(
        1.0,
        1.05,
        0.05,
        edges,
        {"prism": np.array([0.2, 0.05]), "m": np.array([0.0, 1.0])},
        {"prism": np.zeros(2), "m": np.array([-50.0, 50.0])},
        {"prism": 1.2, "m": 1.2},
    )
    assert np.isfinite(divergence(profile, "m")["kl"])


def test_must_show_divergence_from_prism_against_distance(comparison):
    """Motorcycle SGBM error model, Motorcycle camera, 0.1 m cells, p0 = 0.05, measured 2, 5, 10, 20 m.

    What grows with distance, for every model: the PRISM occupancy it clears (sum of PRISM's P over the
    cells the model pushes toward free) is larger at 20 m than at 2 m, by more than 100x, and exceeds one
    whole cell at 20 m: far away the classic models declare free space where PRISM still expects the
    surface. What does not grow: the per-cell mean |dP| and KL are largest at 2 m, where these
    models (posteriors 0.03-0.11 after one update from p0 = 0.05) are far less sure than PRISM (P ~ 0 in
    front, ~0.5 on each of the two cells around the surface).
    """
    assert set(comparison.divergences) == set(CLASSIC)
    for name, metrics in comparison.divergences.items():
        cleared, kl, mad = metrics["cleared"], metrics["kl"], metrics["mad"]
        assert cleared[-1] > 100 * cleared[0] and cleared[-1] > 1.0, name
        assert cleared[-1] == cleared.max(), name
        assert kl[0] > kl[-1] and mad[0] > mad[-1], name


def test_profiles_show_prism_properties(comparison):
    peaks = []
    for profile in comparison.profiles:
        p = profile.posterior["prism"]
        centres = 0.5 * (profile.edges_m[1:] + profile.edges_m[:-1])
        peak = int(np.argmax(p))
        assert abs(centres[peak] - profile.measured_m) < 0.2 + 0.01 * profile.measured_m**2
        assert p[centres < profile.measured_m / 2].max() < profile.prior  # free in front
        assert p[-1] == pytest.approx(profile.prior, abs=0.01)  # prior far behind
        peaks.append(p.max())
    assert np.all(np.diff(peaks) < 0)  # the peak flattens with distance


def test_influence_bound_covers_the_observed_reach():
    measured, bound, observed = influence_distances(MOTORCYCLE_SGBM, [2.0, 8.0, 15.0], setup=SETUP)
    assert measured == pytest.approx([2.0, 8.0, 15.0], rel=1e-2)
    assert np.all(observed <= bound + SETUP.voxel_size_m)
    assert np.all(observed > 0)


def test_prism_sweeps_vary_one_thing_at_a_time():
    g1 = GaussianMixture.gaussian(0.3)
    sweeps = prism_sweeps(
        MOTORCYCLE_SGBM,
        setup=SETUP,
        distances_m=[3.0, 6.0],
        reference_m=5.0,
        noise_scales=(1.0, 3.0),
        cell_sizes_m=(0.1, 0.3),
        mixtures_by_components={1: g1, 3: MOTORCYCLE_SGBM},
    )
    assert list(sweeps) == ["distance", "noise", "cell size", "components"]
    assert [label for label, _ in sweeps["noise"]] == ["sigma x 1", "sigma x 3"]
    (_, fine), (_, coarse) = sweeps["cell size"]
    assert coarse.prior == pytest.approx(SETUP.with_cell_size(0.3).p0)
    assert np.allclose(np.diff(coarse.edges_m), 0.3)
    # more pixel noise flattens the peak
    assert sweeps["noise"][0][1].posterior["prism"].max() > sweeps["noise"][1][1].posterior["prism"].max()
    # the sweep at sigma x 1 is the plain profile
    assert np.array_equal(sweeps["noise"][0][1].posterior["prism"], sweeps["components"][1][1].posterior["prism"])


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: compare_models(MOTORCYCLE_SGBM, [], setup=SETUP), "`distances_m` must be a non-empty"),
        (lambda: compare_models(MOTORCYCLE_SGBM, [2.0, -1.0], setup=SETUP), "positive distances"),
        (lambda: compare_models(MOTORCYCLE_SGBM, [2.0], setup=SETUP, names=["ideal"]), "needs 'prism'"),
        (lambda: study_models("not a mixture", setup=SETUP), "must be a GaussianMixture"),
        (lambda: RaySetup(focal_baseline=10.0, p0=1.0), "`p0` must lie in"),
        (lambda: RaySetup(focal_baseline=-1.0), "focal_baseline"),
        (lambda: study_models(MOTORCYCLE_SGBM, setup=SETUP, names=["nope"]), "unknown sensor model 'nope'"),
    ],
)
def test_bad_input_is_named(call, message):
    with pytest.raises(PrismapInputError, match=message):
        call()
