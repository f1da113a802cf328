"""The rendered worlds of the 3-D experiments (the indoor room, the street): what each run needs to know of its
world, its full and quick sizes, and the settings of a run on it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from prismap._validate import check_integer, check_positive
from prismap.errors import PrismapInputError

MATCHERS = ("bm", "sgbm", "variational")
"""Every matcher the 3-D experiments characterise and map with, in the order of the tables."""


@dataclass(frozen=True)
class RenderedWorld:
    """What a 3-D experiment needs to know of its world; the run itself is :func:`run_rendered_world`.

    Attributes
    ----------
    name : str
        ``settings["world"]`` and the experiment's name (``"scene3d"``, ``"street3d"``).
    title : str
        Heading of the results table.
    sizes : dict of bool -> dict
        Full (False) and ``quick`` (True) sizes: ``n_frames`` rendered along the drive,
        ``between_frames`` (extra characterisation frames from positions between the drive's; 0 without
        ``between_trajectory``), ``image_scale`` of the camera,
        ``voxel_size_m``, ``subsample`` (pixel step when mapping), ``max_range_m``, the integration
        ``mode`` of :class:`prismap.pipeline.MappingConfig`, and ``model_params`` (model name -> its
        extra parameters; models not named get their defaults).
    scene : callable
        ``scene(seed) -> Scene3D``.
    trajectory : callable
        ``trajectory(n_frames, seed) -> (N, 4, 4) T_world_cam``.
    between_trajectory : callable or None
        ``between_trajectory(n_frames, n_between, seed) -> (n_between, 4, 4) T_world_cam``: a second drive
        over the same stretch whose positions the drive of ``n_frames`` does not use; None = none.
    camera : callable
        ``camera(scale) -> StereoCamera``.
    slice_height_m : float, metres
        Height of the horizontal map slice drawn in the figures.
    description : str
        First words of the table's notes (the scene and camera).
    """

    name: str
    title: str
    sizes: dict
    scene: object
    trajectory: object
    camera: object
    slice_height_m: float
    description: str
    between_trajectory: object = None


def _scene3d_world():
    from prismap import sim

    return RenderedWorld(
        "scene3d",
        "3-D indoor scene, characterised matchers",
        {
            False: {
                "n_frames": 40,
                "between_frames": 0,
                "image_scale": 1.0,
                "voxel_size_m": 0.1,
                "subsample": 2,
                "max_range_m": 10.0,
                "mode": "ray",
                "model_params": {},
            },
            True: {
                "n_frames": 16,
                "between_frames": 0,
                "image_scale": 0.25,
                "voxel_size_m": 0.1,
                "subsample": 1,
                "max_range_m": 10.0,
                "mode": "ray",
                "model_params": {},
            },
        },
        lambda seed: sim.indoor_scene(seed=seed),
        lambda n, seed: sim.indoor_trajectory(n, seed=seed),
        lambda scale: sim.tsukuba_camera(scale=scale),
        1.0,
        "Indoor scene, New Tsukuba camera",
    )


STREET_BETWEEN_FRAMES = 32
"""Extra characterisation frames of the full street, from positions between the drive's: with the drive's own
4 the per-class mixtures see the rare gross errors of every class."""


STREET_NEAR_M = 1.5
"""PRISM's ``near_m`` on the street: no surface is nearer than 1.8 m to the drive. PRISM's tables grow like
``1 / near_m``, so the default 0.1 m would build tables far larger than the street needs."""


def _street3d_world():
    from prismap import sim

    return RenderedWorld(
        "street3d",
        "3-D street, KITTI-like rig, characterised matchers",
        {
            False: {
                "n_frames": 16,
                "between_frames": STREET_BETWEEN_FRAMES,
                "image_scale": 0.5,
                "voxel_size_m": 0.2,
                "subsample": 2,
                "max_range_m": 40.0,
                "mode": "projective",
                "model_params": {"prism": {"near_m": STREET_NEAR_M}},
            },
            True: {
                "n_frames": 8,
                "between_frames": 4,
                "image_scale": 0.25,
                "voxel_size_m": 0.4,
                "subsample": 1,
                "max_range_m": 30.0,
                "mode": "projective",
                "model_params": {"prism": {"near_m": STREET_NEAR_M}},
            },
        },
        lambda seed: sim.street_scene(seed=seed),
        lambda n, seed: sim.street_trajectory(n, seed=seed),
        lambda scale: sim.kitti_camera(scale=scale),
        1.0,
        "Street scene, KITTI-like camera",
        lambda n, n_between, seed: sim.street_trajectory_between(n, n_between, seed=seed),
    )


def _avenue3d_world():
    """The second street world: the street's drive through another layout, textures and rig; its only
    characterisation frames are the drive's own 4 (full size), so a model tuned on the street has to hold on few."""
    from prismap import sim

    return RenderedWorld(
        "avenue3d",
        "3-D avenue (second street world), characterised matchers",
        {
            False: {
                "n_frames": 16,
                "between_frames": 0,
                "image_scale": 1.0,
                "voxel_size_m": 0.2,
                "subsample": 2,
                "max_range_m": 40.0,
                "mode": "projective",
                "model_params": {"prism": {"near_m": STREET_NEAR_M}},
            },
            True: {
                "n_frames": 8,
                "between_frames": 2,
                "image_scale": 0.5,
                "voxel_size_m": 0.4,
                "subsample": 1,
                "max_range_m": 30.0,
                "mode": "projective",
                "model_params": {"prism": {"near_m": STREET_NEAR_M}},
            },
        },
        lambda seed: sim.avenue_scene(seed=seed),
        lambda n, seed: sim.street_trajectory(n, seed=seed),
        lambda scale: sim.avenue_camera(scale=scale),
        1.0,
        "Avenue scene, 620x188 rig",
        lambda n, n_between, seed: sim.street_trajectory_between(n, n_between, seed=seed),
    )


