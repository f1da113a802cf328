"""
Every sensor model along one ray
================================

One measured disparity turned into occupancy probabilities by each inverse sensor model, at two distances.
PRISM (thick) is confident near the camera and spreads its evidence as the measurement gets farther; the
classic models keep one shape at every distance.
"""

import matplotlib.pyplot as plt

from prismap.experiment._office2d import SGBM_LIKE_MIXTURE
from prismap.study import RaySetup, compare_models

# A semiglobal-like error mixture (pixels) and the Middlebury Motorcycle rig's focal length x baseline.
setup = RaySetup(focal_baseline=3979.911 * 0.193001, voxel_size_m=0.1, p0=0.05)
comparison = compare_models(SGBM_LIKE_MIXTURE, [2.0, 10.0], setup=setup)

fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), layout="constrained")
for ax, profile in zip(axes, comparison.profiles):
    for name, posterior in profile.posterior.items():
        ax.stairs(posterior, profile.edges_m, baseline=None, label=name, linewidth=2.2 if name == "prism" else 1.1)
    ax.axvline(profile.measured_m, color="0.3", linestyle=":")
    ax.set(xlim=(profile.measured_m - 1.5, profile.measured_m + 1.0), xlabel="distance along the ray (m)",
           ylabel="P(occupied)", title=f"measured {profile.measured_m:.2f} m")
axes[0].legend(fontsize="small")
