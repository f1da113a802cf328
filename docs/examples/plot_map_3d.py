"""
A 3-D map and a slice of it
===========================

A few rendered frames of the 3-D room, matched by semiglobal matching, characterised, mapped with conditioned
PRISM, and drawn beside the ground truth: in 3-D, and as the horizontal layer at 1 m.
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt

from prismap.experiment import run_scene3d
from prismap.experiment._results import cell_path
from prismap.io import load_map, read_ground_truth
from prismap.plots import plot_map_3d

with tempfile.TemporaryDirectory() as folder:
    out = Path(folder)
    result = run_scene3d(out, quick=True, n_frames=4, voxel_size_m=0.2, matchers=("sgbm",))
    grid = load_map(cell_path(out, "sgbm", "prism_conditioned").with_suffix(".npz"))
    truth = read_ground_truth(out / "sequence" / "occupancy.npz")
    rendered = out / "map3d.png"
    plot_map_3d(grid, truth, path=rendered)
    images = [plt.imread(rendered)]
    images += [plt.imread(p) for p, _ in result.artifacts if Path(p).name.startswith("map_slices")]

fig, axes = plt.subplots(len(images), 1, figsize=(10, 12), layout="constrained",
                         height_ratios=[image.shape[0] / image.shape[1] for image in images])
for ax, image in zip(axes, images):
    ax.imshow(image)
    ax.set_axis_off()
print(f"p0 = {result.p0:.4f}; {len(result.cells)} maps scored")
