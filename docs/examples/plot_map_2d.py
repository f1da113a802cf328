"""
A 2-D map by every model
========================

The 2-D office scanned by a simulated stereo range sensor whose errors are drawn from a known mixture, mapped by
every sensor model and scored against the exact ground truth (Brier score and log-loss in each title).
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt

from prismap.experiment import run_office2d

with tempfile.TemporaryDirectory() as folder:
    result = run_office2d(Path(folder), quick=True, n_frames=8)
    slices = next(path for path, _ in result.artifacts if Path(path).name.startswith("map_slices"))
    image = plt.imread(slices)
for cell in result.cells:
    print(f"{cell.model:12s} Brier {cell.scores.brier:.4f}  log-loss {cell.scores.log_loss:.4f}")
fig, ax = plt.subplots(figsize=(10, 7), layout="constrained")
ax.imshow(image)
ax.set_axis_off()
