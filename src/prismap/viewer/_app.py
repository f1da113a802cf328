"""The interactive 3-D map viewer: a viser server (its own web client) showing an occupancy map's voxels
coloured by P(occupied), with controls, the camera trajectory and the ground truth beside the map."""

from __future__ import annotations

import os
import socket
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from prismap.errors import PrismapInputError
from prismap.grid import OccupancyMap
from prismap.io import GroundTruthOccupancy
from prismap.viewer._voxels import (
    AGREEMENT,
    AGREEMENT_COLORS,
    COLORMAP,
    UNKNOWN_COLOR,
    agreement_codes,
    probability_colors,
    select,
    select_codes,
    unobserved_cells,
    voxel_pyramid,
)

POINT_BUDGET = 2_000_000
"""Most voxels sent to the browser per layer; above it the layer is drawn 2^k times coarser."""

TRAJECTORY_COLOR = (230, 40, 40)

COLOUR_MODES = ("P(occupied)", "agreement with the truth")
"""What the map's voxels are coloured by; the agreement needs the ground truth (``--gt``)."""

AGREEMENT_SHOWN = (2, 3, 4)
""":data:`AGREEMENT` codes shown when the agreement colouring starts: correct occupied and both errors (the
correct free voxels would hide them)."""


def load_trajectory(path: str | os.PathLike[str]) -> npt.NDArray[np.float64]:
    """Camera poses for the viewer: a sequence folder (:func:`prismap.io.read_sequence`) or a pose text
    file of 3x4 row-major ``T_world_cam`` rows (KITTI's and prismap's ``poses.txt``).

    Returns
    -------
    (N, 4, 4) float64, metres, world frame
    """
    from prismap.io import read_kitti_poses, read_sequence

    path = Path(path)
    if path.is_dir():
        poses = read_sequence(path).poses
        if poses is None:
            raise PrismapInputError(f"--poses {path}: the sequence has no poses")
        return np.asarray(poses)
    if not path.is_file():
        raise PrismapInputError(f"--poses {path}: no such sequence folder or pose file")
    return read_kitti_poses(path)


def _height_greys(z_m):
    """(N, 3) uint8 greys of the ground truth's occupied voxels, dark (low) to light (high): every one is
    occupied, so height is what tells floor, boxes and walls apart."""
    z = np.asarray(z_m, dtype=np.float64)
    span = max(float(z.max() - z.min()), 1e-9) if len(z) else 1.0
    level = 70 + 150 * (z - (z.min() if len(z) else 0.0)) / span
    return np.repeat(level.astype(np.uint8)[:, None], 3, axis=1)


def agreement_legend():
    """HTML legend of :data:`AGREEMENT`: a swatch of each colour and its name (shown by the checkboxes below it)."""
    rows = "".join(
        f'<div><span style="display:inline-block;width:0.9em;height:0.9em;margin-right:0.4em;vertical-align:middle;'
        f'background:rgb({r},{g},{b})"></span>{name}</div>'
        for (r, g, b), name in zip(AGREEMENT_COLORS, AGREEMENT)
    )
    return (
        '<div style="font-size:0.85em;padding:0.3em 0.5em"><b>Agreement with the truth</b> (colour by: '
        f"agreement; the map's thresholds decide free and occupied){rows}</div>"
    )


def _framing_box(level, occupied_threshold):
    """``(lo_w, hi_w)`` metres: the 1st-99th percentile box of the occupied voxels (of all, if none are),
    so that a few far stray voxels do not shrink the view of the map."""
    keys = level.keys[level.probability >= occupied_threshold]
    keys = keys if len(keys) else level.keys
    lo, hi = np.percentile(keys, 1, axis=0), np.percentile(keys, 99, axis=0) + 1
    return lo * level.size_m, hi * level.size_m


