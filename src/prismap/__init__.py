"""prismap: dense 3-D occupancy mapping from stereo cameras with measured error models.

Subpackages (imported on first use, so ``import prismap`` stays cheap):

- :mod:`prismap.camera`        stereo camera geometry, rectification, triangulation
- :mod:`prismap.stereo`        stereo matchers behind one interface
- :mod:`prismap.gmm`           1-D Gaussian mixtures and their EM fit
- :mod:`prismap.characterise`  matcher error statistics against ground truth
- :mod:`prismap.sensor_models` inverse sensor models (ideal, hit/miss, convolution, Andert, PRISM)
- :mod:`prismap.grid`          the sparse voxel occupancy map
- :mod:`prismap.io`            dataset readers and map files
- :mod:`prismap.sim`           synthetic worlds with exact ground truth
- :mod:`prismap.evaluate`      scores of maps against ground truth
- :mod:`prismap.study`         the sensor models side by side along one ray (``models compare``)
- :mod:`prismap.pipeline`      frames in, map out
- :mod:`prismap.experiment`    end-to-end workflows on worlds with exact ground truth, and the demo
- :mod:`prismap.viewer`        the 3-D map viewer in the browser
"""

import importlib
from importlib.metadata import PackageNotFoundError, version

from prismap.errors import PrismapInputError

try:
    __version__ = version("prismap")  # the one version source: pyproject.toml, through the installed metadata
except PackageNotFoundError:  # a source tree on sys.path that was never installed
    __version__ = "0+unknown"

_SUBPACKAGES = (
    "camera",
    "stereo",
    "gmm",
    "characterise",
    "sensor_models",
    "grid",
    "io",
    "sim",
    "evaluate",
    "study",
    "pipeline",
    "experiment",
    "plots",
    "cli",
    "viewer",
)

__all__ = ["PrismapInputError", "__version__", *_SUBPACKAGES]


def __getattr__(name):
    if name in _SUBPACKAGES:
        return importlib.import_module(f"prismap.{name}")
    raise AttributeError(f"module 'prismap' has no attribute {name!r}")
