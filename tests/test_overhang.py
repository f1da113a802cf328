"""Voxel overhang: plane normals from disparity, the overhang bound, PRISM's occupied event, a grazing floor."""

import numpy as np
import pytest

from prismap.camera import (
    OVERHANG_CAP_VOXELS,
    StereoCamera,
    frame_overhang_m,
    integrate_disparity,
    plane_normals,
    voxel_overhang_m,
)
from prismap.camera._frame_batch import rotate_rays
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.grid import OccupancyMap
from prismap.sensor_models import make_sensor_model
from prismap.sensor_models._prism import TABLE_TOLERANCE
from support import assert_same_map

CAMERA = StereoCamera(500.0, 160.0, 120.0, 0.1, width=320, height=240)
MIXTURE = GaussianMixture([0.9, 0.1], [0.0, -0.5], [0.3, 3.0])


def _plane_disparity(normal, h, camera=CAMERA, shape=(240, 320)):
    """Disparity of the plane ``n . P = h`` (camera frame), NaN where it is behind the camera or nearly so."""
    v, u = np.mgrid[: shape[0], : shape[1]].astype(np.float64)
    ray_dot = (normal[0] * (u - camera.cx_px) + normal[1] * (v - camera.cy_px)) / camera.focal_px + normal[2]
    d = camera.focal_baseline / h * ray_dot - camera.doffs_px
    return np.where(d > 0.5, d, np.nan)


@pytest.mark.parametrize("normal", [(0.0, 1.0, 0.0), (0.1, 1.0, 0.3), (-0.4, 0.2, 1.0)])
def test_plane_normals_recover_the_plane_facing_the_camera(normal):
    n = np.asarray(normal) / np.linalg.norm(normal)
    disparity = _plane_disparity(n, 1.5)
    got = plane_normals(disparity, CAMERA)
    fitted = np.isfinite(got[..., 0])
    assert fitted.mean() > 0.4
    np.testing.assert_allclose(got[fitted], np.broadcast_to(-n, got[fitted].shape), atol=1e-6)  # summed-area rounding
    rays = CAMERA.pixel_rays(disparity.shape)
    assert np.all(np.einsum("...i,...i->...", got[fitted], rays[fitted]) < 0)


