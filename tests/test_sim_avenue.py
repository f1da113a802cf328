"""The avenue, the second street world: its rig, a hand-computed disparity, other textures, seeds."""

import numpy as np
import pytest

from prismap import sim
from prismap.sim._street import CAMERA_HEIGHT_M, DRIVE_START_M, STREET_LENGTH_M
from prismap.sim._textures import FIRST_OTHER, OTHER_PHOTOGRAPHS


def test_avenue_rig():
    rig = sim.avenue_camera()
    assert (rig.width, rig.height, rig.focal_px, rig.baseline_m) == (620, 188, 358.0, 0.54)
    half = sim.avenue_camera(scale=0.5)
    assert (half.width, half.height, half.focal_px) == (310, 94, 179.0)


def test_the_closing_building_is_at_its_hand_computed_depth():
    scene = sim.avenue_scene(seed=0)
    rig = sim.avenue_camera()
    position = np.array([DRIVE_START_M, -1.5, CAMERA_HEIGHT_M])
    frame = scene.render(rig, sim.pose_from_heading(position, 0.0), noise_sigma=0.0)
    # the principal point's ray runs straight along the lane to the fronto-parallel building at x = 84 m
    assert frame.extras["depth_m"][92, 311] == pytest.approx(STREET_LENGTH_M - DRIVE_START_M, rel=1e-9)
    assert frame.disparity_gt[92, 311] == pytest.approx(358.0 * 0.54 / 80.0, rel=1e-6)


def test_the_avenue_wears_only_its_own_photographs_and_noise():
    scene = sim.avenue_scene(seed=3)
    texture = scene.box_texture
    photographs = texture[texture >= len(sim.PHOTOGRAPHS)]
    assert np.all((texture >= len(sim.PHOTOGRAPHS)) & (texture < FIRST_OTHER + len(OTHER_PHOTOGRAPHS)))
    assert np.count_nonzero(photographs >= FIRST_OTHER) >= 10
    assert len(sim.texture_bank()) == FIRST_OTHER + len(OTHER_PHOTOGRAPHS)


def test_seeded_and_unlike_the_street():
    a, b = sim.avenue_scene(seed=1), sim.avenue_scene(seed=1)
    np.testing.assert_array_equal(a.box_lo, b.box_lo)
    assert not np.array_equal(sim.avenue_scene(seed=2).box_hi[:20], a.box_hi[:20]) or len(a.box_lo) != len(
        sim.avenue_scene(seed=2).box_lo
    )
    small = sim.avenue_camera(scale=0.25)
    poses = sim.street_trajectory(6, seed=1)
    avenue = np.concatenate([a.cast(small, pose).ravel() for pose in poses])
    street = np.concatenate([sim.street_scene(seed=1).cast(small, pose).ravel() for pose in poses])
    hit = avenue[np.isfinite(avenue)]
    assert 2.0 < hit.min() < 5.0 and hit.max() > 40.0  # the side street and the park reach far
    assert np.mean(np.abs(avenue - street) > 0.5) > 0.3  # another layout, not the street re-dressed
