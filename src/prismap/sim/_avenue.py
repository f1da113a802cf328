"""A second street world, the avenue: another layout, other textures and another rig than :mod:`prismap.sim._street`.

A model tuned on the street has to hold here. The frame and the drive are the street's (x along the avenue, y to
the left, z up, road surface at z = 0; :func:`prismap.sim.street_trajectory` drives its right-hand lane), so the
same poses serve both; everything seen differs: a wider road with a planted median, a continuous row of tall
façades with shop fronts on the left, a fence, a park and distant blocks on the right, a side street crossing,
vans, a bus shelter and a row of bollards, dressed in scikit-image photographs the street does not use
(:data:`~prismap.sim._textures.OTHER_PHOTOGRAPHS`, a checkerboard among them).
"""

from __future__ import annotations

import numpy as np

from prismap.sim._scene3d import Scene3D
from prismap.sim._street import STREET_LENGTH_M
from prismap.sim._textures import FIRST_OTHER, OTHER_PHOTOGRAPHS, PHOTOGRAPHS

AVENUE_ROAD_HALF_WIDTH_M = 6.5
"""Carriageway from y = -6.5 to 6.5 m (the drive's lane, y = -1.5 m, is the inner right one)."""

CROSSING_M = (40.0, 50.0)
"""x range of the side street crossing the avenue: no façade, fence or parked vehicle there."""


