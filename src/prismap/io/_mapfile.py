"""The versioned ``.npz`` map file (DESIGN.md): everything needed to resume, merge or compare a map.

Fields: ``format`` ("prismap-map"), ``format_version`` (2), ``voxel_size_m``, ``p0``, ``ndim``,
``policy`` (the per-frame policies used, "+"-joined), ``clamp`` ((2,) probabilities, NaN = off),
``occupied_threshold``, ``free_threshold``, ``n_frames``, ``keys`` ((N, 3) int32 voxel keys,
``floor(x / voxel_size)``), ``log_odds`` ((N,) float64, multiples of ``2**-20``: the map's fixed-point
log-odds, exact) and ``counts`` ((N,) uint16, frames that observed each voxel), ``fusion_model``
("independent", "persistent-failure", "failure-mixture" or "failure-clamp": how the map reads its sums,
docs/SENSOR_MODELS.md section 9) and ``fusion`` ((2,) that reading's rate and persistence, NaN where it has
none). Only observed voxels are stored. Version 1 files (float32 log-odds) are still read; their values are
rounded to the fixed point. Version 1 and 2 files have no ``fusion`` and read as independent; version 3 files have no
``fusion_model`` and read their ``fusion`` as persistent failure (NaN = independent).
"""

from __future__ import annotations

import os
from dataclasses import fields as dataclass_fields
from pathlib import Path

import numpy as np

from prismap._files import atomic_path, save_npz
from prismap.errors import PrismapInputError
from prismap.grid import READINGS, OccupancyMap
from prismap.grid._keys import check_voxel_size
from prismap.io._npz import INTEGER, REAL, TEXT, array_field, read_npz

FORMAT = "prismap-map"
FORMAT_VERSION = 4
READABLE_VERSIONS = (1, 2, 3, 4)
"""Version 1 held float32 log-odds; version 2 the map's fixed-point log-odds as exact float64; version 3 adds
``fusion``; version 4 ``fusion_model``."""
_FUSION_SPEC = {"fusion": array_field((2,), "float")}
_FUSION_MODEL_SPEC = {"fusion_model": TEXT}
_SPEC = {
    "format": TEXT,
    "format_version": INTEGER,
    "voxel_size_m": REAL,
    "p0": REAL,
    "ndim": INTEGER,
    "policy": TEXT,
    "clamp": array_field((2,), "float"),
    "occupied_threshold": REAL,
    "free_threshold": REAL,
    "n_frames": INTEGER,
    "keys": array_field((None, 3), "integer"),
    "log_odds": array_field((None,), "float"),
    "counts": array_field((None,), "integer"),
}
#: Memory per stored voxel while loading: the arrays (12 + 8 + 2 bytes), the map's storage and the
#: duplicate check's sorted copy, rounded up.
_BYTES_PER_VOXEL = 64


def save_map(grid: OccupancyMap, path: str | os.PathLike[str]) -> None:
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
    reading = grid.fusion
    parameters = () if reading is None else tuple(getattr(reading, field.name) for field in dataclass_fields(reading))
    fusion = np.array(parameters + (np.nan,) * (2 - len(parameters)))
    fusion_model = "independent" if reading is None else reading.name
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:
        save_npz(
            handle,
            format=np.array(FORMAT),
            format_version=np.array(FORMAT_VERSION),
            voxel_size_m=np.array(grid.voxel_size_m),
            p0=np.array(grid.p0),
            ndim=np.array(grid.ndim),
            policy=np.array("+".join(grid.policies)),
            clamp=clamp,
            occupied_threshold=np.array(grid.occupied_threshold),
            free_threshold=np.array(grid.free_threshold),
            n_frames=np.array(grid.n_frames),
            keys=keys,
            log_odds=log,
            counts=counts,
            fusion=fusion,
            fusion_model=np.array(fusion_model),
        )


def load_map(path: str | os.PathLike[str]) -> OccupancyMap:
    """Read a map written by :func:`save_map`.

    Every field's type and rank, and the memory the declared voxels need, are checked from the archive's
    headers before any array is loaded.

    Raises
    ------
    PrismapInputError
        The file is missing, not an ``.npz`` archive, truncated, of another format or version, lacks a
        field, holds a field of the wrong type or rank, a negative ``n_frames``, a voxel size beyond
        :data:`~prismap.grid._keys.MAX_VOXEL_SIZE_M`, a key twice, or declares
        more voxels than the memory budget holds; the message names the file and the problem.
    """
    path = Path(path)
    if not path.is_file():
        raise PrismapInputError(f"{path}: no such map file")
    fields = read_npz(path, "map file", _SPEC, loaded_bytes_per_row=_BYTES_PER_VOXEL)
    if fields["format"] != FORMAT:
        raise PrismapInputError(f"{path}: not a prismap map file (format {fields['format']!r}, expected {FORMAT!r})")
    if fields["format_version"] not in READABLE_VERSIONS:
        raise PrismapInputError(
            f"{path}: map format version {fields['format_version']} is not supported; expected one of "
            f"{list(READABLE_VERSIONS)}"
        )
    if fields["n_frames"] < 0:
        raise PrismapInputError(f"{path}: `n_frames` must be >= 0; got {fields['n_frames']}")
    try:
        check_voxel_size(fields["voxel_size_m"])
    except PrismapInputError as exc:
        raise PrismapInputError(f"{path}: {exc}") from None
    keys = fields["keys"]
    if len(np.unique(keys, axis=0)) != len(keys):
        raise PrismapInputError(f"{path}: `keys` holds {len(keys) - len(np.unique(keys, axis=0))} duplicate voxel keys")
    clamp = fields["clamp"]
    try:
        reading = _reading(path, fields["format_version"])
        grid = OccupancyMap(
            fields["voxel_size_m"],
            p0=fields["p0"],
            ndim=fields["ndim"],
            clamp=None if np.isnan(clamp).any() else tuple(float(c) for c in clamp),
            occupied_threshold=fields["occupied_threshold"],
            free_threshold=fields["free_threshold"],
            fusion=reading,
        )
        grid.set_voxels(keys, fields["log_odds"], fields["counts"])
    except PrismapInputError as exc:
        raise PrismapInputError(f"{path}: {exc}") from None
    grid.policies = tuple(fields["policy"].split("+")) if fields["policy"] else ()
    grid.n_frames = fields["n_frames"]
    return grid


def _reading(path, version):
    """The map's :class:`~prismap.grid.MapReading` from its ``fusion`` fields, or None (independent)."""
    if version < 3:
        return None
    fusion = read_npz(path, "map file", _FUSION_SPEC)["fusion"]
    name = read_npz(path, "map file", _FUSION_MODEL_SPEC)["fusion_model"] if version >= 4 else "persistent-failure"
    if name == "independent" or (version == 3 and np.isnan(fusion).any()):
        return None
    if name not in READINGS:
        raise PrismapInputError(f"`fusion_model` must be one of {['independent', *READINGS]}; got {name!r}")
    reading = READINGS[name]
    return reading(**{field.name: float(v) for field, v in zip(dataclass_fields(reading), fusion)})
