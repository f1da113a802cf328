"""ConditionedModel: rays by class to per-class sub-models, equal to calling those sub-models by hand."""

import pickle

import numpy as np
import pytest

from prismap.camera import StereoCamera
from prismap.characterise import ClassModel, ErrorClasses, ErrorModel
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture, MixtureFit
from prismap.sensor_models import (
    ConditionedModel,
    _conditioned,
    _kernels_lookup,
    _prism,
    conditioned_sensor_model,
    make_sensor_model,
)
from prismap.sensor_models._kernel_args import Cells, ClassRuns
from prismap.sensor_models._prism import AUTO_TABLE_FLOOR_MB
from prismap.sensor_models._prism_cache import KEY_TAG_SPAN

CAMERA = StereoCamera(500.0, 320.0, 240.0, 0.2)
WHOLE = GaussianMixture([0.8, 0.2], [0.0, -0.5], [0.3, 3.0])
CLASS_MIXTURES = (
    GaussianMixture([0.6, 0.4], [0.0, -2.0], [0.6, 5.0]),
    GaussianMixture([0.95, 0.05], [0.0, 0.1], [0.15, 1.0]),
    GaussianMixture.gaussian(0.25, 0.05),
)
SETTINGS = {"voxel_size_m": 0.2, "p0": 0.05}


def _fit(mixture):
    return MixtureFit(mixture, -1.0, 1.0, 1.0, 100.0, 3, True)


def _error_model(whole=WHOLE, class_mixtures=CLASS_MIXTURES):
    inf = np.inf
    classes = ErrorClasses(("edge_distance_px",), [[-inf], [2.5], [10.0]], [[2.5], [10.0], [inf]])
    class_models = tuple(
        ClassModel((_fit(m),), m.n_components, share, {"n_errors": 100})
        for m, share in zip(class_mixtures, (0.2, 0.5, 0.3))
    )
    return ErrorModel(
        "sgbm",
        {},
        "test",
        1 / 32,
        (_fit(whole),),
        whole.n_components,
        classes=classes,
        class_models=class_models,
        feature_settings={"edge_threshold_px": 1.0, "texture_window_px": 7},
    )


def _rays(seed=0, n_rays=40, cells_per_ray=30):
    rng = np.random.default_rng(seed)
    disparity = np.round(rng.uniform(5.0, 60.0, n_rays) * 16) / 16
    norm = 1.0 + rng.uniform(0.0, 0.2, n_rays)
    ray_class = rng.integers(-1, 3, n_rays)
    rays = np.repeat(np.arange(n_rays), cells_per_ray)
    z_hat = CAMERA.focal_baseline / disparity
    offsets = np.tile(np.linspace(-0.6, 0.6, cells_per_ray), n_rays)
    start = np.maximum(z_hat[rays] * (1 + offsets), 0.2)
    order = rng.permutation(rays.size)  # cells of several rays interleaved, as a grid hands them over
    return disparity, norm, ray_class, rays[order], start[order], start[order] + 0.15


@pytest.mark.parametrize("name", ["prism", "andert", "convolution"])
def test_conditioned_model_equals_each_sub_model_on_its_rays(name):
    model = conditioned_sensor_model(name, CAMERA, error_model=_error_model(), **SETTINGS)
    assert isinstance(model, ConditionedModel) and model.n_classes == 3 and model.name == name
    disparity, norm, ray_class, rays, start, end = _rays()
    posterior, increment = model.cell_posteriors(disparity, norm, rays, start, end, ray_class=ray_class)
    depth = model.influence_depth(disparity, norm, ray_class=ray_class)
    for k in (-1, 0, 1, 2):
        by_hand = conditioned_sensor_model(name, CAMERA, error_model=WHOLE if k < 0 else CLASS_MIXTURES[k], **SETTINGS)
        assert not isinstance(by_hand, ConditionedModel)
        mine = np.flatnonzero(ray_class == k)
        local = np.full(disparity.size, -1)
        local[mine] = np.arange(mine.size)
        cells = np.flatnonzero(np.isin(rays, mine))
        p, inc = by_hand.cell_posteriors(disparity[mine], norm[mine], local[rays[cells]], start[cells], end[cells])
        np.testing.assert_array_equal(posterior[cells], p)
        np.testing.assert_array_equal(increment[cells], inc)
        np.testing.assert_array_equal(depth[mine], by_hand.influence_depth(disparity[mine], norm[mine]))
        one_class = model.cell_posteriors(
            disparity[mine], norm[mine], local[rays[cells]], start[cells], end[cells], ray_class=ray_class[mine]
        )  # a call of one class (a ray-mode chunk) goes to that class's model whole
        np.testing.assert_array_equal(one_class[0], p)
        np.testing.assert_array_equal(one_class[1], inc)
    # The classes differ: the model is not the plain one in disguise.
    plain_p, _ = model.cell_posteriors(disparity, norm, rays, start, end)
    assert np.abs(plain_p - posterior).max() > 1e-3
    np.testing.assert_array_equal(plain_p, model.plain.cell_posteriors(disparity, norm, rays, start, end)[0])


