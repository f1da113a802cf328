"""Textured indoor scenes of axis-aligned boxes, rendered as rectified stereo pairs with exact disparity.

World frame: metres, z up. Cameras use OpenCV axes (x right, y down, z forward) and ``T_world_cam`` poses;
the right camera sits ``baseline_m`` along the left camera's x axis, as in a rectified rig.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from prismap._validate import as_float_array, check_integer
from prismap.camera import StereoCamera
from prismap.errors import PrismapInputError
from prismap.io._frame import StereoFrame
from prismap.io._sequence import GroundTruthOccupancy
from prismap.sim._kernels import cast_view, shade_view
from prismap.sim._poses import pose_from_heading
from prismap.sim._textures import FIRST_OTHER, PHOTOGRAPHS, texture_bank
from prismap.sim._truth import SOLID_DEPTH_QUANTILE, ground_truth, pass_through_ratio, solid_depth

# brightness by face normal axis (x, y, z) and side (the face at the box's lo, at its hi): a fixed light
_SHADE = np.array([[0.80, 0.90], [0.70, 0.85], [0.55, 1.00]])


@dataclass(frozen=True)
class Scene3D:
    """Solid, closed, axis-aligned textured boxes.

    Attributes
    ----------
    box_lo, box_hi : (B, 3) float64, metres, world frame
        Opposite corners, ``lo <= hi``.
    box_texture : (B,) int64
        Index into :func:`texture_bank` (the photographs of ``PHOTOGRAPHS`` first, then procedural noise).
    box_texel_m : (B,) float64, metres
        Size of one texel on the box's faces (textures tile).
    box_tint : (B, 3) float64
        RGB factor applied to the texture.
    name : str
    """

    box_lo: np.ndarray
    box_hi: np.ndarray
    box_texture: np.ndarray
    box_texel_m: np.ndarray
    box_tint: np.ndarray
    name: str = ""

    def __post_init__(self):
        lo = as_float_array(self.box_lo, "box_lo", shape=(None, 3), allow_nan=False)
        n = len(lo)
        hi = as_float_array(self.box_hi, "box_hi", shape=(n, 3), allow_nan=False)
        texel = as_float_array(self.box_texel_m, "box_texel_m", shape=(n,), allow_nan=False)
        tint = as_float_array(self.box_tint, "box_tint", shape=(n, 3), allow_nan=False)
        texture = np.ascontiguousarray(self.box_texture, dtype=np.int64)
        if n == 0 or np.any(lo > hi):
            bad = np.flatnonzero(np.any(lo > hi, axis=1)).tolist()
            raise PrismapInputError(f"a scene needs boxes with `box_lo` <= `box_hi`; bad rows {bad}")
        if texture.shape != (n,) or np.any((texture < 0) | (texture >= len(texture_bank()))):
            raise PrismapInputError(
                f"`box_texture` must be {n} indices in [0, {len(texture_bank())}); got {texture.tolist()}"
            )
        if np.any(texel <= 0) or np.any(tint < 0):
            raise PrismapInputError("`box_texel_m` must be > 0 and `box_tint` >= 0")
        checked = {"box_lo": lo, "box_hi": hi, "box_texture": texture, "box_texel_m": texel, "box_tint": tint}
        for name, value in checked.items():
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    @classmethod
    def from_boxes(
        cls,
        box_lo: npt.ArrayLike,
        box_hi: npt.ArrayLike,
        *,
        texture: str | int = "gravel",
        texel_m: float = 0.01,
        name: str = "",
    ) -> Scene3D:
        """A scene whose boxes all wear one texture (a name of ``PHOTOGRAPHS`` or an index), untinted."""
        lo = np.atleast_2d(np.asarray(box_lo, dtype=np.float64))
        index = PHOTOGRAPHS.index(texture) if isinstance(texture, str) else int(texture)
        n = len(lo)
        return cls(lo, box_hi, np.full(n, index), np.full(n, float(texel_m)), np.ones((n, 3)), name=name)

    def cast(self, camera: StereoCamera, T_world_cam: npt.ArrayLike, *, right: bool = False) -> npt.NDArray[np.float64]:
        """Exact depth (H, W) float64, metres of camera z, inf where nothing is hit, of the left (or right) view."""
        return self._cast(camera, T_world_cam, right)[0][0]

    def _cast(self, camera, T_world_cam, right):
        if camera.width is None or camera.height is None:
            raise PrismapInputError("the camera needs `width` and `height` to render")
        pose = as_float_array(T_world_cam, "T_world_cam", shape=(4, 4), allow_nan=False)
        rotation = np.ascontiguousarray(pose[:3, :3])
        origin = pose[:3, 3] + (rotation[:, 0] * camera.baseline_m if right else 0.0)
        cx = camera.cx_px + (camera.doffs_px if right else 0.0)
        view = (origin, rotation, camera.focal_px, cx, camera.cy_px)
        return cast_view(*view, camera.height, camera.width, self.box_lo, self.box_hi), view

    def _image(self, camera, T_world_cam, right, noise_sigma, rng):
        (depth, box, axis), view = self._cast(camera, T_world_cam, right)
        looks = (self.box_texture, self.box_texel_m, self.box_tint, texture_bank(), _SHADE)
        image = shade_view(*view, depth, box, axis, *looks)
        image *= 255.0
        if noise_sigma > 0:
            image += np.float32(noise_sigma) * rng.standard_normal(image.shape, dtype=np.float32)
        return np.clip(np.rint(image), 0, 255).astype(np.uint8), depth

    def render(
        self,
        camera: StereoCamera,
        T_world_cam: npt.ArrayLike,
        *,
        noise_sigma: float = 2.0,
        rng: np.random.Generator | int | None = None,
        name: str = "",
    ) -> StereoFrame:
        """Render a rectified stereo pair with its exact left disparity.

        Parameters
        ----------
        camera : StereoCamera
            With ``width`` and ``height``; the right view uses ``cx + doffs``.
        T_world_cam : (4, 4) float64
            Pose of the left camera, metres.
        noise_sigma : float, grey levels
            Standard deviation of the Gaussian noise added to each pixel and channel of both images.
        rng : np.random.Generator or int, optional
            Draws the image noise.

        Returns
        -------
        StereoFrame
            ``left``/``right`` (H, W, 3) uint8 RGB; ``disparity_gt`` (H, W) float32, pixels,
            ``f b / z - doffs`` with z the true depth, NaN where nothing is hit; ``extras["depth_m"]`` (H, W)
            float64, the true depth (inf where nothing is hit).
        """
        sigma = float(noise_sigma)
        if not (np.isfinite(sigma) and sigma >= 0):
            raise PrismapInputError(f"`noise_sigma` must be a finite number >= 0; got {noise_sigma!r}")
        rng = np.random.default_rng(rng)
        left, depth = self._image(camera, T_world_cam, False, sigma, rng)
        right, _ = self._image(camera, T_world_cam, True, sigma, rng)
        disparity = camera.disparity_from_depth(depth).astype(np.float32)
        pose = np.array(T_world_cam, dtype=np.float64)
        return StereoFrame(left, right, camera, disparity, pose, name=name, extras={"depth_m": depth})

    def frames(
        self, camera: StereoCamera, poses: npt.ArrayLike, *, noise_sigma: float = 2.0, seed: int = 0
    ) -> Iterator[StereoFrame]:
        """Yield :meth:`render` of every pose in ``poses`` (N, 4, 4); one generator seeded with ``seed``."""
        poses = as_float_array(poses, "poses", shape=(None, 4, 4), allow_nan=False)
        rng = np.random.default_rng(seed)
        for index, pose in enumerate(poses):
            yield self.render(camera, pose, noise_sigma=noise_sigma, rng=rng, name=f"{self.name}/{index:06d}")

    def ground_truth(
        self, frames: Iterable[StereoFrame], voxel_size_m: float, *, max_depth_m: float = np.inf
    ) -> GroundTruthOccupancy:
        """:class:`~prismap.io.GroundTruthOccupancy` of the scene seen by ``frames`` (e.g. rendered ones).

        Occupied: every voxel holding a point of a box -- boxes are solid, so voxels inside furniture are
        occupied too, although no sensor sees them; they are scored only if observed. Observed: voxels whose
        centre a frame sees in front of (or on) the true surface within ``max_depth_m`` of camera depth, and
        the voxels of the visible surface points (see ``prismap.sim._truth.ground_truth``).
        """
        return ground_truth(self.box_lo, self.box_hi, frames, voxel_size_m, max_depth_m=max_depth_m)

    def pass_through_ratio(
        self,
        frames: Iterable[StereoFrame],
        voxel_size_m: float,
        *,
        max_depth_m: float = np.inf,
        subsample: int = 1,
        ray_classes: Sequence[np.ndarray] | None = None,
        n_classes: int | None = None,
    ) -> float | npt.NDArray[np.float64]:
        """How often a ray crosses an occupied voxel without meeting its surface there, seen by ``frames``
        (see ``prismap.sim._truth.pass_through_ratio``): PRISM's ``pass_through`` for this world, or with
        ``ray_classes`` one per pixel class (``class_pass_through``)."""
        return pass_through_ratio(
            self.box_lo,
            self.box_hi,
            frames,
            voxel_size_m,
            max_depth_m=max_depth_m,
            subsample=subsample,
            ray_classes=ray_classes,
            n_classes=n_classes,
        )

    def solid_depth(
        self,
        frames: Iterable[StereoFrame],
        voxel_size_m: float,
        *,
        max_depth_m: float = np.inf,
        subsample: int = 1,
        quantile: float = SOLID_DEPTH_QUANTILE,
    ) -> float:
        """Depth of solid behind all but ``quantile`` of the noise-free hits of ``frames`` (metres along the
        ray; see ``prismap.sim._truth.solid_depth``): PRISM's ``solid_depth_m`` for this world."""
        return solid_depth(
            self.box_lo,
            self.box_hi,
            frames,
            voxel_size_m,
            max_depth_m=max_depth_m,
            subsample=subsample,
            quantile=quantile,
        )


