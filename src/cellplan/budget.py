"""Resource guards: how much memory this machine has, and refusing work that cannot fit.

Each planner estimates the memory of a request from the arrays it will allocate (count x
dtype size) before it allocates any of them, and calls :func:`require` with the total;
a request that needs more than the memory available is refused with one line, e.g.
``cells 1024,1024,1024: needs about 190 GB for 17 modes; this machine has 24 GB
available``. The estimates live beside the planners; this module only knows bytes.

``CELLPLAN_MEMORY_LIMIT`` (bytes, or a size such as ``2GB``, ``512MiB``) lowers the
memory cellplan assumes it may use, for machines shared with other work.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from cellplan.errors import ArgumentError, CellplanError, Problem

#: Environment variable that caps the memory cellplan assumes it may use.
LIMIT_VARIABLE = "CELLPLAN_MEMORY_LIMIT"

_UNITS = {
    "": 1,
    "B": 1,
    "KB": 10**3,
    "MB": 10**6,
    "GB": 10**9,
    "TB": 10**12,
    "KIB": 2**10,
    "MIB": 2**20,
    "GIB": 2**30,
    "TIB": 2**40,
}


def parse_bytes(text: str) -> int:
    """``"2GB"``, ``"512 MiB"`` or ``"1000000"`` as a number of bytes (ValueError if not)."""
    match = re.fullmatch(r"\s*([0-9]+(?:\.[0-9]+)?)\s*([A-Za-z]*)\s*", text)
    if match is None or match.group(2).upper() not in _UNITS:
        raise ValueError(f"not a size: {text!r}")
    return int(float(match.group(1)) * _UNITS[match.group(2).upper()])


def format_bytes(n: float) -> str:
    """A size for people: ``190 GB``, ``2.4 MB``, ``512 B`` (decimal units)."""
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            value = n / size
            return f"{value:.0f} {unit}" if value >= 10 else f"{value:.1f} {unit}"
    return f"{int(n)} B"


def _meminfo_available() -> int | None:
    try:
        text = Path("/proc/meminfo").read_text()
    except OSError:
        return None
    match = re.search(r"^MemAvailable:\s+(\d+) kB", text, re.MULTILINE)
    return int(match.group(1)) * 1024 if match else None


def _cgroup_available() -> int | None:
    """Room left under a cgroup v2 memory limit (containers), if there is one."""
    base = Path("/sys/fs/cgroup")
    try:
        limit = (base / "memory.max").read_text().strip()
        used = int((base / "memory.current").read_text().strip())
    except (OSError, ValueError):
        return None
    if limit == "max":
        return None
    try:
        return max(0, int(limit) - used)
    except ValueError:
        return None


def _address_space_available() -> int | None:
    """Room left under the process's address-space limit (``ulimit -v``), if there is one.

    The limit counts virtual memory, so the room is the limit less the process's present
    virtual size (``VmSize``), not less what it has touched.
    """
    try:
        import resource
    except ImportError:  # pragma: no cover - not POSIX
        return None
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY:
        return None
    try:
        text = Path("/proc/self/status").read_text()
    except OSError:  # pragma: no cover - no procfs
        return soft
    match = re.search(r"^VmSize:\s+(\d+) kB", text, re.MULTILINE)
    used = int(match.group(1)) * 1024 if match else 0
    return max(0, soft - used)


def available_memory() -> int:
    """Bytes of memory this process may still allocate without swapping.

    The smallest of: the kernel's ``MemAvailable``, the room left under a cgroup limit,
    the room left under the address-space limit (``ulimit -v``), and
    ``CELLPLAN_MEMORY_LIMIT``. Falls back to the physical memory when the system says
    nothing (non-Linux).
    """
    found = [
        v
        for v in (_meminfo_available(), _cgroup_available(), _address_space_available())
        if v is not None
    ]
    if not found:
        try:
            found.append(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
        except (ValueError, OSError, AttributeError):  # pragma: no cover - exotic systems
            found.append(2**63 - 1)
    text = os.environ.get(LIMIT_VARIABLE)
    if text:
        try:
            found.append(parse_bytes(text))
        except ValueError:
            raise ArgumentError(
                f"expected a size such as 2GB or 512MiB, got {text!r}", LIMIT_VARIABLE
            ) from None
    return min(found)


def require(
    need: float, field: str, what: str = "", error: type[CellplanError] = ArgumentError
) -> None:
    """Refuse (``error`` naming ``field``) a request that needs more than is available.

    ``what`` completes the message: ``needs about 190 GB <what>; this machine has 24 GB
    available``. Pass ``error=ScenarioError`` when ``field`` names a scenario field.
    """
    have = available_memory()
    if need > have:
        extra = f" {what}" if what else ""
        raise error(
            [
                Problem(
                    field,
                    f"needs about {format_bytes(need)}{extra}; this machine has "
                    f"{format_bytes(have)} available",
                )
            ]
        )