@pytest.mark.parametrize("name", ["prism", "andert"])
def test_rays_in_class_order_give_the_same_cells_as_rays_in_any_order(name):
    """A projective part hands rays sorted by class and cells sorted by ray (the split then takes slices, no
    gathers): every cell's posterior and increment equal those of the same rays and cells in another order."""
    model = conditioned_sensor_model(name, CAMERA, error_model=_error_model(), **SETTINGS)
    disparity, norm, ray_class, rays, start, end = _rays(seed=4)
    posterior, increment = model.cell_posteriors(disparity, norm, rays, start, end, ray_class=ray_class)
    by_class = np.argsort(ray_class, kind="stable")  # new ray i is old ray by_class[i]
    new_ray = np.empty_like(by_class)
    new_ray[by_class] = np.arange(by_class.size)
    cells = np.argsort(new_ray[rays], kind="stable")
    sorted_rays = new_ray[rays][cells]
    assert np.all(np.diff(ray_class[by_class]) >= 0) and np.all(np.diff(sorted_rays) >= 0)
    p, inc = model.cell_posteriors(
        disparity[by_class], norm[by_class], sorted_rays, start[cells], end[cells], ray_class=ray_class[by_class]
    )
    np.testing.assert_array_equal(p, posterior[cells])
    np.testing.assert_array_equal(inc, increment[cells])
    split = list(_conditioned._split_by_class(ray_class[by_class], sorted_rays))
    assert [k for k, *_ in split] == sorted(set(ray_class.tolist()))
    assert all(isinstance(ray_index, slice) and isinstance(mine, slice) for _, ray_index, mine, _ in split)


@pytest.mark.parametrize("name", ["andert", "convolution"])
def test_sigma_models_take_each_class_dominant_sigma_and_extra_noise_widens_every_one(name):
    model = conditioned_sensor_model(name, CAMERA, error_model=_error_model(), **SETTINGS)
    assert [m.sigma_px for m in model.class_models] == [0.6, 0.15, 0.25]
    assert model.plain.sigma_px == 0.3
    wide = model.with_extra_noise(0.4)
    assert isinstance(wide, ConditionedModel)
    np.testing.assert_allclose([m.sigma_px for m in wide.class_models], np.hypot([0.6, 0.15, 0.25], 0.4))
    assert wide.plain.sigma_px == pytest.approx(0.5)


def test_prism_sub_models_hold_each_class_mixture_and_widen_it():
    model = conditioned_sensor_model("prism", CAMERA, error_model=_error_model(), near_m=0.5, **SETTINGS)
    for sub, mixture in zip(model.class_models, CLASS_MIXTURES):
        np.testing.assert_array_equal(sub.error_model.sigmas, mixture.sigmas)
        assert sub.near_m == 0.5
    wide = model.with_extra_noise(0.2)
    for sub, mixture in zip(wide.class_models, CLASS_MIXTURES):
        np.testing.assert_allclose(sub.error_model.sigmas, np.hypot(mixture.sigmas, 0.2))