class MapViewer:
    """A viser scene of one occupancy map.

    Parameters
    ----------
    grid : OccupancyMap
    truth : GroundTruthOccupancy, optional
        Its occupied voxels that a perfect sensor observed are drawn beside the map (shifted along +x past
        the map's box), in greys by height (all are occupied), toggleable, with the map's height range
        (which starts below the truth's top layer, so a ceiling does not hide the room). The map's voxels
        can then be coloured by their agreement with it (:data:`AGREEMENT`, with a legend).
    poses_w : (N, 4, 4) float64, optional
        ``T_world_cam`` of the camera trajectory, metres; the map file does not record poses.
    host, port : str, int
        Where the server listens (port 0: a free one, see :attr:`port`).
    budget : int
        :data:`POINT_BUDGET`.
    agreement : bool
        Start with the map coloured by agreement with ``truth`` (needs it) instead of P(occupied).

    Notes
    -----
    Each voxel is one square point of its edge length, flat-shaded, so colours are the colormap's
    exactly. The controls (P threshold, free/unknown/occupied, height range) re-select voxels from a
    level-of-detail pyramid built once (:func:`prismap.viewer.voxel_pyramid`): the finest level
    that fits the budget is sent.
    """

    def __init__(
        self,
        grid: OccupancyMap,
        *,
        truth: GroundTruthOccupancy | None = None,
        poses_w: npt.ArrayLike | None = None,
        host: str = "127.0.0.1",
        port: int = 8080,
        budget: int = POINT_BUDGET,
        agreement: bool = False,
    ) -> None:
        try:
            import viser
        except ImportError:
            raise PrismapInputError(
                "prismap view needs the optional `viser` module: pip install -e '.[view]'"
            ) from None

        start = time.perf_counter()
        keys, probability, _, _ = grid.known_probabilities()
        if len(keys) == 0:
            raise PrismapInputError("the map has no known voxels: nothing to view")
        self.grid = grid
        self.budget = int(budget)
        self.levels = voxel_pyramid(keys, probability, grid.voxel_size_m)
        self._unobserved = None
        self._handles, self._keys, self._shown = {}, {}, {}
        base = self.levels[0]
        z_lo, z_hi = base.keys[:, 2].min() * base.size_m, (base.keys[:, 2].max() + 1) * base.size_m
        lo_w, hi_w = _framing_box(base, grid.occupied_threshold)
        self.truth_levels = self.agreement = None
        self.truth_offset_w = np.zeros(3)
        z_top = None
        if truth is not None and len(truth.occupied_keys):
            if abs(truth.voxel_size_m - grid.voxel_size_m) > 1e-9 * grid.voxel_size_m:
                raise PrismapInputError(
                    f"the ground truth's voxels are {truth.voxel_size_m} m, the map's "
                    f"{grid.voxel_size_m} m: they must match"
                )
            occupied = truth.observed_occupied_keys
            occupied = occupied if len(occupied) else truth.occupied_keys
            self.truth_levels = voxel_pyramid(occupied, np.ones(len(occupied)), truth.voxel_size_m)
            codes = agreement_codes(
                keys,
                base.probability,
                truth,
                free_threshold=grid.free_threshold,
                occupied_threshold=grid.occupied_threshold,
            )
            self.agreement = voxel_pyramid(keys, codes, grid.voxel_size_m)
            if occupied[:, 2].max() > occupied[:, 2].min():
                z_top = float(occupied[:, 2].max() * truth.voxel_size_m)  # the top layer's floor
            truth_lo, truth_hi = _framing_box(self.truth_levels[0], 0.5)
            # beside the map along +x: past both boxes, with a 1 m gap
            self.truth_offset_w[0] = max(hi_w[0], truth_hi[0]) - min(lo_w[0], truth_lo[0]) + 1.0
            lo_w, hi_w = np.minimum(lo_w, truth_lo), np.maximum(hi_w, truth_hi)

        if agreement and self.agreement is None:
            raise PrismapInputError("colouring by agreement needs the ground truth (--gt TRUTH.npz)")
        self.server = _start_server(viser, host, port)
        self.port = self.server.get_port()
        scene, gui = self.server.scene, self.server.gui
        scene.set_up_direction("+z")
        center = (lo_w + hi_w) / 2 + self.truth_offset_w / 2
        extent = float(np.linalg.norm(hi_w - lo_w)) + self.truth_offset_w[0]
        self.server.initial_camera.look_at = tuple(center)
        self.server.initial_camera.position = tuple(center + extent * np.array([0.0, -0.42, 0.4]))

        gui.add_markdown(
            f"**{len(keys):,} voxels** of {base.size_m:g} m. Colour: P(occupied), {COLORMAP} "
            "(violet 0, teal 0.5, yellow 1); grey: unobserved inside the map's box."
        )
        with_truth = self.agreement is not None
        self.colour_by = gui.add_dropdown(
            "colour by",
            COLOUR_MODES if with_truth else COLOUR_MODES[:1],
            initial_value=COLOUR_MODES[int(bool(agreement))],
            visible=with_truth,
        )
        self.threshold = gui.add_slider("P(occupied) >=", 0.0, 1.0, 0.01, 0.0)
        self.show = {name: gui.add_checkbox(name, name == "occupied") for name in ("occupied", "unknown", "free")}
        gui.add_html(agreement_legend(), visible=with_truth)
        self.show_agreement = [
            gui.add_checkbox(name, code in AGREEMENT_SHOWN, visible=with_truth) for code, name in enumerate(AGREEMENT)
        ]
        z_lo, z_hi = float(z_lo), float(z_hi)
        start_hi = z_top if z_top is not None and z_lo < z_top < z_hi else z_hi
        self.z_range = gui.add_multi_slider("height z (m)", z_lo, z_hi, base.size_m, (z_lo, start_hi))
        self.show_truth = gui.add_checkbox("ground truth (beside)", True, visible=with_truth)
        self.status = gui.add_markdown("")
        for control in (
            self.colour_by,
            self.threshold,
            self.z_range,
            self.show_truth,
            *self.show.values(),
            *self.show_agreement,
        ):
            control.on_update(lambda _: self.refresh())

        if poses_w is not None:
            self._add_trajectory(np.asarray(poses_w, dtype=np.float64))
        scene.add_label("/labels/map", "map", position=tuple((lo_w + hi_w) / 2 * [1, 1, 0] + [0, 0, hi_w[2]]))
        if self.truth_levels is not None:
            scene.add_label(
                "/labels/truth",
                "ground truth",
                position=tuple((lo_w + hi_w) / 2 * [1, 1, 0] + [0, 0, hi_w[2]] + self.truth_offset_w),
            )
        self.stats = self.refresh()
        self.stats["build_s"] = time.perf_counter() - start

    def refresh(self) -> dict[str, Any]:
        """Redraw the layers for the current controls.

        Returns
        -------
        dict
            ``points`` sent, the map layer's ``level`` (0 = full resolution) and ``voxel_m``.
        """
        classes = tuple(name for name, box in self.show.items() if box.value)
        z_range = tuple(self.z_range.value)
        if self.colour_by.value == COLOUR_MODES[1]:
            shown = tuple(code for code, box in enumerate(self.show_agreement) if box.value)
            level = self._layer(
                "/map/voxels", ("agreement", shown, z_range), lambda: self._agreement_layer(shown, z_range)
            )
        else:
            level = self._layer(
                "/map/voxels", (self.threshold.value, classes, z_range), lambda: self._map_layer(classes, z_range)
            )
        self._layer("/map/unobserved", (self.show["unknown"].value, z_range), lambda: self._unobserved_layer(z_range))
        self._layer("/truth/voxels", (self.show_truth.value, z_range), lambda: self._truth_layer(z_range))
        stats = {
            "level": level.level,
            "voxel_m": level.size_m,
            "points": sum(count for count, _ in self._shown.values()),
        }
        coarse = f" (2^{level.level} coarser: over the {self.budget:,}-point budget)" if level.level else ""
        self.status.content = f"{stats['points']:,} points shown; map voxels {level.size_m:g} m{coarse}."
        return stats

    def _map_layer(self, classes, z_range):
        level, mask = select(
            self.levels,
            threshold=self.threshold.value,
            classes=classes,
            z_range_m=z_range,
            free_threshold=self.grid.free_threshold,
            occupied_threshold=self.grid.occupied_threshold,
            budget=self.budget,
        )
        return level, (level.centers_w[mask], probability_colors(level.probability[mask]), level.size_m)

    def _agreement_layer(self, shown, z_range):
        level, mask = select_codes(self.agreement, shown=shown, z_range_m=z_range, budget=self.budget)
        colors = AGREEMENT_COLORS[level.probability[mask].astype(np.intp)]
        return level, (level.centers_w[mask], colors, level.size_m)

    def _unobserved_layer(self, z_range):
        if not self.show["unknown"].value:
            return None, None
        if self._unobserved is None:
            self._unobserved = unobserved_cells(self.levels[0], budget=self.budget)
        cells = self._unobserved
        z = cells.centers_w[:, 2]
        keep = (z >= z_range[0]) & (z <= z_range[1])
        colors = np.broadcast_to(np.array(UNKNOWN_COLOR, dtype=np.uint8), (int(keep.sum()), 3))
        return cells, (cells.centers_w[keep], colors, cells.size_m)

    def _truth_layer(self, z_range):
        if self.truth_levels is None or not self.show_truth.value:
            return None, None
        truth, keep = select(self.truth_levels, z_range_m=z_range, budget=self.budget)
        centers = truth.centers_w[keep]
        return truth, (centers, _height_greys(centers[:, 2]), truth.size_m, self.truth_offset_w)

    def _layer(self, name, key, build):
        """Redraw layer ``name`` with ``build() -> (level, (centres, colours, size[, position]) or None)``
        unless its controls ``key`` are unchanged; returns its level."""
        if name in self._shown and self._keys.get(name) == key:
            return self._shown[name][1]
        level, cloud = build()
        old = self._handles.pop(name, None)
        if old is not None:
            old.remove()
        self._keys[name] = key
        self._shown[name] = (0 if cloud is None else len(cloud[0]), level)
        if cloud is not None and len(cloud[0]):
            self._handles[name] = self._point_cloud(name, *cloud)
        return level

    def _point_cloud(self, name, centers_w, colors, size_m, position=(0.0, 0.0, 0.0)):
        """One point cloud of square voxels, flat-shaded so colours are exact."""
        reach = float(np.abs(centers_w).max())
        precision = "float16" if reach < 256 * size_m else "float32"  # float16 steps stay under size / 4
        return self.server.scene.add_point_cloud(
            name,
            centers_w,
            np.ascontiguousarray(colors),
            point_size=size_m,
            point_shape="square",
            point_shading="flat",
            precision=precision,
            position=tuple(position),
        )

    def _add_trajectory(self, poses_w):
        if poses_w.ndim != 3 or poses_w.shape[1:] != (4, 4) or len(poses_w) == 0:
            raise PrismapInputError(f"`poses_w` must be (N, 4, 4) with N >= 1; got shape {poses_w.shape}")
        from scipy.spatial.transform import Rotation

        centres = poses_w[:, :3, 3]
        if len(centres) > 1:
            segments = np.stack([centres[:-1], centres[1:]], axis=1)
            self.server.scene.add_line_segments(
                "/trajectory/path", segments, TRAJECTORY_COLOR, thickness=3.0, thickness_units="screen"
            )
        xyzw = Rotation.from_matrix(poses_w[:, :3, :3]).as_quat()
        wxyz = np.roll(xyzw, 1, axis=1)
        step = max(1, len(poses_w) // 50)
        for index in range(0, len(poses_w), step):
            self.server.scene.add_camera_frustum(
                f"/trajectory/camera_{index:05d}",
                fov=1.0,
                aspect=4 / 3,
                scale=0.15,
                color=TRAJECTORY_COLOR,
                wxyz=tuple(wxyz[index]),
                position=tuple(centres[index]),
            )

    def stop(self) -> None:
        """Stop the server."""
        self.server.stop()


READY_TIMEOUT_S = 30.0
"""Longest wait (seconds) for the viser server to say it listens before ``prismap view`` gives up."""


def _start_server(viser, host, port):
    """A running ``viser.ViserServer`` on ``host``, or a one-line error.

    The address is bound once first (port 0), so an address this machine does not have is refused at
    once instead of viser retrying a thousand ports; the server then has :data:`READY_TIMEOUT_S` to report
    that it listens (its own wait has no deadline).
    """
    try:
        infos = socket.getaddrinfo(host, 0, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
        with socket.socket(infos[0][0], socket.SOCK_STREAM) as probe:
            probe.bind(infos[0][4])
    except (OSError, UnicodeError) as exc:
        raise PrismapInputError(
            f"--host {host}: cannot listen on this address ({getattr(exc, 'strerror', None) or exc})"
        ) from None
    started = {}

    def start():
        try:
            started["server"] = viser.ViserServer(host=host, port=port, verbose=False)
        except OSError as exc:
            started["error"] = exc

    thread = threading.Thread(target=start, daemon=True)
    thread.start()
    thread.join(READY_TIMEOUT_S)
    if "error" in started:
        raise started["error"]
    if "server" not in started:
        raise PrismapInputError(
            f"--host {host} --port {port}: the viewer did not start listening within "
            f"{READY_TIMEOUT_S:g} s (READY_TIMEOUT_S)"
        )
    return started["server"]
