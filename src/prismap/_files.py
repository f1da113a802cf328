"""Atomic file writing: results appear whole or not at all, and existing files survive errors."""

import contextlib
import os
import tempfile
from pathlib import Path

from prismap.errors import PrismapInputError


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path beside ``path``; rename it onto ``path`` only if the block succeeds.

    The temporary file keeps the target's suffix, so writers that pick a format by suffix
    (``np.savez`` adds ``.npz``, matplotlib chooses by extension) behave as for the real name.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=path.suffix + ".tmp" + path.suffix)
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_text_atomic(path, text):
    """Write ``text`` to ``path`` atomically (UTF-8)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def check_output_dir(path, option):
    """Raise a :class:`PrismapInputError` unless ``path`` is, or can be made, a writable directory.

    Called before a long run, so a bad ``--out`` fails at once rather than after the work. Nothing is
    created: a missing directory passes when its nearest existing ancestor is a writable directory.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise PrismapInputError(f"{option} {path}: exists and is not a directory")
    existing = next(p for p in (path.absolute(), *path.absolute().parents) if p.exists())
    if not existing.is_dir():
        raise PrismapInputError(f"{option} {path}: {existing} is a file, not a directory")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise PrismapInputError(f"{option} {path}: {existing} is not writable")
