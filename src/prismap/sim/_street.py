"""A KITTI-like street of axis-aligned boxes: road, façades, parked cars, poles and blocks, and a drive along it.

World frame: metres, z up, x along the street (the direction of travel), y to the left, the road surface at
z = 0 and the street's centre line at y = 0. Cameras use OpenCV axes and ``T_world_cam`` poses (see
:mod:`prismap.sim._poses`); the scene is a :class:`~prismap.sim.Scene3D`, so it renders and voxelises like
the indoor room. The road, pavements and façades lie at round coordinates; to keep those planes off voxel
faces, shift scene and poses by half a voxel as the experiments do (``run_street3d(grid_offset=0.5)``).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from prismap._validate import check_integer, check_real
from prismap.errors import PrismapInputError
from prismap.sim._poses import pose_from_heading
from prismap.sim._scene3d import Scene3D
from prismap.sim._textures import FIRST_OTHER, PHOTOGRAPHS

STREET_LENGTH_M = 84.0
"""The street runs from x = 0 to this; a building closes it across its far end, 80 m from the first pose."""

ROAD_HALF_WIDTH_M = 5.0
"""Carriageway from y = -5 to 5 m; pavements (kerb height 0.15 m) from there to the façades."""

FACADE_Y_M = 8.0
"""Distance of the nearest façade line from the centre line (façades are set back by up to 1.5 m more)."""

BUILDING_DEPTH_M = 2.0
"""Depth of every building behind its façade: only façades are seen, and thin solids keep the voxelised truth
small at fine voxels."""

CAMERA_HEIGHT_M = 1.65
"""Height of the left camera above the road (KITTI's rig)."""

LANE_Y_M = -1.5
"""Centre of the right-hand lane the camera drives in."""

DRIVE_START_M = 4.0
"""x of the first camera position."""


def street_scene(*, seed: int = 0) -> Scene3D:
    """A straight street, 84 m long between façades 8-9.5 m either side of its centre line.

    Contents: the road slab and two pavements, a row of buildings of seeded length (8-20 m), height
    (6-18 m), set-back (0-1.5 m) and a depth of 2 m on each side, a building across the far end at x = 84 m, parked cars (a body and
    a cabin box, 3.8-4.6 m long) along both kerbs, street-light poles every 14 m on both pavements, and
    seeded blocks (bins, bollards, boxes of 0.4-1.2 m) on the pavements. Textures come from
    :func:`~prismap.sim.texture_bank` (scikit-image's photographs and procedural noise). From the lane of
    :func:`street_trajectory` surfaces lie 2 to more than 80 m away; above the buildings is sky.

    Parameters
    ----------
    seed : int
        Building sizes, car and block placement, textures and tints.

    Returns
    -------
    Scene3D

    Examples
    --------
    A full-size KITTI-like sequence with exact disparity, poses and voxelised truth:

    >>> from prismap import sim
    >>> scene = sim.street_scene(seed=0)
    >>> camera = sim.kitti_camera()  # 1242x375; kitti_camera(scale=0.5) for 621x188
    >>> poses = sim.street_trajectory(10, seed=0)  # T_world_cam, 1 m apart
    >>> frames = list(scene.frames(camera, poses, seed=0))  # StereoFrame: left, right, disparity_gt, T_world_cam
    >>> truth = scene.ground_truth(frames, 0.1, max_depth_m=80.0)  # GroundTruthOccupancy
    """
    rng = np.random.default_rng(seed)
    tex = {name: i for i, name in enumerate(PHOTOGRAPHS)}
    noise = len(PHOTOGRAPHS)
    n_textures = FIRST_OTHER
    length, road, facade = STREET_LENGTH_M, ROAD_HALF_WIDTH_M, FACADE_Y_M
    depth = BUILDING_DEPTH_M
    back = facade + 1.5 + depth  # the back of the most set-back building
    boxes = [  # (lo, hi, texture, texel_m, tint)
        ((-10.0, -back, -0.3), (length + depth, back, 0.0), tex["gravel"], 0.03, (0.55, 0.55, 0.6)),  # road
        ((-10.0, road, 0.0), (length, facade + 1.5, 0.15), noise, 0.05, (0.85, 0.8, 0.75)),  # left pavement
        ((-10.0, -facade - 1.5, 0.0), (length, -road, 0.15), noise, 0.05, (0.85, 0.8, 0.75)),  # right pavement
        ((length, -back, 0.0), (length + depth, back, 14.0), tex["brick"], 0.08, (0.9, 0.75, 0.65)),  # far end
    ]
    facade_looks = [
        (tex["brick"], 0.05),
        (tex["coffee"], 0.04),
        (tex["rocket"], 0.05),
        (tex["chelsea"], 0.04),
        (tex["astronaut"], 0.05),
        (noise + 1, 0.05),
        (noise + 2, 0.06),
        (tex["camera"], 0.04),
    ]
    for side in (1.0, -1.0):  # a row of buildings on each side
        x = -10.0
        while x < length:
            size = rng.uniform(8.0, 20.0)
            height = rng.uniform(6.0, 18.0)
            near = facade + rng.uniform(0.0, 1.5)
            texture, texel = facade_looks[int(rng.integers(len(facade_looks)))]
            y0, y1 = sorted((side * near, side * (near + depth)))
            boxes.append(((x, y0, 0.0), (min(x + size, length), y1, height), texture, texel, rng.uniform(0.7, 1.0, 3)))
            x += size
    for side in (1.0, -1.0):  # parked cars along both kerbs
        x = rng.uniform(2.0, 8.0)
        while x < length - 8.0:
            car_length, width = rng.uniform(3.8, 4.6), rng.uniform(1.7, 1.9)
            y_kerb = side * (road - 0.3)
            y0, y1 = sorted((y_kerb, y_kerb - side * width))
            texture, tint = int(rng.integers(n_textures)), rng.uniform(0.3, 1.0, 3)
            boxes.append(((x, y0, 0.2), (x + car_length, y1, 0.95), texture, 0.02, tint))  # body
            inset = 0.6
            boxes.append(
                ((x + inset + 0.3, y0 + 0.1, 0.95), (x + car_length - inset, y1 - 0.1, 1.5), texture, 0.02, 0.6 * tint)
            )  # cabin
            x += car_length + rng.uniform(1.0, 9.0)
    for side in (1.0, -1.0):  # street-light poles
        for x in np.arange(7.0, length - 3.0, 14.0):
            y = side * (road + 0.6)
            boxes.append(((x - 0.08, y - 0.08, 0.15), (x + 0.08, y + 0.08, 6.0), noise + 3, 0.01, (0.6, 0.6, 0.65)))
    for _ in range(16):  # blocks on the pavements
        side = 1.0 if rng.random() < 0.5 else -1.0
        size = rng.uniform([0.4, 0.4, 0.4], [1.2, 1.2, 1.2])
        x = rng.uniform(0.0, length - 2.0)
        y = side * rng.uniform(road + 1.0, facade - size[1] - 0.2)
        texture, texel, tint = int(rng.integers(n_textures)), rng.uniform(0.005, 0.02), rng.uniform(0.5, 1.0, 3)
        boxes.append(((x, y, 0.15), (x + size[0], y + size[1], 0.15 + size[2]), texture, texel, tint))
    lo, hi, texture, texel, tint = (np.array(column) for column in zip(*boxes))
    return Scene3D(lo, hi, texture, texel, tint, name=f"street-{seed}")


def street_trajectory(
    n_frames: int = 12, *, step_m: float = 1.0, seed: int = 0, start_m: float = DRIVE_START_M
) -> npt.NDArray[np.float64]:
    """A drive along :func:`street_scene`'s right-hand lane, forward ``step_m`` per frame, weaving a little.

    The left camera is 1.65 m above the road, starts at x = ``start_m`` and moves ``step_m`` along +x per frame
    (KITTI at 10 Hz and 36 km/h), within 0.3 m of the lane centre (y = -1.5 m), looking along the road with
    a seeded yaw of up to +-6 degrees (following the weave, plus a slow look-around) and a pitch of 1-2
    degrees down. The weave, yaw and pitch are functions of x, so drives of one seed with other starts or
    steps follow the same path: a second drive with ``start_m`` half a step on sees the street from the
    positions between the first one's (separate frames to characterise a matcher on).

    Parameters
    ----------
    n_frames : int >= 1
    step_m : float, metres, in (0, 5]
        Forward motion per frame; the drive must end 30 m before the building closing the street.
    start_m : float, metres, >= 0
        x of the first camera position.
    seed : int
        Phase of the weave and of the yaw.

    Returns
    -------
    T_world_cam : (n_frames, 4, 4) float64
    """
    n_frames = check_integer(n_frames, "n_frames", expected="a positive integer", condition=lambda n: n >= 1)
    step = float(step_m)
    if not 0.0 < step <= 5.0:
        raise PrismapInputError(f"`step_m` must lie in (0, 5] metres; got {step_m!r}")
    start = check_real(start_m, "start_m", minimum=0.0)
    n = int(n_frames)
    end = start + step * (n - 1)
    if end > STREET_LENGTH_M - 30.0:
        raise PrismapInputError(
            f"{n} frames of {step} m end at x = {end:g} m: the street allows up to "
            f"x = {STREET_LENGTH_M - 30.0:g} m (fewer frames or a shorter `step_m`)"
        )
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0.0, 2.0 * np.pi, 2)
    x = start + step * np.arange(n)
    wavelength = 25.0
    y = LANE_Y_M + 0.3 * np.sin(2.0 * np.pi * x / wavelength + phase[0])
    slope = 0.3 * 2.0 * np.pi / wavelength * np.cos(2.0 * np.pi * x / wavelength + phase[0])
    heading = np.arctan(slope) + np.radians(1.5) * np.sin(2.0 * np.pi * x / 40.0 + phase[1])
    pitch = np.radians(1.5 + 0.5 * np.sin(2.0 * np.pi * x / 17.0 + phase[1]))
    return np.array(
        [pose_from_heading((a, b, CAMERA_HEIGHT_M), h, pitch_rad=p) for a, b, h, p in zip(x, y, heading, pitch)]
    )


def street_trajectory_between(
    n_frames: int, n_between: int, *, step_m: float = 1.0, seed: int = 0
) -> npt.NDArray[np.float64]:
    """``n_between`` poses spread evenly over the stretch of ``street_trajectory(n_frames, step_m=step_m)``.

    The same path (weave, yaw and pitch follow x), ``n_between`` positions ``n_frames * step_m / n_between``
    apart starting half such a step after the drive's first: frames of the same street the drive does not
    see from, to characterise a matcher on before mapping the drive.

    Parameters
    ----------
    n_frames : int >= 1
        Frames of the drive whose stretch is covered.
    n_between : int >= 1
    step_m : float, metres
        The drive's step.
    seed : int
        The drive's seed.

    Returns
    -------
    T_world_cam : (n_between, 4, 4) float64
    """
    n = check_integer(n_frames, "n_frames", expected="a positive integer", condition=lambda k: k >= 1)
    step = (
        n
        * check_real(step_m, "step_m", minimum=0.0)
        / check_integer(n_between, "n_between", expected="a positive integer", condition=lambda k: k >= 1)
    )
    return street_trajectory(n_between, step_m=step, start_m=DRIVE_START_M + 0.5 * step, seed=seed)