WORLDS = {"scene3d": _scene3d_world, "street3d": _street3d_world, "avenue3d": _avenue3d_world}
"""Name -> :class:`RenderedWorld` factory of every 3-D experiment."""


def scene3d_settings(
    *,
    world="scene3d",
    n_frames=None,
    voxel_size_m=None,
    seed=0,
    quick=False,
    matchers=MATCHERS,
    characterise_every=4,
    max_range_m=None,
    grid_offset=0.5,
    between_frames=None,
    class_pass_through=False,
):
    """The settings dict of a 3-D run on ``world`` (its sizes unless overridden); ``class_pass_through`` is
    recorded only when set, so the settings of runs without it stay as they were."""
    if world not in WORLDS:
        raise PrismapInputError(f"`world` must be one of {sorted(WORLDS)}; got {world!r}")
    spec = WORLDS[world]()
    sizes = dict(spec.sizes[bool(quick)])
    if between_frames is not None:
        sizes["between_frames"] = check_integer(
            between_frames, "between_frames", expected="an integer >= 0", condition=lambda n: n >= 0
        )
        if sizes["between_frames"] and spec.between_trajectory is None:
            raise PrismapInputError(
                f"`between_frames`: world {world!r} has no drive between its frames; got {between_frames!r} (0 or None)"
            )
    if n_frames is not None:
        sizes["n_frames"] = check_integer(
            n_frames, "n_frames", expected="an integer >= 2 (characterisation + mapping)", condition=lambda n: n >= 2
        )
    if voxel_size_m is not None:
        sizes["voxel_size_m"] = check_positive(voxel_size_m, "voxel_size_m")
    if max_range_m is not None:
        sizes["max_range_m"] = check_positive(max_range_m, "max_range_m")
    every = check_integer(
        characterise_every, "characterise_every", expected="an integer >= 2", condition=lambda n: n >= 2
    )
    unknown = [m for m in matchers if m not in MATCHERS]
    if unknown or not matchers:
        raise PrismapInputError(f"`matchers` must be a non-empty subset of {list(MATCHERS)}; got {list(matchers)}")
    offset = float(grid_offset)
    if not 0.0 <= offset < 1.0:
        raise PrismapInputError(f"`grid_offset` must lie in [0, 1) voxels; got {grid_offset!r}")
    return {
        "world": world,
        "quick": bool(quick),
        "seed": int(seed),
        "characterise_every": int(every),
        "grid_offset_m": offset * sizes["voxel_size_m"],
        "matchers": list(matchers),
        **sizes,
        **({"class_pass_through": True} if class_pass_through else {}),
    }


def split_frames(n_frames: int, every: int) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Indices ``(characterisation, mapping)``: every ``every``-th frame (from 0) characterises, the rest map."""
    indices = np.arange(n_frames)
    return indices[indices % every == 0], indices[indices % every != 0]


def render_world(settings):
    """Render the frames of a run with ``settings`` (:func:`scene3d_settings`): the same images for the same settings.

    The world's scene and the drive (then the positions between, ``between_frames``) are translated by
    ``grid_offset_m`` on every axis, and rendered with one noise stream seeded by ``seed``.

    Returns
    -------
    scene : Scene3D
        The translated scene.
    camera : StereoCamera
    drive_char_frames, char_frames, map_frames : list of StereoFrame
        The drive's characterisation frames (every ``characterise_every``-th), those and the frames between
        (every characterisation frame), and the drive's other frames (the mapping frames).
    """
    from prismap import sim
    from prismap._progress import progress

    spec, seed = WORLDS[settings["world"]](), settings["seed"]
    n_drive, n_between = settings["n_frames"], settings["between_frames"]
    char_index, map_index = split_frames(n_drive, settings["characterise_every"])
    poses = spec.trajectory(n_drive, seed)
    if n_between:
        poses = np.concatenate([poses, spec.between_trajectory(n_drive, n_between, seed)])
    camera = spec.camera(settings["image_scale"])
    base, shift = spec.scene(seed), settings["grid_offset_m"]
    scene = sim.Scene3D(
        base.box_lo + shift, base.box_hi + shift, base.box_texture, base.box_texel_m, base.box_tint, name=base.name
    )
    poses[:, :3, 3] += shift
    frames = list(progress(scene.frames(camera, poses, seed=seed), total=len(poses), desc="render", unit="frame"))
    drive_char_frames = [frames[i] for i in char_index]
    return scene, camera, drive_char_frames, drive_char_frames + frames[n_drive:], [frames[i] for i in map_index]
