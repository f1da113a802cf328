"""Resumable runs: a partial map plus the fingerprint of what produced it, both written atomically.

A checkpoint is two files beside each other: ``NAME.npz`` (a map file, :func:`prismap.io.save_map`)
and ``NAME.json`` (format, fingerprint, frames done). The JSON is written first, when the run starts,
so a map checkpoint never exists without the fingerprint that vouches for it. How many frames the map
holds is the map's own ``n_frames`` (written in the same atomic file as the voxels), so the two files
can never disagree about progress; the JSON's ``frames_done`` is for people.
"""

import hashlib
import json
from pathlib import Path

from prismap._files import write_text_atomic
from prismap.errors import PrismapInputError
from prismap.io import load_map, save_map
from prismap.pipeline._config import DISPARITY_FROM_MATCHER, DISPARITY_FROM_SEQUENCE

FORMAT = "prismap-map-checkpoint"
FORMAT_VERSION = 1


def run_fingerprint(sequence, config):
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


def open_checkpoint(path, fingerprint):
    """Start or resume a checkpointed run; returns the checkpointed map or None.

    Parameters
    ----------
    path : str or Path
        Checkpoint name; the files are ``path`` with suffixes ``.npz`` and ``.json``.
    fingerprint : str
        :func:`run_fingerprint` of this run.

    Raises
    ------
    PrismapInputError
        The checkpoint was written by a run with another config or other inputs, or is unreadable: it
        is refused (never silently overwritten) and the message says which file to delete.
    """
    map_path, meta_path = _paths(path)
    if meta_path.is_file():
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise PrismapInputError(f"checkpoint {meta_path}: not valid JSON ({exc}); delete it to start afresh") from None
        if not isinstance(meta, dict) or meta.get("format") != FORMAT or meta.get("format_version") != FORMAT_VERSION:
            raise PrismapInputError(f"checkpoint {meta_path}: not a {FORMAT} version {FORMAT_VERSION} file")
        if meta.get("fingerprint") != fingerprint:
            raise PrismapInputError(
                f"checkpoint {meta_path} was written by a run with another configuration or other input "
                f"frames; refusing to resume from it. Delete {meta_path} and {map_path} to start afresh"
            )
        return load_map(map_path) if map_path.is_file() else None
    if map_path.is_file():
        raise PrismapInputError(
            f"checkpoint map {map_path} has no {meta_path.name} to say which run wrote it; delete it to start afresh"
        )
    _write_meta(meta_path, fingerprint, 0)
    return None


def save_checkpoint(path, fingerprint, grid):
    """Write ``grid`` as the checkpoint map (atomic), then record its ``n_frames`` in the JSON."""
    map_path, meta_path = _paths(path)
    save_map(grid, map_path)
    _write_meta(meta_path, fingerprint, grid.n_frames)


def remove_checkpoint(path):
    """Delete a checkpoint's files (once the final result is safely written)."""
    for file in _paths(path):
        file.unlink(missing_ok=True)


def _write_meta(meta_path, fingerprint, frames_done):
    text = json.dumps({"format": FORMAT, "format_version": FORMAT_VERSION, "fingerprint": fingerprint,
                       "frames_done": int(frames_done)}, indent=1)
    write_text_atomic(meta_path, text + "\n")