def avenue_scene(*, seed: int = 0) -> Scene3D:
    """The avenue: 84 m between a closing building at x = 84 m and the drive's start, seeded layout and looks.

    Contents: the road slab; a median of 1 m (kerb 0.2 m) at y = 1-2 m with a young tree (trunk and
    canopy box, canopy from 2.5 m up) every 9-13 m; on the left a pavement and a continuous row of 12-24 m
    tall façades 10-10.5 m from the centre line with ground-floor shop fronts set 0.4 m forward; on the right a
    pavement, a 1.2 m fence at y = -9.5 m, a park behind it with a few trees and blocks of flats 22-30 m away;
    a side street over :data:`CROSSING_M` with façades 40 m off on both sides; vans (2.1-2.6 m tall) and cars
    along the right kerb, a bus shelter and a row of bollards 1.5 m apart on the right pavement. Textures:
    :data:`~prismap.sim._textures.OTHER_PHOTOGRAPHS` and procedural noise.

    Parameters
    ----------
    seed : int
        Façade heights and looks, tree, vehicle and block placement, tints.

    Returns
    -------
    Scene3D
    """
    rng = np.random.default_rng(seed)
    tex = {name: FIRST_OTHER + i for i, name in enumerate(OTHER_PHOTOGRAPHS)}
    noise = len(PHOTOGRAPHS)
    photos = [FIRST_OTHER + i for i in range(len(OTHER_PHOTOGRAPHS))]
    length, road = STREET_LENGTH_M, AVENUE_ROAD_HALF_WIDTH_M
    cross_lo, cross_hi = CROSSING_M
    boxes = [  # (lo, hi, texture, texel_m, tint)
        ((-10.0, -45.0, -0.3), (length + 3.0, 45.0, 0.0), tex["moon"], 0.03, (0.5, 0.5, 0.52)),  # road and ground
        ((-10.0, 1.0, 0.0), (length, 2.0, 0.2), noise + 1, 0.04, (0.6, 0.75, 0.5)),  # median
        ((-10.0, road, 0.0), (length, 10.0, 0.12), tex["page"], 0.05, (0.8, 0.8, 0.78)),  # left pavement
        ((-10.0, -9.5, 0.0), (length, -road, 0.12), tex["coins"], 0.05, (0.8, 0.78, 0.75)),  # right pavement
        ((length, -30.0, 0.0), (length + 3.0, 30.0, 20.0), tex["hubble_deep_field"], 0.1, (0.9, 0.85, 0.8)),  # end
        ((cross_lo, 40.0, 0.0), (cross_hi, 42.0, 15.0), tex["retina"], 0.08, (0.9, 0.8, 0.8)),  # down the side street
        ((cross_lo, -42.0, 0.0), (cross_hi, -40.0, 15.0), tex["text"], 0.06, (0.85, 0.85, 0.9)),
    ]
    left_looks = [
        (tex["immunohistochemistry"], 0.06),
        (tex["retina"], 0.07),
        (tex["checkerboard"], 0.12),
        (tex["clock"], 0.05),
        (tex["cell"], 0.05),
        (noise + 2, 0.06),
    ]
    for start, end in ((-10.0, cross_lo), (cross_hi, length)):  # the left row, broken by the side street
        x = start
        while x < end:
            size = min(rng.uniform(10.0, 18.0), end - x)
            near = 10.0 + rng.uniform(0.0, 0.5)
            texture, texel = left_looks[int(rng.integers(len(left_looks)))]
            boxes.append(
                (
                    (x, near, 0.0),
                    (x + size, near + 3.0, rng.uniform(12.0, 24.0)),
                    texture,
                    texel,
                    rng.uniform(0.7, 1.0, 3),
                )
            )
            if size > 4.0:  # a shop front on the ground floor
                boxes.append(
                    (
                        (x + 1.0, near - 0.4, 0.0),
                        (x + size - 1.0, near, 3.5),
                        photos[int(rng.integers(10))],
                        0.02,
                        rng.uniform(0.6, 1.0, 3),
                    )
                )
            x += size
    for start, end in ((-10.0, cross_lo), (cross_hi, length)):
        boxes.append(((start, -9.6, 0.12), (end, -9.5, 1.2), noise + 3, 0.01, (0.45, 0.5, 0.45)))  # fence
    for _ in range(6):  # blocks of flats beyond the park
        x, depth = rng.uniform(-5.0, length - 15.0), rng.uniform(22.0, 30.0)
        if x + 15.0 > cross_lo and x < cross_hi:
            continue
        boxes.append(
            (
                (x, -depth - 8.0, 0.0),
                (x + rng.uniform(8.0, 15.0), -depth, rng.uniform(10.0, 25.0)),
                photos[int(rng.integers(10))],
                0.1,
                rng.uniform(0.6, 0.9, 3),
            )
        )
    for _ in range(5):  # park trees
        x, y = rng.uniform(0.0, length - 10.0), -rng.uniform(12.0, 20.0)
        boxes.append(((x - 0.15, y - 0.15, 0.0), (x + 0.15, y + 0.15, 3.0), noise, 0.02, (0.45, 0.35, 0.3)))
        boxes.append(((x - 1.5, y - 1.5, 3.0), (x + 1.5, y + 1.5, 6.0), tex["cell"], 0.03, (0.4, 0.7, 0.35)))
    x = rng.uniform(2.0, 6.0)
    while x < length - 6.0:  # median trees, clear of the side street
        if not cross_lo - 2.0 < x < cross_hi + 2.0:
            boxes.append(((x - 0.1, 1.4, 0.2), (x + 0.1, 1.6, 2.5), noise, 0.02, (0.45, 0.35, 0.3)))
            boxes.append(((x - 1.0, 1.05, 2.5), (x + 1.0, 1.95, 4.5), tex["cell"], 0.03, (0.45, 0.75, 0.4)))
        x += rng.uniform(9.0, 13.0)
    x = rng.uniform(4.0, 10.0)
    while x < length - 10.0:  # vans and cars along the right kerb
        if cross_lo - 6.0 < x < cross_hi:
            x = cross_hi + 1.0
            continue
        van = rng.random() < 0.5
        size, height = (rng.uniform(5.0, 6.0), rng.uniform(2.1, 2.6)) if van else (rng.uniform(3.9, 4.5), 1.45)
        texture, tint = photos[int(rng.integers(10))], rng.uniform(0.35, 1.0, 3)
        boxes.append(((x, -road + 0.3, 0.25), (x + size, -road + 2.2, height), texture, 0.025, tint))
        x += size + rng.uniform(1.5, 10.0)
    shelter = rng.uniform(10.0, 25.0)
    boxes.append(((shelter, -9.3, 0.12), (shelter + 4.0, -9.2, 2.5), tex["text"], 0.01, (0.9, 0.9, 1.0)))  # back
    boxes.append(((shelter, -9.3, 2.5), (shelter + 4.0, -7.6, 2.65), noise + 1, 0.02, (0.7, 0.7, 0.75)))  # roof
    for x in np.arange(55.0, 70.0, 1.5):  # bollards: a repeated structure
        boxes.append(
            ((x - 0.1, -road - 0.5, 0.12), (x + 0.1, -road - 0.3, 1.0), tex["checkerboard"], 0.01, (0.8, 0.8, 0.8))
        )
    lo, hi, texture, texel, tint = (np.array(column) for column in zip(*boxes))
    return Scene3D(lo, hi, texture, texel, tint, name=f"avenue-{seed}")