def _brute_force_normals(disparity, camera, window, step):
    """Each fitted pixel's normal from a least-squares plane over the valid pixels of its window, by numpy."""
    d = disparity + camera.doffs_px
    half, (height, width) = window // 2, d.shape
    out = np.full((-(-height // step), -(-width // step), 3), np.nan)
    for i, y in enumerate(range(0, height, step)):
        for j, x in enumerate(range(0, width, step)):
            if not d[y, x] > 0:
                continue
            y0, y1, x0, x1 = max(y - half, 0), min(y + half + 1, height), max(x - half, 0), min(x + half + 1, width)
            v, u = np.mgrid[y0:y1, x0:x1]
            valid = d[y0:y1, x0:x1] > 0
            if valid.sum() < 0.5 * valid.size:
                continue
            coords = np.stack([u[valid], v[valid]], axis=1).astype(float)
            cov = np.cov(np.column_stack([coords, d[y0:y1, x0:x1][valid]]).T, bias=True)
            if np.linalg.det(cov[:2, :2]) <= 1e-6:
                continue
            alpha, beta = np.linalg.solve(cov[:2, :2], cov[:2, 2])
            gamma = (d[y, x] - alpha * (x - camera.cx_px) - beta * (y - camera.cy_px)) / camera.focal_px
            normal = np.array([alpha, beta, gamma])
            out[i, j] = -normal / np.linalg.norm(normal)
    return out


@pytest.mark.parametrize(("window", "step"), [(7, 1), (5, 3), (3, 2)])
def test_plane_normals_equal_a_least_squares_fit_on_each_window(window, step):
    """Rough disparities with holes (every window's own fit, edges and subsampled rows included) against numpy's
    fit of the window's valid pixels."""
    rng = np.random.default_rng(7)
    camera = StereoCamera(300.0, 20.0, 15.0, 0.1, width=41, height=29)
    disparity = 20.0 + 0.3 * np.arange(41)[None, :] - 0.2 * np.arange(29)[:, None] + rng.normal(0, 0.5, (29, 41))
    disparity[rng.random((29, 41)) < 0.2] = np.nan
    disparity[5:9, 10:30] = np.nan
    got = plane_normals(disparity, camera, window_px=window, subsample=step)
    want = _brute_force_normals(disparity, camera, window, step)
    assert np.isfinite(want[..., 0]).mean() > 0.5
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got[np.isfinite(got)], want[np.isfinite(want)], atol=1e-8)


def test_plane_normals_refuse_what_they_cannot_fit():
    disparity = _plane_disparity(np.array([0.0, 0.0, 1.0]), 4.0)
    disparity[50, 50] = np.nan
    disparity[100:, :] = np.nan
    disparity[10:40:3, 200:240] = np.nan  # two or three rows of each window invalid: still fitted
    got = plane_normals(disparity, CAMERA)
    assert np.isnan(got[50, 50]).all() and np.isnan(got[150, 10]).all()
    assert np.isfinite(got[20, 220]).all()
    one_row = np.full((240, 320), np.nan)
    one_row[60, :] = 20.0  # collinear pixels: no plane
    assert np.isnan(plane_normals(one_row, CAMERA)).all()
    with pytest.raises(PrismapInputError, match="window_px"):
        plane_normals(disparity, CAMERA, window_px=4)
    with pytest.raises(PrismapInputError, match=r"\(H, W\)"):
        plane_normals(disparity[0], CAMERA)


def test_overhang_bound_by_hand():
    v = 0.1
    R = np.eye(3)
    # a floor (normal +z) seen by a ray at cos(theta) = 0.2; a wall head on; a 45-degree wall head on; no normal
    normals = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [np.sqrt(0.5), np.sqrt(0.5), 0.0], [np.nan] * 3])
    rays = np.array([[np.sqrt(0.96), 0.0, -0.2], [-1.0, 0.0, 0.0], [-1.0, -1.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(voxel_overhang_m(normals, rays, R, v), [v / 0.2, v, v * np.sqrt(2), 0.0])
    grazing = voxel_overhang_m(np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, -1e-4]]), R, v)
    assert grazing[0] == OVERHANG_CAP_VOXELS * v
    # the world rotation matters (voxels are world-aligned), the camera's does not change cos(theta)
    c, s = np.cos(0.3), np.sin(0.3)
    turned = voxel_overhang_m(normals[1:2], rays[1:2], np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), v)
    np.testing.assert_allclose(turned, v * (c + s))


def test_no_voxel_beyond_the_bound_holds_the_plane():
    """Brute force: voxels a ray leaves t before a random plane and that the plane cuts all have t <= bound."""
    rng = np.random.default_rng(7)
    v = 0.1
    worst = 0.0
    for _ in range(300):
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        r = rng.normal(size=3)
        r -= 2 * min(r @ n, 0) * n  # the ray runs toward the plane's front side... then flip the normal
        r /= np.linalg.norm(r)
        if abs(r @ n) < 0.05:
            continue
        normal = -n if r @ n > 0 else n  # facing the ray
        hit = rng.uniform(0.0, 1.0, 3) + 3.0 * r
        bound = voxel_overhang_m(normal[None], r[None], np.eye(3), v, cap_voxels=1e9)[0]
        for t in np.linspace(0.0, 1.2 * bound, 60)[1:]:
            key = np.floor((hit - t * r) / v)
            corners = (key + np.array(np.meshgrid([0, 1], [0, 1], [0, 1])).reshape(3, -1).T) * v
            side = (corners - hit) @ normal
            exit_t = t  # the point lies inside the voxel: the ray leaves it no later than t before the hit
            if side.min() <= 0 <= side.max():
                assert exit_t <= bound + 1e-9
                worst = max(worst, exit_t / bound)
    assert worst > 0.6  # the bound is not loose by orders of magnitude


def _prism(**kw):
    return make_sensor_model(
        "prism", focal_baseline=CAMERA.focal_baseline, error_model=MIXTURE, voxel_size_m=0.1, p0=0.05, **kw
    )


def _cells(seed=0, n_rays=30, cells_per_ray=40):
    rng = np.random.default_rng(seed)
    depth = np.exp(rng.uniform(np.log(0.8), np.log(25.0), n_rays))
    disparity = np.round(CAMERA.focal_baseline / depth * 16) / 16
    norm = rng.uniform(1.0, 1.3, n_rays)
    rays = np.repeat(np.arange(n_rays), cells_per_ray)
    edges = [np.sort(rng.uniform(0.2, 2.0 * z + 1.0, cells_per_ray + 1)) for z in depth]
    start = np.concatenate([e[:-1] for e in edges])
    end = np.concatenate([e[1:] for e in edges])
    overhang = rng.uniform(0.0, 0.8, n_rays)
    return disparity, norm, rays, start, end, overhang