def test_conditioned_prism_sub_models_share_one_table_cache_and_budget():
    """The plain and class PRISM models keep their tables in one cache (keys apart by class), within one budget:
    the automatic floor once, or the fixed ``table_memory_mb`` once. A sub-model called by itself finds the tables
    a fused call built, and a widened copy made twice keeps its cache."""
    model = conditioned_sensor_model("prism", CAMERA, error_model=_error_model(), **SETTINGS)
    subs = (model.plain, *model.class_models)
    cache = model.plain._cache
    assert all(sub._cache is cache for sub in subs) and cache.floor_bytes == int(AUTO_TABLE_FLOOR_MB * 2**20)
    assert [sub._table_tag for sub in subs] == [k * KEY_TAG_SPAN for k in range(4)]
    disparity, norm, ray_class, *cells = _rays()
    model.cell_posteriors(disparity, norm, *cells, ray_class=ray_class)
    rate_key = np.floor(np.log(norm) / _prism._LAMBDA_STEP).astype(np.int64)
    pairs = set(zip(ray_class.tolist(), np.rint(disparity * 16).astype(np.int64).tolist(), rate_key.tolist()))
    assert len(cache) == cache.builds == len(pairs)  # one table per (class, disparity, rate): none shared by classes
    np.testing.assert_array_equal(np.unique(cache.keys // KEY_TAG_SPAN), np.unique(ray_class + 1))
    mine = np.flatnonzero(ray_class == 1)
    alone = model.class_models[1].influence_depth(disparity[mine], norm[mine])
    assert cache.builds == len(pairs)  # found, not built again
    np.testing.assert_array_equal(alone, model.influence_depth(disparity, norm, ray_class=ray_class)[mine])
    wide = model.with_extra_noise(0.2)
    wide.cell_posteriors(disparity, norm, *cells, ray_class=ray_class)
    again = model.with_extra_noise(0.2)
    assert again.plain._cache is wide.plain._cache and len(again.plain._cache) == len(pairs)
    fixed = conditioned_sensor_model("prism", CAMERA, error_model=_error_model(), table_memory_mb=0.05, **SETTINGS)
    assert all(sub._cache is fixed.plain._cache for sub in (fixed.plain, *fixed.class_models))
    fixed.cell_posteriors(disparity, norm, *cells, ray_class=ray_class)
    for seed in (1, 2):  # other rays: the least recently used tables go, of whichever class
        other = _rays(seed=seed)
        fixed.influence_depth(other[0], other[1], ray_class=other[2])
        assert fixed.plain._cache.nbytes <= max(fixed.plain._cache.limit_bytes, fixed.plain._cache.largest_call_bytes)
    assert fixed.plain._cache.limit_bytes == int(0.05 * 2**20) and len(fixed.plain._cache) < fixed.plain._cache.builds


def test_fused_classes_with_failures_overhang_and_any_ray_order_equal_each_sub_model():
    """With matcher failures in every class mixture, voxel overhangs and rays of the classes interleaved, the one
    look-up gives every cell bit for bit what its class's own model gives; with failures in some classes only,
    the classes take their own calls."""
    error = _error_model()
    failing = [m.with_failure(w, (0.0, 64.0)) for m, w in zip((WHOLE, *CLASS_MIXTURES), (0.05, 0.2, 0.01, 0.1))]
    mixed = [failing[0], *CLASS_MIXTURES[:2], failing[3]]
    disparity, norm, ray_class, rays, start, end = _rays(seed=7, n_rays=60)
    overhang = np.random.default_rng(7).uniform(0.0, 0.3, disparity.size)
    for mixtures, fused in ((failing, True), (mixed, False)):
        subs = [
            make_sensor_model("prism", focal_baseline=CAMERA.focal_baseline, error_model=m, **SETTINGS)
            for m in mixtures
        ]
        model = ConditionedModel(subs[0], tuple(subs[1:]))
        assert model._classes.fused is fused and error.n_classes == 3
        posterior, increment = model.cell_posteriors(
            disparity, norm, rays, start, end, ray_class=ray_class, voxel_overhang_m=overhang
        )
        for k, mixture in zip((-1, 0, 1, 2), mixtures):
            by_hand = make_sensor_model("prism", focal_baseline=CAMERA.focal_baseline, error_model=mixture, **SETTINGS)
            mine = np.flatnonzero(ray_class == k)
            local = np.full(disparity.size, -1)
            local[mine] = np.arange(mine.size)
            cells = np.flatnonzero(np.isin(rays, mine))
            p, inc = by_hand.cell_posteriors(
                disparity[mine],
                norm[mine],
                local[rays[cells]],
                start[cells],
                end[cells],
                voxel_overhang_m=overhang[mine],
            )
            np.testing.assert_array_equal(posterior[cells], p)
            np.testing.assert_array_equal(increment[cells], inc)


def test_a_pickled_conditioned_prism_model_arrives_with_one_empty_shared_cache_and_gives_the_same_cells():
    """What a Dask worker receives: the sub-models still share one cache (empty, the budget kept), the fused call
    uses it, and every cell and influence depth is the original's; only -1 rays, and no cells, work too."""
    model = conditioned_sensor_model("prism", CAMERA, error_model=_error_model(), **SETTINGS)
    disparity, norm, ray_class, rays, start, end = _rays(seed=5)
    want = model.cell_posteriors(disparity, norm, rays, start, end, ray_class=ray_class)
    twin = pickle.loads(pickle.dumps(model))
    cache = twin.plain._cache
    assert len(cache) == 0 and cache is not model.plain._cache and cache is twin._classes.cache
    assert all(sub._cache is cache for sub in twin.class_models) and twin._classes.fused
    got = twin.cell_posteriors(disparity, norm, rays, start, end, ray_class=ray_class)
    np.testing.assert_array_equal(got[1], want[1])
    np.testing.assert_array_equal(
        twin.influence_depth(disparity, norm, ray_class=ray_class),
        model.influence_depth(disparity, norm, ray_class=ray_class),
    )
    plain_only = np.full(disparity.size, -1)
    np.testing.assert_array_equal(
        twin.cell_posteriors(disparity, norm, rays, start, end, ray_class=plain_only)[1],
        model.plain.cell_posteriors(disparity, norm, rays, start, end)[1],
    )
    empty = twin.cell_posteriors(disparity, norm, rays[:0], start[:0], end[:0], ray_class=ray_class)
    assert empty[0].shape == empty[1].shape == (0,)


def test_fused_look_up_splits_blocks_at_class_runs():
    """Runs of one class that begin and end inside a look-up block (a block of 7 cells here) give the cells what a
    call per run gives."""
    model = conditioned_sensor_model("prism", CAMERA, error_model=_error_model(), **SETTINGS)
    disparity, norm, ray_class, rays, start, end = _rays(seed=3, n_rays=12, cells_per_ray=5)
    order = np.argsort(ray_class[rays], kind="stable")
    rays, start, end = rays[order], start[order], end[order]
    classes = model._classes
    first = classes.models[0]
    index = ray_class + 1
    tables = classes.tables_for(disparity, norm, index)
    lam = first.rate_per_m * norm
    cell_model = index[rays]
    bounds = np.flatnonzero(np.diff(cell_model)) + 1
    runs = ClassRuns(np.concatenate(([0], bounds, [rays.size])), cell_model[np.concatenate(([0], bounds))])
    assert runs.model.size == 4 and np.any(bounds % 7 != 0)
    post, inc = _kernels_lookup.prism_table_cells(
        lam, np.zeros(disparity.size), tables, Cells(rays, start, end), runs, 0.25, 7, 0.0,
        np.empty(0), np.empty(0), np.empty(0), first._geometry(), classes.mixtures,
    )  # fmt: skip
    for k in range(4):
        cells = np.flatnonzero(cell_model == k)
        p, i = classes.models[k]._table_cells(
            lam,
            rays[cells],
            start[cells],
            end[cells],
            np.zeros(disparity.size),
            tables,
            (np.empty(0), np.empty(0)),
        )
        np.testing.assert_array_equal(post[cells], p)
        np.testing.assert_array_equal(inc[cells], i)


@pytest.mark.parametrize("name", ["ideal", "hitmiss"])
def test_models_that_ignore_the_error_are_not_wrapped(name):
    model = conditioned_sensor_model(name, CAMERA, error_model=_error_model(), **SETTINGS)
    assert type(model) is type(make_sensor_model(name, focal_baseline=CAMERA.focal_baseline, **SETTINGS))


def test_a_plain_error_model_gives_the_plain_model():
    plain = ErrorModel("sgbm", {}, "test", 1 / 32, (_fit(WHOLE),), 2)
    model = conditioned_sensor_model("prism", CAMERA, error_model=plain, **SETTINGS)
    assert not isinstance(model, ConditionedModel)
    np.testing.assert_array_equal(model.error_model.sigmas, WHOLE.sigmas)


def test_bad_classes_and_arguments_are_named():
    model = conditioned_sensor_model("andert", CAMERA, error_model=_error_model(), **SETTINGS)
    disparity, norm, _, rays, start, end = _rays(n_rays=5, cells_per_ray=3)
    with pytest.raises(PrismapInputError, match=r"`ray_class` must lie in \[-1, 2\]"):
        model.cell_posteriors(disparity, norm, rays, start, end, ray_class=np.full(5, 3))
    with pytest.raises(PrismapInputError, match=r"`ray_class` must be \(5,\) integers"):
        model.influence_depth(disparity, norm, ray_class=np.zeros(5))
    with pytest.raises(PrismapInputError, match=r"`ray_class` must be \(5,\) integers"):
        model.cell_posteriors(disparity, norm, rays, start, end, ray_class=np.zeros(4, int))
    with pytest.raises(PrismapInputError, match="`error_model` must be an ErrorModel or a GaussianMixture"):
        conditioned_sensor_model("prism", CAMERA, error_model="model.json", **SETTINGS)
    other = make_sensor_model("andert", focal_baseline=CAMERA.focal_baseline, voxel_size_m=0.1, p0=0.05)
    with pytest.raises(PrismapInputError, match="differs from the plain model"):
        ConditionedModel(model.plain, (other,))
    with pytest.raises(PrismapInputError, match="is ConvolutionModel; expected AndertModel"):
        ConditionedModel(model.plain, (make_sensor_model("convolution", focal_baseline=1.0, **SETTINGS),))


def test_conditioned_prism_reports_the_far_depth_the_key_reach_check_reads():
    from prismap.camera import TSUKUBA_CAMERA
    from prismap.sensor_models import conditioned_sensor_model
    from support import conditioned_error_model

    error_model = conditioned_error_model()
    prism = conditioned_sensor_model(
        "prism", TSUKUBA_CAMERA, voxel_size_m=0.1, p0=0.1, error_model=error_model, far_depth_m=37.0
    )
    assert prism.far_depth_m == 37.0 == prism.plain.far_depth_m
    andert = conditioned_sensor_model("andert", TSUKUBA_CAMERA, voxel_size_m=0.1, p0=0.1, error_model=error_model)
    assert not hasattr(andert, "far_depth_m")


def test_conditioned_prism_gives_each_class_its_rays_overhangs():
    model = conditioned_sensor_model("prism", CAMERA, error_model=_error_model(), **SETTINGS)
    assert model.takes_voxel_overhang
    disparity, norm, ray_class, rays, start, end = _rays(seed=2)
    overhang = np.random.default_rng(5).uniform(0.0, 1.0, disparity.size)
    posterior, increment = model.cell_posteriors(
        disparity, norm, rays, start, end, ray_class=ray_class, voxel_overhang_m=overhang
    )
    for k in (-1, 0, 1, 2):
        mine = np.flatnonzero(ray_class == k)
        local = np.full(disparity.size, -1)
        local[mine] = np.arange(mine.size)
        cells = np.flatnonzero(np.isin(rays, mine))
        p, inc = model._model(k).cell_posteriors(
            disparity[mine], norm[mine], local[rays[cells]], start[cells], end[cells], voxel_overhang_m=overhang[mine]
        )
        np.testing.assert_array_equal(posterior[cells], p)
        np.testing.assert_array_equal(increment[cells], inc)
    without = model.cell_posteriors(disparity, norm, rays, start, end, ray_class=ray_class)[0]
    assert np.abs(without - posterior).max() > 1e-3
    plain = model.cell_posteriors(disparity, norm, rays, start, end, voxel_overhang_m=overhang)[0]
    np.testing.assert_array_equal(
        plain, model.plain.cell_posteriors(disparity, norm, rays, start, end, voxel_overhang_m=overhang)[0]
    )
    with pytest.raises(PrismapInputError, match="voxel_overhang_m"):
        model.cell_posteriors(disparity, norm, rays, start, end, ray_class=ray_class, voxel_overhang_m=overhang[:3])
    assert not conditioned_sensor_model("andert", CAMERA, error_model=_error_model(), **SETTINGS).takes_voxel_overhang


def test_class_pass_through_gives_each_class_its_own_and_equals_that_class_by_hand():
    values = (0.02, 0.3, 0.0)
    model = conditioned_sensor_model(
        "prism", CAMERA, error_model=_error_model(), pass_through=0.1, class_pass_through=values, **SETTINGS
    )
    assert [m.pass_through for m in model.class_models] == list(values) and model.plain.pass_through == 0.1
    disparity, norm, ray_class, rays, start, end = _rays(seed=3)
    posterior, increment = model.cell_posteriors(disparity, norm, rays, start, end, ray_class=ray_class)
    for k in (-1, 0, 1, 2):
        by_hand = conditioned_sensor_model(
            "prism",
            CAMERA,
            error_model=WHOLE if k < 0 else CLASS_MIXTURES[k],
            pass_through=0.1 if k < 0 else values[k],
            **SETTINGS,
        )
        cells = ray_class[rays] == k
        want = by_hand.cell_posteriors(disparity, norm, rays[cells], start[cells], end[cells])
        np.testing.assert_array_equal(posterior[cells], want[0])
        np.testing.assert_array_equal(increment[cells], want[1])
    # a thinner pass-through lets a ray's free evidence go deeper: class 2 (m = 0) below class 1 (m = 0.3)
    free = model.cell_posteriors(
        np.array([20.0, 20.0]),
        np.ones(2),
        np.array([0, 1]),
        np.full(2, 1.0),
        np.full(2, 1.1),
        ray_class=np.array([1, 2]),
    )[1]
    assert free[1] < free[0] < 0 and free[0] >= np.log(0.3) - 1e-12


def test_bad_class_pass_through_is_named():
    with pytest.raises(PrismapInputError, match=r"`class_pass_through` must hold one value per class \(3\); got 2"):
        conditioned_sensor_model("prism", CAMERA, error_model=_error_model(), class_pass_through=(0.1, 0.2), **SETTINGS)
    with pytest.raises(PrismapInputError, match="`class_pass_through` needs PRISM with a conditioned error model"):
        conditioned_sensor_model(
            "andert", CAMERA, error_model=_error_model(), class_pass_through=(0.1,) * 3, **SETTINGS
        )
    plain = ErrorModel("sgbm", {}, "test", 1 / 32, (_fit(WHOLE),), 2)
    with pytest.raises(PrismapInputError, match="`class_pass_through` needs PRISM with a conditioned error model"):
        conditioned_sensor_model("prism", CAMERA, error_model=plain, class_pass_through=(0.1,), **SETTINGS)
    with pytest.raises(PrismapInputError, match="pass_through"):
        conditioned_sensor_model(
            "prism", CAMERA, error_model=_error_model(), class_pass_through=(0.1, 1.0, 0.2), **SETTINGS
        )


def test_silent_rays_are_those_of_each_rays_class_model():
    """With matcher failures, a far ray is silent (influence depth 0: ``PrismModel.influence_depth``) by its own
    class's mixture: the fused look-up of the classes gives each ray its class model's influence depth, overhang
    included, and far rays of some classes are silent while those of others are not."""
    failing = [m.with_failure(0.1, (0.0, 64.0)) for m in (WHOLE, *CLASS_MIXTURES)]
    model = conditioned_sensor_model(
        "prism", CAMERA, error_model=_error_model(failing[0], failing[1:]), far_depth_m=150.0, **SETTINGS
    )
    assert model._classes.fused
    rng = np.random.default_rng(11)
    disparity = CAMERA.focal_baseline / np.geomspace(5.0, 140.0, 64)
    norm = 1.0 + rng.uniform(0.0, 0.2, disparity.size)
    ray_class = rng.integers(-1, 3, disparity.size)
    overhang = rng.uniform(0.0, 1.6, disparity.size)
    depth = model.influence_depth(disparity, norm, ray_class=ray_class, voxel_overhang_m=overhang)
    for k in (-1, 0, 1, 2):
        mine = np.flatnonzero(ray_class == k)
        own = model._model(k).influence_depth(disparity[mine], norm[mine], voxel_overhang_m=overhang[mine])
        np.testing.assert_array_equal(depth[mine], own)
    silent_classes = {int(k) for k in ray_class[depth == 0]}
    assert 0 < len(silent_classes) and np.any(depth[disparity < 1.0] > 0)
    with pytest.raises(PrismapInputError, match="voxel_overhang_m"):
        model._classes.fused = False
        model.influence_depth(disparity, norm, ray_class=ray_class, voxel_overhang_m=overhang[:3])
