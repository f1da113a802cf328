"""Output files: atomic writes, permissions, stale temporaries, output checks and run locks.

Results appear whole or not at all and existing files survive errors. A temporary file is named
``.NAME.<pid>.<random>.tmp<suffix>`` beside its target; one whose process is gone (killed during a save)
is removed by the next save of the same target. A replaced file keeps its mode; a new one gets
``0666 & ~umask``, as ``open`` would give it.
"""

import contextlib
import errno
import fcntl
import os
import stat
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from prismap.errors import PrismapInputError

NPZ_LEVEL = 1
"""zlib level of the ``.npz`` files prismap writes: the fastest, since a map's keys, log-odds and counts deflate
almost as well at 1 as at ``np.savez_compressed``'s fixed 6, at a fraction of its time."""


def umask_mode(mode=0o666):
    """``mode`` with the process's umask applied (0o666 for files, 0o777 for directories)."""
    current = os.umask(0)
    os.umask(current)
    return mode & ~current


def _pid_alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_temporaries(path):
    """Delete the temporaries of ``path`` left by processes that no longer run; the number removed."""
    path = Path(path)
    removed = 0
    for candidate in path.parent.glob(f".{path.name}.*.tmp{path.suffix}"):
        pid_text = candidate.name[len(path.name) + 2 :].split(".", 1)[0]
        if pid_text.isdigit() and not _pid_alive(int(pid_text)):
            with contextlib.suppress(FileNotFoundError):
                candidate.unlink()
                removed += 1
    return removed


def make_parents(path):
    """Create the missing ancestors of ``path``; the directories created, deepest first.

    Give them to :func:`remove_if_empty` when the write they were made for fails, so that a refused or
    failed run leaves no directory behind.
    """
    created = []
    parent = Path(path).parent
    while not parent.exists():
        created.append(parent)
        parent = parent.parent
    for directory in reversed(created):
        with contextlib.suppress(FileExistsError):
            directory.mkdir(mode=0o777)
    return created


def remove_if_empty(directories):
    """Remove each of ``directories`` (deepest first) that is empty, as a failed run found none of them."""
    for directory in directories:
        try:
            directory.rmdir()
        except OSError:
            return


def _os_message(exc):
    reason = exc.strerror or str(exc)
    if exc.errno == errno.EFBIG:
        reason += " (the file-size limit, ulimit -f)"
    return reason


def save_npz(file, **arrays):
    """Write ``arrays`` to ``file`` (a path or a binary file object) as an ``.npz`` archive that ``np.load`` reads,
    compressed at :data:`NPZ_LEVEL` (``np.savez_compressed`` has no level)."""
    with zipfile.ZipFile(file, "w", zipfile.ZIP_DEFLATED, compresslevel=NPZ_LEVEL) as archive:
        for name, value in arrays.items():
            with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path beside ``path``; rename it onto ``path`` only if the block succeeds.

    The temporary file keeps the target's suffix, so writers that pick a format by suffix
    (``np.savez`` adds ``.npz``, matplotlib chooses by extension) behave as for the real name.

    Raises
    ------
    PrismapInputError
        The file cannot be written (no such directory, a full disk, a file-size limit, permissions);
        the message names ``path`` and the operating system's reason, and ``path`` is left as it was.
    """
    path = Path(path)
    created = []
    try:
        created = make_parents(path)
        remove_stale_temporaries(path)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp" + path.suffix)
    except OSError as exc:
        remove_if_empty(created)
        raise PrismapInputError(f"{path}: cannot write ({_os_message(exc)})") from None
    os.close(fd)
    tmp = Path(tmp)
    done = False
    try:
        try:
            yield tmp
            try:
                mode = stat.S_IMODE(path.stat().st_mode)
            except FileNotFoundError:
                mode = umask_mode()
            os.chmod(tmp, mode)
            os.replace(tmp, path)
            done = True
        except OSError as exc:
            raise PrismapInputError(f"{path}: cannot write ({_os_message(exc)})") from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        if not done:
            remove_if_empty(created)


def write_text_atomic(path, text):
    """Write ``text`` to ``path`` atomically (UTF-8)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


