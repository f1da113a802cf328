"""The versioned ``.npz`` map file (DESIGN.md): everything needed to resume, merge or compare a map.

Fields: ``format`` ("prismap-map"), ``format_version`` (2), ``voxel_size_m``, ``p0``, ``ndim``,
``policy`` (the per-frame policies used, "+"-joined), ``clamp`` ((2,) probabilities, NaN = off),
``occupied_threshold``, ``free_threshold``, ``n_frames``, ``keys`` ((N, 3) int32 voxel keys,
``floor(x / voxel_size)``), ``log_odds`` ((N,) float64, multiples of ``2**-20``: the map's fixed-point
log-odds, exact) and ``counts`` ((N,) uint16, frames that observed each voxel). Only observed voxels are
stored. Version 1 files (float32 log-odds) are still read; their values are rounded to the fixed point.
"""

import zipfile
from pathlib import Path

import numpy as np

from prismap._files import atomic_path
from prismap.errors import PrismapInputError
from prismap.grid import OccupancyMap

FORMAT = "prismap-map"
FORMAT_VERSION = 2
READABLE_VERSIONS = (1, 2)
"""Version 1 held float32 log-odds; version 2 the map's fixed-point log-odds as exact float64."""
_FIELDS = ("format", "format_version", "voxel_size_m", "p0", "ndim", "policy", "clamp", "occupied_threshold",
           "free_threshold", "n_frames", "keys", "log_odds", "counts")


def save_map(grid, path):
    """Write ``grid`` to ``path`` (``.npz``) atomically: the file appears whole or not at all.

    Parameters
    ----------
    grid : OccupancyMap
    path : str or Path
        Destination; ``.npz`` is the expected suffix.
    """
    if not isinstance(grid, OccupancyMap):
        raise PrismapInputError(f"`grid` must be an OccupancyMap; got {type(grid).__name__}")
    keys, log, counts = grid.known_voxels()
    clamp = np.array(grid.clamp if grid.clamp is not None else (np.nan, np.nan))
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:
        np.savez_compressed(
            handle, format=np.array(FORMAT), format_version=np.array(FORMAT_VERSION),
            voxel_size_m=np.array(grid.voxel_size_m), p0=np.array(grid.p0), ndim=np.array(grid.ndim),
            policy=np.array("+".join(grid.policies)), clamp=clamp,
            occupied_threshold=np.array(grid.occupied_threshold), free_threshold=np.array(grid.free_threshold),
            n_frames=np.array(grid.n_frames), keys=keys, log_odds=log, counts=counts,
        )


def load_map(path):
    """Read a map written by :func:`save_map`.

    Raises
    ------
    PrismapInputError
        The file is missing, not an ``.npz`` archive, truncated, of another format or version, or
        lacks a field; the message names the file and the problem.
    """
    path = Path(path)
    if not path.is_file():
        raise PrismapInputError(f"{path}: no such map file")
    try:
        data = np.load(path, allow_pickle=False)
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise PrismapInputError(f"{path}: not a prismap map (.npz archive); got a single .npy array")
        with data:
            missing = [f for f in _FIELDS if f not in data.files]
            if "format" in missing or ("format" in data.files and str(data["format"]) != FORMAT):
                raise PrismapInputError(f"{path}: not a prismap map file (no format field {FORMAT!r})")
            version = int(data["format_version"]) if "format_version" in data.files else None
            if version not in READABLE_VERSIONS:
                raise PrismapInputError(f"{path}: map format version {version} is not supported; expected one of "
                                        f"{list(READABLE_VERSIONS)}")
            if missing:
                raise PrismapInputError(f"{path}: map file lacks field(s) {missing}")
            fields = {name: data[name] for name in _FIELDS}
    except (zipfile.BadZipFile, EOFError, OSError, ValueError) as exc:
        if isinstance(exc, PrismapInputError):
            raise
        raise PrismapInputError(f"{path}: not a readable .npz map file (truncated or corrupt?): {exc}") from None
    clamp = fields["clamp"]
    grid = OccupancyMap(
        float(fields["voxel_size_m"]), p0=float(fields["p0"]), ndim=int(fields["ndim"]),
        clamp=None if np.isnan(clamp).any() else tuple(float(c) for c in clamp),
        occupied_threshold=float(fields["occupied_threshold"]), free_threshold=float(fields["free_threshold"]),
    )
    try:
        grid.set_voxels(fields["keys"], fields["log_odds"], fields["counts"])
    except PrismapInputError as exc:
        raise PrismapInputError(f"{path}: {exc}") from None
    policy = str(fields["policy"])
    grid.policies = tuple(policy.split("+")) if policy else ()
    grid.n_frames = int(fields["n_frames"])
    return grid