ROOM_M = (14.0, 9.0, 3.0)  # interior of the indoor scene: x, y, z extents from the origin


def indoor_scene(*, seed: int = 0) -> Scene3D:
    """A 14 m x 9 m x 3 m room: textured walls, floor and ceiling, shelves, cabinets, a table with objects,
    a pillar, pictures, and ``seed``-placed boxes along the walls. Objects lie 1-15 m from the trajectory
    of :func:`indoor_trajectory`, which never comes closer than 0.5 m to a box.
    """
    rng = np.random.default_rng(seed)
    lx, ly, lz = ROOM_M
    t = 0.2
    tex = {name: i for i, name in enumerate(PHOTOGRAPHS)}
    noise = len(PHOTOGRAPHS)
    boxes = [  # (lo, hi, texture, texel_m, tint)
        ((-t, -t, -t), (lx + t, ly + t, 0.0), tex["gravel"], 0.02, (0.9, 0.8, 0.7)),  # floor
        ((-t, -t, lz), (lx + t, ly + t, lz + t), noise, 0.03, (0.95, 0.95, 1.0)),  # ceiling
        ((-t, 0.0, 0.0), (0.0, ly, lz), tex["brick"], 0.02, (1.0, 0.75, 0.6)),
        ((lx, 0.0, 0.0), (lx + t, ly, lz), tex["brick"], 0.025, (0.85, 0.8, 0.75)),
        ((0.0, -t, 0.0), (lx, 0.0, lz), noise + 1, 0.03, (0.7, 0.85, 1.0)),
        ((0.0, ly, 0.0), (lx, ly + t, lz), tex["grass"], 0.02, (0.75, 1.0, 0.7)),
        ((0.0, 1.5, 0.0), (0.5, 3.5, 2.2), tex["coffee"], 0.01, (1.0, 1.0, 1.0)),  # shelf
        ((13.4, 5.0, 0.0), (lx, 7.5, 1.8), tex["chelsea"], 0.01, (1.0, 1.0, 1.0)),  # shelf
        ((4.0, 8.5, 0.0), (6.5, ly, 2.0), tex["rocket"], 0.012, (1.0, 1.0, 1.0)),  # shelf
        ((9.0, 0.0, 0.0), (11.0, 0.6, 1.0), noise + 2, 0.01, (1.0, 0.9, 0.6)),  # cabinet
        ((6.0, 3.9, 0.70), (8.0, 5.1, 0.76), tex["camera"], 0.006, (0.9, 0.7, 0.5)),  # table top
        ((7.0, 0.8, 0.0), (7.4, 1.2, lz), noise + 3, 0.01, (0.9, 0.9, 0.9)),  # pillar
        ((6.6, 4.2, 0.76), (7.0, 4.6, 1.1), tex["astronaut"], 0.004, (1.0, 1.0, 1.0)),  # objects on the table
        ((7.3, 4.5, 0.76), (7.5, 4.9, 0.96), tex["coffee"], 0.004, (1.0, 1.0, 1.0)),
        ((3.0, ly - 0.02, 1.2), (4.0, ly, 2.0), tex["astronaut"], 0.004, (1.0, 1.0, 1.0)),  # pictures
        ((lx - 0.02, 2.0, 1.0), (lx, 3.5, 2.0), tex["chelsea"], 0.005, (1.0, 1.0, 1.0)),
        ((10.0, 0.0, 1.3), (12.0, 0.02, 2.3), tex["rocket"], 0.008, (1.0, 1.0, 1.0)),
    ]
    for x0, y0 in [(6.0, 3.9), (7.94, 3.9), (6.0, 5.04), (7.94, 5.04)]:  # table legs
        boxes.append(((x0, y0, 0.0), (x0 + 0.06, y0 + 0.06, 0.70), noise + 3, 0.01, (0.5, 0.4, 0.3)))
    bands = [((0.3, 2.5), (4.0, 8.6)), ((11.5, 13.3), (0.8, 4.6)), ((1.0, 3.5), (0.3, 1.4)), ((8.0, 12.5), (7.4, 8.6))]
    for (x0, x1), (y0, y1) in bands:  # two seeded boxes per band along the walls
        for _ in range(2):
            size = rng.uniform([0.3, 0.3, 0.3], [0.9, 0.9, 1.4])
            corner = rng.uniform([x0, y0], [x1 - size[0], y1 - size[1]])
            texture = int(rng.integers(FIRST_OTHER))
            texel, tint = rng.uniform(0.005, 0.015), rng.uniform(0.6, 1.0, 3)
            boxes.append(((*corner, 0.0), (*(corner + size[:2]), size[2]), texture, texel, tint))
    lo, hi, texture, texel, tint = (np.array(column) for column in zip(*boxes))
    return Scene3D(lo, hi, texture, texel, tint, name=f"indoor-{seed}")