@pytest.mark.parametrize("method", ["direct", "table"])
def test_prism_overhang_evaluates_the_extended_stretch(method):
    """Cell [a, c] with overhang o is the cell [a, c + f o / |r|]: posterior and increment (against its own prior)."""
    fraction = 0.25
    model = _prism(overhang_fraction=fraction, method=method)
    disparity, norm, rays, start, end, overhang = _cells()
    post, inc = model.cell_posteriors(disparity, norm, rays, start, end, voxel_overhang_m=overhang)
    extended = end + fraction * overhang[rays] / norm[rays]
    post_ext, inc_ext = model.cell_posteriors(disparity, norm, rays, start, extended)
    np.testing.assert_array_equal(post, post_ext)
    np.testing.assert_array_equal(inc, inc_ext)
    p_ext = -np.expm1(-model.rate_per_m * norm[rays] * (extended - start))
    moderate = (post > 1e-6) & (post < 1 - 1e-6) & (p_ext > 1e-9)
    logit = np.log(post[moderate] / (1 - post[moderate])) - np.log(p_ext[moderate] / (1 - p_ext[moderate]))
    np.testing.assert_allclose(inc[moderate], logit, rtol=1e-6, atol=1e-6)
    changed = np.abs(post - model.cell_posteriors(disparity, norm, rays, start, end)[0])
    assert changed.max() > 0.05


def test_prism_overhang_table_agrees_with_direct_and_zero_changes_nothing():
    disparity, norm, rays, start, end, overhang = _cells(seed=1)
    model = _prism()
    p_table, inc_table = model.cell_posteriors(disparity, norm, rays, start, end, voxel_overhang_m=overhang)
    p_direct, inc_direct = model.cell_posteriors(
        disparity, norm, rays, start, end, voxel_overhang_m=overhang, method="direct"
    )
    assert np.abs(p_table - p_direct).max() <= TABLE_TOLERANCE["posterior"]
    moderate = np.abs(inc_direct) <= TABLE_TOLERANCE["large"]
    assert np.all(
        np.abs(inc_table - inc_direct)[moderate]
        <= TABLE_TOLERANCE["abs"] + TABLE_TOLERANCE["rel"] * np.abs(inc_direct[moderate])
    )
    plain = model.cell_posteriors(disparity, norm, rays, start, end)
    for zero in (np.zeros_like(overhang), overhang):
        off = _prism(overhang_fraction=0.0) if zero is overhang else model
        got = off.cell_posteriors(disparity, norm, rays, start, end, voxel_overhang_m=zero)
        np.testing.assert_array_equal(got[0], plain[0])
        np.testing.assert_array_equal(got[1], plain[1])
    assert model.takes_voxel_overhang and not _prism(overhang_fraction=0.0).takes_voxel_overhang


def test_prism_overhang_bad_input_is_named():
    disparity, norm, rays, start, end, overhang = _cells()
    for bad in (-0.1, 1.5, True, "0.2"):
        with pytest.raises(PrismapInputError, match="overhang_fraction"):
            _prism(overhang_fraction=bad)
    with pytest.raises(PrismapInputError, match="voxel_overhang_m"):
        _prism().cell_posteriors(disparity, norm, rays, start, end, voxel_overhang_m=-overhang)
    with pytest.raises(PrismapInputError, match="voxel_overhang_m"):
        _prism().cell_posteriors(disparity, norm, rays, start, end, voxel_overhang_m=overhang[:-1])
    grid = OccupancyMap(0.1, p0=0.05)
    with pytest.raises(PrismapInputError, match="voxel_overhang_m"):
        grid.integrate_rays(
            np.zeros(3), np.array([[0.0, 0.0, 1.0]]), np.array([20.0]), _prism(), voxel_overhang_m=np.array([np.inf])
        )


def _floor_frame(camera, height_m, floor_z_m):
    """Disparity of a flat floor seen by a level camera ``height_m`` above it, and the camera -> world pose.

    World: z up, x forward; camera: x right, y down, z forward.
    """
    disparity = _plane_disparity(np.array([0.0, 1.0, 0.0]), height_m, camera, (camera.height, camera.width))
    pose = np.eye(4)
    pose[:3, :3] = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
    pose[:3, 3] = [0.05, 0.05, floor_z_m + height_m]
    return disparity, pose