MAX_NAME_BYTES = 200
"""Longest output file name (bytes): the temporary beside it (``.NAME.<pid>.<random>.tmp<suffix>``) and the
lock (``.NAME.lock``) must stay within the file system's 255-byte name limit."""


def check_output(path, option="--out", *, directory=False, inputs=()):
    """Refuse, before any work, an output that cannot be written or would overwrite an input.

    Parameters
    ----------
    path : str or Path
        The output file (``directory=False``) or directory.
    option : str
        The argument's name in messages.
    directory : bool, keyword-only
        Whether ``path`` is a directory the command writes into.
    inputs : iterable of (str, Path), keyword-only
        The run's inputs as ``(role, path)``: a file may not be the output, a directory may not hold it.

    Raises
    ------
    PrismapInputError
        ``path`` names a directory where a file is expected (or a file where a directory is), something
        that is not a regular file (a device, a pipe), one of ``inputs`` or a file inside one, lies under a
        regular file, has a name longer than :data:`MAX_NAME_BYTES`, or lies in a directory this process
        may not write to.
    """
    path = Path(path)
    name_bytes = len(os.fsencode(path.name))
    if name_bytes > MAX_NAME_BYTES:
        raise PrismapInputError(
            f"{option} {str(path)[:60]}...: the file name has {name_bytes} bytes; at most "
            f"{MAX_NAME_BYTES} (MAX_NAME_BYTES, room for the temporary file beside it)"
        )
    if path.exists():
        if directory and not path.is_dir():
            raise PrismapInputError(f"{option} {path}: exists and is not a directory")
        if not directory and path.is_dir():
            raise PrismapInputError(f"{option} {path}: is a directory; expected a file name")
        if not directory and not path.is_file():
            raise PrismapInputError(
                f"{option} {path}: exists and is not a regular file (a device, pipe or socket); expected a file name"
            )
    _check_not_input(path, option, inputs)
    ancestor = path if directory and path.is_dir() else path.parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise PrismapInputError(f"{option} {path}: {ancestor} is not a directory")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise PrismapInputError(f"{option} {path}: no permission to write in {ancestor}")
    return path


def _check_not_input(path, option, inputs):
    """Refuse ``path`` when it is one of ``inputs`` ((role, path) pairs) or lies inside an input directory."""
    resolved = path.resolve()
    for role, source in inputs:
        if source is None or not Path(source).exists():
            continue
        source = Path(source).resolve()
        inside = source.is_dir() and (resolved == source or source in resolved.parents)
        if inside or resolved == source:
            where = "is" if resolved == source else "lies inside"
            raise PrismapInputError(
                f"{option} {path}: {where} {source}, an input of this run ({role}); choose an output elsewhere"
            )


@contextlib.contextmanager
def exclusive_lock(path, option="--out"):
    """Hold an exclusive ``fcntl`` lock on ``path`` (via ``.NAME.lock`` beside it) for the block.

    A second process asking for the same lock while the first holds it gets a
    :class:`PrismapInputError` at once instead of sharing (and corrupting) the file. The lock file is
    removed when the block ends, and so are the directories made for it that the run left empty.
    """
    path = Path(path)
    lock_path = path.parent / f".{path.name}.lock"
    created = []
    try:
        created = make_parents(lock_path)
    except OSError as exc:
        remove_if_empty(created)
        raise PrismapInputError(f"{option} {path}: cannot create its directory ({_os_message(exc)})") from None
    while True:
        try:
            fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, umask_mode())
        except OSError as exc:
            remove_if_empty(created)
            raise PrismapInputError(
                f"{option} {path}: cannot create the lock {lock_path} ({_os_message(exc)})"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            remove_if_empty(created)
            raise PrismapInputError(
                f"{option} {path}: another prismap run is using it (lock {lock_path}); wait for it to finish "
                "or choose another output"
            ) from None
        try:
            same = os.stat(lock_path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # the holder removed the file between our open and flock: lock the new one
    try:
        yield lock_path
    finally:
        with contextlib.suppress(FileNotFoundError):
            lock_path.unlink()
        os.close(fd)
        remove_if_empty(created)