MAX_INDOOR_FRAMES = 360
"""Most frames of :func:`indoor_trajectory`: one per degree of the loop (more are near-duplicates)."""


def indoor_trajectory(n_frames: int = 40, *, seed: int = 0) -> npt.NDArray[np.float64]:
    """A smooth closed loop through :func:`indoor_scene`'s room, panning and tilting to look at its content.

    The camera circles the room centre (7, 4.5) on a seeded, wobbling ellipse of radii about 3.8 x 2.0 m at
    1.4-1.6 m height, heading along the path plus a +-35 degree pan, pitched 3-9 degrees down.

    Parameters
    ----------
    n_frames : int, 1 .. MAX_INDOOR_FRAMES
    seed : int

    Returns
    -------
    T_world_cam : (n_frames, 4, 4) float64
    """
    n_frames = check_integer(
        n_frames,
        "n_frames",
        expected=f"an integer in [1, {MAX_INDOOR_FRAMES}] (one frame per degree of the loop at most)",
        condition=lambda n: 1 <= n <= MAX_INDOOR_FRAMES,
    )
    rng = np.random.default_rng(seed)
    amplitude, phase = rng.uniform(-0.05, 0.05, 2), rng.uniform(0, 2 * np.pi, 3)
    angle = np.linspace(0.0, 2 * np.pi, int(n_frames), endpoint=False)
    scale = 1.0 + amplitude[0] * np.cos(2 * angle + phase[0]) + amplitude[1] * np.cos(3 * angle + phase[1])
    x = 7.0 + 3.8 * scale * np.cos(angle)
    y = 4.5 + 2.0 * scale * np.sin(angle)
    z = 1.5 + 0.1 * np.sin(2 * angle + phase[2])
    tangent = np.arctan2(2.0 * np.cos(angle), -3.8 * np.sin(angle))
    heading = tangent + np.radians(35.0) * np.sin(2 * angle + phase[2])
    pitch = np.radians(6.0 + 3.0 * np.sin(3 * angle))
    return np.array([pose_from_heading((a, b, c), h, pitch_rad=p) for a, b, c, h, p in zip(x, y, z, heading, pitch)])