def test_a_grazing_floor_stays_in_the_map_without_a_false_layer_above():
    """A floor through voxel middles 1.2 m below a wide-angle camera, seen from 1.6 m on, one frame: with the
    overhang the floor layer's voxels come out more occupied, and the layer above (free) stays below the prior."""
    camera = StereoCamera(80.0, 80.0, 60.0, 0.3, width=160, height=120)
    disparity, pose = _floor_frame(camera, 1.2, 0.05)
    normals = plane_normals(disparity, camera)
    assert np.nanmax(np.abs(normals @ pose[:3, :3].T - [0.0, 0.0, 1.0])) < 1e-6
    rays_cam = camera.pixel_rays(disparity.shape).reshape(-1, 3)
    fitted = np.isfinite(normals.reshape(-1, 3)[:, 0])
    expected = 0.1 * np.linalg.norm(rays_cam[fitted], axis=1) / np.abs(rays_cam[fitted, 1])
    got = frame_overhang_m(disparity, camera, pose[:3, :3], 0.1, 1, rays_cam)
    np.testing.assert_allclose(got[fitted], np.minimum(expected, 0.8), rtol=1e-8)
    means = {}
    for fraction in (0.0, 0.25):
        grid = OccupancyMap(0.1, p0=0.05)
        model = make_sensor_model(
            "prism",
            focal_baseline=camera.focal_baseline,
            error_model=GaussianMixture.gaussian(0.2),
            voxel_size_m=0.1,
            p0=0.05,
            overhang_fraction=fraction,
        )
        integrate_disparity(grid, disparity, camera, pose, model, max_range_m=8.0)
        keys = grid.known_voxels()[0]
        p = grid.probability_at_keys(keys)
        ahead = (keys[:, 0] >= 16) & (keys[:, 0] < 40)  # 1.6-4 m ahead: grazing (cos 0.29-0.6)
        means[fraction] = (p[ahead & (keys[:, 2] == 0)].mean(), p[ahead & (keys[:, 2] == 1)].mean())
    floor_off, above_off = means[0.0]
    floor_on, above_on = means[0.25]
    assert floor_on > floor_off + 0.05
    assert above_off < above_on < 0.05  # raised a little (noise), still below the prior: no false layer


def test_integrate_disparity_gives_the_overhang_it_fits_to_the_model_as_integrate_rays_would():
    """The plane fits run beside the frame's set-up (a background thread); the map equals one integrated from
    the same rays with the overhang given, invalid pixels included; a given overhang is checked."""
    camera = StereoCamera(80.0, 80.0, 60.0, 0.3, width=160, height=120)
    disparity, pose = _floor_frame(camera, 1.2, 0.05)
    disparity[:10, :30] = np.nan  # dropped rays: the overhang follows the kept ones
    model = make_sensor_model(
        "prism",
        focal_baseline=camera.focal_baseline,
        error_model=GaussianMixture.gaussian(0.2),
        voxel_size_m=0.1,
        p0=0.05,
        overhang_fraction=0.25,
    )
    fitted, given = OccupancyMap(0.1, p0=0.05), OccupancyMap(0.1, p0=0.05)
    integrate_disparity(fitted, disparity, camera, pose, model, max_range_m=8.0, floor_rays=0)  # as integrate_rays
    rays_cam = camera.pixel_rays(disparity.shape).reshape(-1, 3)
    overhang = frame_overhang_m(disparity, camera, pose[:3, :3], 0.1, 1, rays_cam)
    rays_w = rotate_rays(rays_cam, np.ascontiguousarray(pose[:3, :3]))  # as integrate_disparity rotates them
    given.integrate_rays(pose[:3, 3], rays_w, disparity.reshape(-1), model, max_range_m=8.0, voxel_overhang_m=overhang)
    assert fitted.n_known > 1000
    assert_same_map(fitted, given)
    bad = overhang.copy()
    bad[np.flatnonzero(np.isfinite(disparity.reshape(-1)))[0]] = -0.1
    with pytest.raises(PrismapInputError, match="`voxel_overhang_m` must be finite and >= 0 at every valid ray"):
        given.integrate_rays(pose[:3, 3], rays_w, disparity.reshape(-1), model, max_range_m=8.0, voxel_overhang_m=bad)
