"""Figures of maps beside the ground truth: a horizontal slice of every model's map, one map in 3-D."""

from __future__ import annotations

import os
from collections.abc import Mapping

import numpy as np
from matplotlib.figure import Figure

from prismap._files import atomic_path
from prismap.errors import PrismapInputError
from prismap.evaluate import MapScores
from prismap.grid import OccupancyMap
from prismap.io import GroundTruthOccupancy


def slice_raster(truth, layer):
    """Key window of ``truth``'s observed voxels in z layer ``layer``.

    Returns
    -------
    keys : (H, W, 3) int64
        Voxel key of each raster cell; row = y key - y0, column = x key - x0.
    truth_image : (H, W) float64
        1 = occupied, 0 = free, NaN = not observed by a perfect sensor (not scored).
    extent_m : (4,) float64, metres
        ``(x_min, x_max, y_min, y_max)`` of the raster's outer edges.
    """
    observed = truth.observed_keys[truth.observed_keys[:, 2] == layer]
    if observed.shape[0] == 0:
        raise PrismapInputError(f"the ground truth observes no voxel in z layer {layer}: nothing to draw")
    x0, y0 = observed[:, 0].min(), observed[:, 1].min()
    width, height = observed[:, 0].max() - x0 + 1, observed[:, 1].max() - y0 + 1
    ys, xs = np.mgrid[y0 : y0 + height, x0 : x0 + width]
    keys = np.stack([xs, ys, np.full_like(xs, layer)], axis=-1).astype(np.int64)
    image = np.full((height, width), np.nan)
    image[observed[:, 1] - y0, observed[:, 0] - x0] = 0.0
    occupied = truth.observed_occupied_keys
    occupied = occupied[occupied[:, 2] == layer]
    image[occupied[:, 1] - y0, occupied[:, 0] - x0] = 1.0
    v = truth.voxel_size_m
    return keys, image, np.array([x0 * v, (x0 + width) * v, y0 * v, (y0 + height) * v])


