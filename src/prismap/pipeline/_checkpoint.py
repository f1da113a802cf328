"""Resumable runs: a partial map plus the fingerprint of what produced it, both written atomically.

A checkpoint is two files beside each other: ``NAME.npz`` (a map file, :func:`prismap.io.save_map`)
and ``NAME.json`` (format, fingerprint, the SHA-256 of the map files it vouches for, frames done). The JSON is
written first, when the run starts, so a map checkpoint never exists without the fingerprint that vouches
for it. A save writes the new map beside the old one, lists both digests in the JSON, renames the map into
place and then lists only the new digest: a run killed at any point leaves a map the JSON vouches for.
A map the JSON does not vouch for (swapped in from another run, edited) is refused, and so is one whose
voxel size, prior or frame count does not fit the run. How many frames the map holds is the map's own
``n_frames``; the JSON's ``frames_done`` is for people.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path

from prismap._files import atomic_path, write_text_atomic
from prismap.errors import PrismapInputError
from prismap.grid import OccupancyMap
from prismap.io import BagSequence, Sequence, load_map, save_map
from prismap.pipeline._config import DISPARITY_FROM_MATCHER, DISPARITY_FROM_SEQUENCE, MappingConfig

FORMAT = "prismap-map-checkpoint"
FORMAT_VERSION = 2
"""Version 2 added ``map_sha256``; version 1 checkpoints (no digest) are refused with how to start afresh."""


def run_fingerprint(sequence: Sequence | BagSequence, config: MappingConfig) -> str:
    """SHA-256 (hex) of the config and of the inputs it reads from ``sequence``.

    Inputs are fingerprinted cheaply: ``calib.txt`` and the pose file (``poses.txt``, or a KITTI
    tree's ``ROOT/poses/NN.txt``) by content, every selected image
    (and disparity file, when those are the source) by name and size. Rewriting a frame with an image
    of the same byte size is not detected.
    """
    digest = hashlib.sha256(config.fingerprint().encode())
    for name, path in (("calib.txt", sequence.path / "calib.txt"), ("poses.txt", sequence.pose_path)):
        digest.update(name.encode() + (path.read_bytes() if path is not None and path.is_file() else b"<absent>"))
    folders = [sequence.path / "image_2", sequence.path / "image_3"]
    if config.disparity_source == DISPARITY_FROM_SEQUENCE:
        folders.append(sequence.path / "disp")
    elif config.disparity_source != DISPARITY_FROM_MATCHER:
        folders.append(Path(config.disparity_source))
    for index in config.frame_indices(len(sequence)):
        name = sequence.names[index]
        for folder in folders:
            path = folder / name
            digest.update(f"{name}:{path.stat().st_size if path.is_file() else -1};".encode())
    return digest.hexdigest()


def _paths(path):
    path = Path(path)
    return path.with_suffix(".npz"), path.with_suffix(".json")


def open_checkpoint(
    path: str | os.PathLike[str], fingerprint: str, config: MappingConfig | None = None, n_frames: int | None = None
) -> OccupancyMap | None:
    """Start or resume a checkpointed run; returns the checkpointed map or None.

    Parameters
    ----------
    path : str or Path
        Checkpoint name; the files are ``path`` with suffixes ``.npz`` and ``.json``.
    fingerprint : str
        :func:`run_fingerprint` of this run.
    config : MappingConfig or None
        The run's configuration: the map's voxel size and prior must be its own.
    n_frames : int or None
        Frames the run integrates in all: the map may not hold more.

    Raises
    ------
    PrismapInputError
        The checkpoint was written by a run with another config or other inputs, its map is not the one
        its JSON vouches for, does not fit the run, or is unreadable: it is refused (never silently
        overwritten) and the message says which files to delete.
    """
    map_path, meta_path = _paths(path)
    if meta_path.is_file():
        meta = _read_meta(meta_path, map_path)
        if meta.get("fingerprint") != fingerprint:
            raise PrismapInputError(
                f"checkpoint {meta_path} was written by a run with another configuration or other input "
                f"frames; refusing to resume from it. Delete {meta_path} and {map_path} to start afresh"
            )
        if not map_path.is_file():
            return None
        if _digest(map_path) not in meta["map_sha256"]:
            raise PrismapInputError(
                f"checkpoint map {map_path} is not the map {meta_path.name} vouches for (its SHA-256 differs: "
                f"replaced or edited); delete {meta_path} and {map_path} to start afresh"
            )
        grid = load_map(map_path)
        _check_fits(grid, map_path, config, n_frames)
        return grid
    if map_path.is_file():
        raise PrismapInputError(
            f"checkpoint map {map_path} has no {meta_path.name} to say which run wrote it; delete it to start afresh"
        )
    _write_meta(meta_path, fingerprint, 0, [])
    return None


def _read_meta(meta_path, map_path):
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PrismapInputError(f"checkpoint {meta_path}: not valid JSON ({exc}); delete it to start afresh") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT or meta.get("format_version") != FORMAT_VERSION:
        raise PrismapInputError(
            f"checkpoint {meta_path}: not a {FORMAT} version {FORMAT_VERSION} file; delete "
            f"{meta_path} and {map_path} to start afresh"
        )
    digests = meta.get("map_sha256")
    if not isinstance(digests, list) or not all(isinstance(d, str) for d in digests):
        raise PrismapInputError(
            f"checkpoint {meta_path}: `map_sha256` must be a list of SHA-256 digests; got "
            f"{digests!r}; delete {meta_path} and {map_path} to start afresh"
        )
    return meta


def _check_fits(grid, map_path, config, n_frames):
    """Refuse a checkpoint map of another voxel size or prior than ``config``'s, or with more frames than the run."""
    if config is not None:
        for name, mine, theirs in (("voxel size", config.voxel_size_m, grid.voxel_size_m), ("p0", config.p0, grid.p0)):
            if not math.isclose(mine, theirs, rel_tol=1e-12):
                raise PrismapInputError(
                    f"checkpoint map {map_path}: {name} {theirs:g}, this run's is {mine:g}; "
                    "delete the checkpoint to start afresh"
                )
    if n_frames is not None and not 0 <= grid.n_frames <= n_frames:
        raise PrismapInputError(
            f"checkpoint map {map_path}: holds {grid.n_frames} frames, this run has {n_frames}; "
            "delete the checkpoint to start afresh"
        )


def save_checkpoint(path: str | os.PathLike[str], fingerprint: str, grid: OccupancyMap) -> None:
    """Write ``grid`` as the checkpoint map (atomic) and record its digest and ``n_frames`` in the JSON.

    While the new map waits beside the old one the JSON vouches for both (its ``frames_done`` still the
    old map's), so a kill anywhere leaves a resumable checkpoint.
    """
    map_path, meta_path = _paths(path)
    old, old_frames = [], 0
    if map_path.is_file():
        old, old_frames = [_digest(map_path)], _read_meta(meta_path, map_path).get("frames_done", 0)
    with atomic_path(map_path) as staged:
        save_map(grid, staged)
        new = _digest(staged)
        _write_meta(meta_path, fingerprint, old_frames, [new, *old])  # frames_done: the map still in place
    _write_meta(meta_path, fingerprint, grid.n_frames, [new])


def remove_checkpoint(path: str | os.PathLike[str]) -> None:
    """Delete a checkpoint's files (once the final result is safely written): the JSON that vouches for the map
    first, so that no moment shows a checkpoint whose map is already gone."""
    map_path, meta_path = _paths(path)
    meta_path.unlink(missing_ok=True)
    map_path.unlink(missing_ok=True)


def _digest(path):
    """SHA-256 (hex) of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _write_meta(meta_path, fingerprint, frames_done, digests):
    text = json.dumps(
        {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "fingerprint": fingerprint,
            "frames_done": int(frames_done),
            "map_sha256": list(digests),
        },
        indent=1,
    )
    write_text_atomic(meta_path, text + "\n")
