"""The memory budget every up-front size check compares against, so no input can exhaust the machine.

A request is refused when it exceeds half of what the process can still get: the smaller of the
machine's available memory (``MemAvailable`` in ``/proc/meminfo``) and the room left under the address-space
limit (``RLIMIT_AS``, e.g. ``ulimit -v``) beyond the process's current size.
"""

import os
import resource

from prismap.errors import PrismapInputError

#: Fraction of the available memory one request may take (the rest is for copies and temporaries).
BUDGET_FRACTION = 0.5


def _meminfo_bytes(field, path="/proc/meminfo"):
    try:
        with open(path, encoding="ascii") as handle:
            for line in handle:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def physical_memory_bytes():
    """Bytes of physical memory of the machine (None where the system does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def address_space_room_bytes():
    """Bytes the address-space limit (``RLIMIT_AS``) leaves beyond the process's current size; None without a
    limit."""
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY:
        return None
    used = _meminfo_bytes("VmSize", "/proc/self/status") or 0
    return max(soft - used, 0)


def memory_budget():
    """Bytes a single allocation may take: half of what the process can still allocate."""
    available = _meminfo_bytes("MemAvailable")
    if available is None:
        available = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    room = address_space_room_bytes()
    if room is not None:
        available = min(available, room)
    return int(available * BUDGET_FRACTION)


def check_memory(nbytes, what, fix=""):
    """Raise :class:`PrismapInputError` if ``nbytes`` exceeds :func:`memory_budget`.

    Parameters
    ----------
    nbytes : int or float
        The memory the request needs, bytes.
    what : str
        What needs it, with the parameter responsible, e.g. ``"PRISM's table for sigma 1e-4 px"``.
    fix : str
        Optional advice appended to the message (what to change).
    """
    budget = memory_budget()
    if not nbytes <= budget:
        advice = f"; {fix}" if fix else ""
        raise PrismapInputError(
            f"{what} needs {_size(nbytes)}, more than the memory budget of {_size(budget)} "
            f"(half the memory available){advice}"
        )


def _size(nbytes):
    units = ("B", "KiB", "MiB", "GiB", "TiB", "PiB")
    power = 0
    while abs(nbytes) >= 1024 and power < len(units) - 1:
        nbytes /= 1024
        power += 1
    return f"{nbytes:.3g} {units[power]}"