def plot_map_slices(
    maps_by_model: Mapping[str, OccupancyMap],
    truth: GroundTruthOccupancy,
    *,
    layer: int,
    path: str | os.PathLike[str] | None = None,
    title: str = "",
    scores_by_model: Mapping[str, MapScores | None] | None = None,
) -> Figure:
    """One horizontal voxel layer of each map beside the ground truth, on one shared window.

    Parameters
    ----------
    maps_by_model : dict of str -> OccupancyMap
        Maps on ``truth``'s grid (same voxel size).
    truth : GroundTruthOccupancy
    layer : int, keyword-only
        z key of the layer (0 for the 2-D worlds; ``floor(z / voxel_size_m)`` for a height z in metres).
    path : str or Path or None, keyword-only
        Where to save the figure (format from the suffix), written atomically.
    title : str, keyword-only
    scores_by_model : dict of str -> MapScores or None, keyword-only
        If given, each panel's title shows the map's Brier score and log-loss.

    Returns
    -------
    matplotlib.figure.Figure
        Panels of ``P(occupied)`` on a grey scale (white free, black occupied); voxels a map never
        observed are light blue; the window is the ground truth's observed voxels of that layer.
    """
    from matplotlib import colormaps
    from scipy.special import expit

    if not isinstance(maps_by_model, dict) or not maps_by_model:
        raise PrismapInputError(
            f"`maps_by_model` must be a non-empty dict of name -> OccupancyMap; got {maps_by_model!r:.80}"
        )
    for name, grid in maps_by_model.items():
        if abs(grid.voxel_size_m - truth.voxel_size_m) > 1e-9 * truth.voxel_size_m:
            raise PrismapInputError(
                f"map {name!r} has voxel size {grid.voxel_size_m} m; the ground truth's is {truth.voxel_size_m} m"
            )
    if int(layer) != layer:
        raise PrismapInputError(f"`layer` must be an integer z key; got {layer!r}")
    keys, truth_image, extent = slice_raster(truth, int(layer))
    panels = [("ground truth", truth_image)]
    for name, grid in maps_by_model.items():
        log, count = grid.lookup_keys(keys.reshape(-1, 3))
        probability = expit(log.astype(np.float64))
        probability[count == 0] = np.nan
        label = name
        if scores_by_model and name in scores_by_model:
            s = scores_by_model[name]
            label = f"{name}: Brier {s.brier:.3f}, LL {s.log_loss:.3f}"
        panels.append((label, probability.reshape(truth_image.shape)))
    n_cols = min(3, len(panels))
    n_rows = -(-len(panels) // n_cols)
    aspect = (extent[3] - extent[2]) / max(extent[1] - extent[0], 1e-9)
    fig = Figure(figsize=(4.0 * n_cols, 0.6 + 4.0 * n_rows * min(max(aspect, 0.3), 1.5)), layout="constrained")
    axes = fig.subplots(n_rows, n_cols, squeeze=False)
    cmap = colormaps["gray_r"].with_extremes(bad="#cfe3f5")
    image = None
    for ax, (label, data) in zip(axes.flat, panels):
        image = ax.imshow(data, origin="lower", extent=extent, cmap=cmap, vmin=0.0, vmax=1.0, interpolation="nearest")
        ax.set_title(label, fontsize="small")
        ax.set(xlabel="x (m)", ylabel="y (m)")
    for ax in axes.flat[len(panels) :]:
        ax.set_axis_off()
    fig.colorbar(image, ax=axes, shrink=0.8, label="P(occupied); light blue = unknown")
    return _finish(fig, title, path, dpi=110)


MAX_POINTS_3D = 60_000
"""Most voxels one 3-D panel draws; more are thinned to every k-th (seeded choice, the same for every panel)."""


def plot_map_3d(
    grid: OccupancyMap,
    truth: GroundTruthOccupancy,
    *,
    path: str | os.PathLike[str] | None = None,
    title: str = "",
    threshold: float = 0.5,
    max_height_m: float | None = None,
    elev: float = 32.0,
    azim: float = -58.0,
) -> Figure:
    """The map's occupied voxels beside the ground truth's, in 3-D from one viewpoint.

    Parameters
    ----------
    grid : OccupancyMap
        A map on ``truth``'s grid (same voxel size).
    truth : GroundTruthOccupancy
    path : str or Path or None, keyword-only
        Where to save the figure (format from the suffix), written atomically.
    title : str, keyword-only
    threshold : float, keyword-only
        A map voxel is drawn when P(occupied) > ``threshold``.
    max_height_m : float or None, keyword-only
        Voxels whose centre lies above this height (z, metres) are left out of both panels, so a ceiling
        does not hide the room; None = below the truth's highest occupied layer.
    elev, azim : float, keyword-only
        The viewpoint (degrees, :meth:`mpl_toolkits.mplot3d.axes3d.Axes3D.view_init`).

    Returns
    -------
    matplotlib.figure.Figure
        Two panels, the truth's occupied voxels that a perfect sensor observed and the map's voxels above
        ``threshold`` within the truth's observed box, coloured by height, with the voxel counts.
    """
    if abs(grid.voxel_size_m - truth.voxel_size_m) > 1e-9 * truth.voxel_size_m:
        raise PrismapInputError(
            f"the map has voxel size {grid.voxel_size_m} m; the ground truth's is {truth.voxel_size_m} m"
        )
    if not 0.0 <= threshold < 1.0:
        raise PrismapInputError(f"`threshold` must lie in [0, 1); got {threshold!r}")
    voxel = truth.voxel_size_m
    truth_keys = truth.observed_occupied_keys
    if truth_keys.shape[0] == 0:
        raise PrismapInputError("the ground truth has no observed occupied voxel: nothing to draw")
    top = truth_keys[:, 2].max() - 1 if max_height_m is None else np.floor(max_height_m / voxel)
    lo, hi = truth.observed_keys.min(axis=0), truth.observed_keys.max(axis=0)
    keys = _above(grid, threshold)
    inside = np.all((keys >= lo) & (keys <= hi), axis=1)
    panels = [
        (f"ground truth: {int(np.sum(truth_keys[:, 2] <= top)):,} occupied voxels", truth_keys),
        (f"map: {int(np.sum(inside & (keys[:, 2] <= top))):,} voxels with P > {threshold:g}", keys[inside]),
    ]
    fig = Figure(figsize=(11.0, 5.0), layout="constrained")
    rng = np.random.default_rng(0)
    for i, (label, shown) in enumerate(panels):
        shown = shown[shown[:, 2] <= top]
        if shown.shape[0] > MAX_POINTS_3D:
            shown = shown[np.sort(rng.choice(shown.shape[0], MAX_POINTS_3D, replace=False))]
        centres = (shown + 0.5) * voxel
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        ax.scatter(
            centres[:, 0],
            centres[:, 1],
            centres[:, 2],
            c=centres[:, 2],
            cmap="viridis",
            marker="s",
            s=float(np.clip(3e4 / max(len(centres), 1), 1.5, 10.0)),
            linewidths=0,
            depthshade=True,
            vmin=(lo[2] + 0.5) * voxel,
            vmax=(top + 0.5) * voxel,
        )
        ax.set(
            xlim=(lo[0] * voxel, (hi[0] + 1) * voxel),
            ylim=(lo[1] * voxel, (hi[1] + 1) * voxel),
            zlim=(lo[2] * voxel, (top + 1) * voxel),
            xlabel="x (m)",
            ylabel="y (m)",
            zlabel="z (m)",
        )
        ax.set_box_aspect((hi[0] - lo[0] + 1, hi[1] - lo[1] + 1, top - lo[2] + 1))
        ax.view_init(elev=elev, azim=azim)
        ax.set_title(label, fontsize="small")
    return _finish(fig, title, path, dpi=90)


def _finish(fig, title, path, *, dpi):
    """Title ``fig`` and save it to ``path`` (if any) atomically; return it."""
    if title:
        fig.suptitle(title)
    if path is not None:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi)
    return fig


def _above(grid, threshold):
    """Keys of the known voxels with P(occupied) > ``threshold``."""
    from scipy.special import logit

    keys, log, _ = grid.known_voxels()
    return keys[log > logit(threshold)]
