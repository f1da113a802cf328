"""Figures of maps: a horizontal slice of every model's map beside the ground truth."""

import numpy as np

from prismap._files import atomic_path
from prismap.errors import PrismapInputError


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


def plot_map_slices(maps_by_model, truth, *, layer, path=None, title="", scores_by_model=None):
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
    from matplotlib.figure import Figure
    from scipy.special import expit

    if not isinstance(maps_by_model, dict) or not maps_by_model:
        raise PrismapInputError(f"`maps_by_model` must be a non-empty dict of name -> OccupancyMap; got {maps_by_model!r:.80}")
    for name, grid in maps_by_model.items():
        if abs(grid.voxel_size_m - truth.voxel_size_m) > 1e-9 * truth.voxel_size_m:
            raise PrismapInputError(f"map {name!r} has voxel size {grid.voxel_size_m} m; the ground truth's is "
                                    f"{truth.voxel_size_m} m")
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
    for ax in axes.flat[len(panels):]:
        ax.set_axis_off()
    fig.colorbar(image, ax=axes, shrink=0.8, label="P(occupied); light blue = unknown")
    if title:
        fig.suptitle(title)
    if path is not None:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=110)
    return fig
