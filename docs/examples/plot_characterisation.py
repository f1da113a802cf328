"""
Characterise a stereo matcher
=============================

Block matching's disparity errors on the Middlebury Motorcycle pair (which ships with scikit-image), with
the Gaussian mixtures EM fits to them for G = 1..4 components; the selected G predicts held-out errors best.
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt

from prismap.characterise import characterise_matcher, write_characterisation
from prismap.io import load_middlebury_motorcycle
from prismap.stereo import make_matcher

frame = load_middlebury_motorcycle()
matcher = make_matcher("bm", num_disparities=272)
result = characterise_matcher([frame], matcher, conditioned=False, progress=False)
print(f"selected G = {result.model.selected_components}")

with tempfile.TemporaryDirectory() as folder:
    paths = write_characterisation(result, Path(folder))
    image = plt.imread(paths["figure"])
fig, ax = plt.subplots(figsize=(9, 4.5), layout="constrained")
ax.imshow(image)
ax.set_axis_off()
