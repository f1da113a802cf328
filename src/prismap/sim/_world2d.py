"""2-D worlds of axis-aligned rectangles, and a simulated 2-D stereo range sensor (a 1-row stereo camera).

Axis conventions. The world is the plane z = 0 of a right-handed frame with z up; positions are (x, y) in
metres and headings are angles from +x towards +y. The sensor is a stereo camera whose image has one row:
its optical axis (camera z) lies in the world plane along the heading, camera x (right, the baseline
direction) is ``(sin h, -cos h, 0)`` and camera y (down) is world -z, so ``T_world_cam`` is an ordinary
OpenCV-axes pose (:func:`prismap.sim.pose_from_heading`) and the 3-D grid engine maps the frames with one
layer of voxels (z key 0).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from prismap._validate import as_float_array, check_positive
from prismap.camera import StereoCamera
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.io._sequence import GroundTruthOccupancy
from prismap.sim._kernels import cast_view
from prismap.sim._poses import poses_from_se2
from prismap.sim._truth import ground_truth, solid_key_ranges

_HALF_HEIGHT_M = 1.0  # rectangles become boxes z in [-1, 1] m so that the sensor plane z = 0 cuts them


@dataclass(frozen=True)
class World2D:
    """A planar world: solid closed rectangles inside ``[0, width] x [0, height]``.

    Attributes
    ----------
    rectangles : (N, 4) float64, metres
        ``(x_min, y_min, x_max, y_max)`` of each solid.
    size_m : (2,) float64, metres
        ``(width, height)``.
    waypoints : (K, 2) float64, metres
        A tour through free space (for :func:`waypoint_path`); may be empty.
    name : str
    """

    rectangles: np.ndarray
    size_m: np.ndarray
    waypoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    name: str = ""

    def __post_init__(self):
        rects = as_float_array(self.rectangles, "rectangles", shape=(None, 4), allow_nan=False)
        size = as_float_array(self.size_m, "size_m", shape=(2,), allow_nan=False)
        waypoints = as_float_array(self.waypoints, "waypoints", shape=(None, 2), allow_nan=False)
        if np.any(size <= 0):
            raise PrismapInputError(f"`size_m` must be > 0; got {size.tolist()}")
        bad = (rects[:, 0] > rects[:, 2]) | (rects[:, 1] > rects[:, 3]) | np.any(rects < 0, axis=1)
        bad |= (rects[:, 2] > size[0]) | (rects[:, 3] > size[1])
        if np.any(bad):
            raise PrismapInputError(
                f"`rectangles` must be (x_min, y_min, x_max, y_max) with min <= max inside [0, {size[0]}] x "
                f"[0, {size[1]}]; bad rows {np.flatnonzero(bad).tolist()}: {rects[bad].tolist()}"
            )
        for name, value in (("rectangles", rects), ("size_m", size), ("waypoints", waypoints)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    @property
    def boxes(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """``(lo, hi)``, (N, 3) float64 each, metres: the rectangles as boxes spanning z in [-1, 1] m."""
        n = len(self.rectangles)
        lo = np.column_stack([self.rectangles[:, :2], np.full(n, -_HALF_HEIGHT_M)])
        hi = np.column_stack([self.rectangles[:, 2:], np.full(n, _HALF_HEIGHT_M)])
        return lo, hi

    def occupancy(self, cell_size_m: float) -> npt.NDArray[np.bool_]:
        """Exact occupancy raster: ``grid[iy, ix]`` is True if cell key ``(ix, iy)`` holds a point of a solid.

        The key of a point is ``floor(p / cell_size_m)`` (the map's convention), cell ``(ix, iy)`` is the
        half-open square ``[ix c, (ix + 1) c) x [iy c, (iy + 1) c)`` and rectangles are closed, so a rectangle
        whose edge lies on a cell boundary also occupies the cell beyond it. The raster covers every key of
        ``[0, width] x [0, height]``: ``nx = floor(width / c) + 1``, ``ny = floor(height / c) + 1``.

        Returns
        -------
        grid : (ny, nx) bool
        """
        cell = check_positive(cell_size_m, "cell_size_m")
        nx, ny = (np.floor(self.size_m / cell).astype(np.int64) + 1).tolist()
        grid = np.zeros((ny, nx), dtype=bool)
        lo, hi = solid_key_ranges(self.rectangles[:, :2], self.rectangles[:, 2:], cell)
        for (x0, y0), (x1, y1) in zip(lo, hi):
            grid[y0 : y1 + 1, x0 : x1 + 1] = True
        return grid

    def ground_truth(
        self, frames: Iterable[DisparityFrame], cell_size_m: float, *, max_depth_m: float = np.inf
    ) -> GroundTruthOccupancy:
        """:class:`~prismap.io.GroundTruthOccupancy` of this world seen by ``frames`` (keys with z = 0).

        Occupied keys are those of :meth:`occupancy`; observed keys are the cells whose centre the sensor
        sees up to the true surface (or ``max_depth_m`` of camera depth), plus the cells of the true hits.
        """
        lo, hi = self.boxes
        return ground_truth(lo, hi, frames, cell_size_m, planar=True, max_depth_m=max_depth_m)


def simple_world() -> World2D:
    """The simple 20 m x 20 m world: outer walls, two long inner walls and four blocks."""
    rects = _outer_walls(20.0, 20.0) + [
        (6.0, 0.0, 6.2, 12.0),  # inner wall from the south
        (13.8, 8.0, 14.0, 20.0),  # inner wall from the north
        (9.0, 3.0, 11.0, 5.0),
        (3.0, 15.0, 4.5, 17.0),
        (16.0, 3.0, 18.0, 4.0),
        (10.0, 13.0, 10.6, 13.6),  # pillar
    ]
    waypoints = [(2.5, 2.5), (2.5, 12.0), (8.0, 15.0), (8.5, 10.0), (12.0, 8.5), (16.5, 6.0), (12.5, 1.5)]
    return World2D(np.array(rects), np.array([20.0, 20.0]), np.array(waypoints), name="simple")


def office_world() -> World2D:
    """The 30 m x 20 m office: a corridor (y 9-11 m) between four rooms south and three north, 1 m doors.

    Walls are 0.2 m thick; every room has furniture (desks and cabinets).
    """
    width, height, t = 30.0, 20.0, 0.2
    rects = _outer_walls(width, height)
    south_doors, north_doors = (3.75, 11.25, 18.75, 26.25), (5.0, 15.0, 25.0)
    rects += _wall_with_doors(0.0, width, 9.0 - t, 9.0, south_doors)
    rects += _wall_with_doors(0.0, width, 11.0, 11.0 + t, north_doors)
    rects += [(x - t / 2, 0.0, x + t / 2, 9.0 - t) for x in (7.5, 15.0, 22.5)]
    rects += [(x - t / 2, 11.0 + t, x + t / 2, height) for x in (10.0, 20.0)]
    rects += [  # desks 1.6 x 0.8 m and cabinets 0.5 m deep along walls
        (2.0, 3.0, 3.6, 3.8),
        (4.5, 5.0, 5.3, 6.6),
        (0.2, 0.2, 2.2, 0.7),
        (9.5, 2.5, 11.1, 3.3),
        (12.5, 5.5, 13.3, 7.1),
        (14.4, 0.2, 14.9, 2.2),
        (17.0, 3.0, 18.6, 3.8),
        (20.0, 3.0, 21.6, 3.8),
        (17.0, 0.2, 19.0, 0.7),
        (24.0, 5.0, 25.6, 5.8),
        (27.5, 2.0, 28.3, 3.6),
        (29.3, 6.0, 29.8, 8.0),
        (2.5, 15.0, 4.1, 15.8),
        (6.5, 17.0, 8.1, 17.8),
        (0.2, 12.5, 0.7, 14.5),
        (13.0, 14.5, 14.6, 15.3),
        (16.5, 17.0, 18.1, 17.8),
        (19.3, 12.0, 19.8, 14.0),
        (23.0, 15.5, 24.6, 16.3),
        (27.0, 13.0, 27.8, 14.6),
        (25.0, 19.3, 27.0, 19.8),
    ]
    waypoints = [
        (1.5, 10.0),
        (11.25, 10.0),
        (11.25, 6.0),
        (13.5, 4.0),
        (11.25, 6.0),
        (11.25, 10.0),
        (15.0, 10.0),
        (15.0, 13.5),
        (17.0, 15.5),
        (15.0, 13.5),
        (15.0, 10.0),
        (26.25, 10.0),
        (26.25, 6.5),
        (26.25, 10.0),
        (28.5, 10.0),
    ]
    return World2D(np.array(rects), np.array([width, height]), np.array(waypoints), name="office")


def _outer_walls(width, height, t=0.2):
    return [
        (0.0, 0.0, width, t),
        (0.0, height - t, width, height),
        (0.0, 0.0, t, height),
        (width - t, 0.0, width, height),
    ]


def _wall_with_doors(x0, x1, y0, y1, door_centres, door_width=1.0):
    """Segments of the wall ``[x0, x1] x [y0, y1]`` with gaps of ``door_width`` centred on ``door_centres``."""
    edges = [x0] + [e for c in door_centres for e in (c - door_width / 2, c + door_width / 2)] + [x1]
    return [(a, y0, b, y1) for a, b in zip(edges[::2], edges[1::2])]


def waypoint_path(
    waypoints_m: npt.ArrayLike, *, step_m: float = 0.25, turn_step_deg: float = 10.0
) -> npt.NDArray[np.float64]:
    """Planar poses along a polyline: heading along each segment, turning in place at the corners.

    Parameters
    ----------
    waypoints_m : (K, 2) float, metres, K >= 2
    step_m : float, metres
        Largest distance between consecutive poses along a segment.
    turn_step_deg : float, degrees
        Largest heading change between consecutive poses at a corner.

    Returns
    -------
    poses_se2 : (N, 3) float64
        ``(x, y, heading)`` in metres and radians.
    """
    points = as_float_array(waypoints_m, "waypoints_m", shape=(None, 2), allow_nan=False)
    if len(points) < 2:
        raise PrismapInputError(f"`waypoints_m` needs at least 2 points; got {len(points)}")
    step = check_positive(step_m, "step_m")
    turn = np.radians(check_positive(turn_step_deg, "turn_step_deg"))
    poses = []
    heading = None
    for a, b in zip(points[:-1], points[1:]):
        length = float(np.hypot(*(b - a)))
        if length == 0:
            continue
        new_heading = float(np.arctan2(*(b - a)[::-1]))
        if heading is not None:
            change = (new_heading - heading + np.pi) % (2 * np.pi) - np.pi
            n_turn = int(np.ceil(abs(change) / turn))
            poses += [(a[0], a[1], heading + change * k / n_turn) for k in range(1, n_turn)]
        n = int(np.ceil(length / step))
        poses += [(*(a + (b - a) * k / n), new_heading) for k in range(n)]
        heading = new_heading
    poses.append((points[-1][0], points[-1][1], heading))
    return np.array(poses)


@dataclass(frozen=True)
class DisparityFrame:
    """A disparity image with its camera and pose, ready for the grid engine (no images).

    Attributes
    ----------
    disparity : (H, W) float32, pixels, NaN = no measurement
        Measured disparity ``d_true - e``.
    camera : StereoCamera
    T_world_cam : (4, 4) float64
        Camera-to-world pose, metres.
    disparity_gt : (H, W) float64, pixels, NaN = nothing hit
        Exact disparity ``f b / z`` of the first surface.
    range_m : (H, W) float64, metres
        Exact distance along each pixel's ray to the first surface; inf when nothing is hit.
    name : str
    """

    disparity: np.ndarray
    camera: StereoCamera
    T_world_cam: np.ndarray
    disparity_gt: np.ndarray
    range_m: np.ndarray
    name: str = ""


class StereoScanner2D:
    """A fan of rays measured as disparities: the pixel columns of a 1-row stereo camera.

    The camera has ``n_rays`` pixels, ``cx = (n_rays - 1) / 2``, ``cy = 0`` and the focal length that makes
    the image ``fov_deg`` wide from the outer pixel edges: ``f = (n_rays / 2) / tan(fov / 2)``. The ray of
    column u is ``((u - cx) / f, 0, 1)`` in camera axes. A hit at camera depth z (along the optical axis, not
    along the ray) has the true disparity ``d = f b / z``; the sensor reports ``d - e`` with ``e`` drawn from
    ``error_model`` (``e = d_true - d_measured``), NaN when the hit is deeper than ``max_depth_m``, when nothing
    is hit, or when the measurement is <= 0 (a matcher reports no negative disparities).

    Parameters
    ----------
    n_rays : int
    fov_deg : float, degrees, in (0, 180)
    baseline_m : float, metres
    max_depth_m : float, metres of camera depth
    error_model : GaussianMixture or None
        None: noise-free measurements.
    """

    def __init__(
        self,
        *,
        n_rays: int = 360,
        fov_deg: float = 90.0,
        baseline_m: float = 0.1,
        max_depth_m: float = 15.0,
        error_model: GaussianMixture | None = None,
    ) -> None:
        if int(n_rays) != n_rays or n_rays < 1:
            raise PrismapInputError(f"`n_rays` must be a positive integer; got {n_rays!r}")
        fov = float(fov_deg)
        if not 0 < fov < 180:
            raise PrismapInputError(f"`fov_deg` must lie in (0, 180) degrees; got {fov_deg!r}")
        if error_model is not None and not isinstance(error_model, GaussianMixture):
            raise PrismapInputError(
                f"`error_model` must be a GaussianMixture or None; got {type(error_model).__name__}"
            )
        self.max_depth_m = check_positive(max_depth_m, "max_depth_m")
        self.error_model = error_model
        focal = (n_rays / 2) / np.tan(np.radians(fov) / 2)
        self.camera = StereoCamera(focal, (n_rays - 1) / 2, 0.0, baseline_m, width=int(n_rays), height=1)

    @property
    def ray_directions_cam(self) -> npt.NDArray[np.float64]:
        """(W, 3) float64, camera frame: the ray of each column, scaled so that its z is 1 (unit depth)."""
        return self.camera.pixel_rays()[0]

    def scan(
        self,
        world: World2D,
        T_world_cam: npt.ArrayLike,
        *,
        rng: np.random.Generator | int | None = None,
        name: str = "",
    ) -> DisparityFrame:
        """One :class:`DisparityFrame` of ``world`` from the pose ``T_world_cam`` (4, 4), errors drawn with ``rng``."""
        pose = as_float_array(T_world_cam, "T_world_cam", shape=(4, 4), allow_nan=False)
        if abs(pose[2, 3]) > 0 or abs(pose[2, 2]) > 1e-12 or abs(pose[2, 0]) > 1e-12:
            raise PrismapInputError(
                "`T_world_cam` of a 2-D sensor must keep the camera x and z axes in the plane z = 0 "
                f"(rows 2 of columns 0, 2, 3 zero); got row 2 = {pose[2].tolist()}"
            )
        lo, hi = world.boxes
        cam = self.camera
        depth, _, _ = cast_view(
            np.ascontiguousarray(pose[:3, 3]),
            np.ascontiguousarray(pose[:3, :3]),
            cam.focal_px,
            cam.cx_px,
            cam.cy_px,
            1,
            cam.width,
            lo,
            hi,
        )
        with np.errstate(divide="ignore"):
            truth = np.where(np.isfinite(depth), cam.focal_baseline / depth, np.nan)
        measured = truth.copy()
        if self.error_model is not None:
            measured -= self.error_model.sample(truth.size, rng).reshape(truth.shape)
        measured[~(depth <= self.max_depth_m) | ~(measured > 0)] = np.nan
        range_m = depth * np.linalg.norm(self.ray_directions_cam, axis=1)
        return DisparityFrame(measured.astype(np.float32), cam, pose.copy(), truth, range_m, name=name)

    def frames(self, world: World2D, poses: npt.ArrayLike, *, seed: int = 0) -> Iterator[DisparityFrame]:
        """Yield one :class:`DisparityFrame` per pose; ``poses`` is (N, 4, 4) T_world_cam or (N, 3) (x, y, heading).

        One generator seeded with ``seed`` draws all the errors, so a run is reproducible.
        """
        poses = np.asarray(poses, dtype=np.float64)
        if poses.ndim == 2 and poses.shape[1] == 3:
            poses = poses_from_se2(poses)
        if poses.ndim != 3 or poses.shape[1:] != (4, 4):
            raise PrismapInputError(f"`poses` must be (N, 4, 4) or (N, 3); got shape {poses.shape}")
        rng = np.random.default_rng(seed)
        for index, pose in enumerate(poses):
            yield self.scan(world, pose, rng=rng, name=f"{world.name}/{index:06d}")
