"""Resource guards: how much memory this machine has, and refusing work that cannot fit.

Each planner estimates the memory of a request from the arrays it will allocate (count x
dtype size) before it allocates any of them, and calls :func:`require` with the total;
a request that needs more than the memory available is refused with one line, e.g.
``cells 1024,1024,1024: needs about 190 GB for 17 modes; this machine has 24 GB
available``. The estimates live beside the planners; this module only knows bytes.

``CELLPLAN_MEMORY_LIMIT`` (bytes, or a size such as ``2GB``, ``512MiB``) caps the whole
process's memory (resident set), for machines shared with other work: what the process
already holds (the interpreter and its libraries, about 200 MB) counts against it.

Time is guarded the same way: each planner estimates the seconds of a request from its
size (a per-cell or per-task cost measured once, beside the planner) and calls
:func:`require_time`; more than the time limit (:data:`DEFAULT_TIME_LIMIT_S`, or
``CELLPLAN_TIME_LIMIT``; ``none`` lifts it) is refused with one line. Accepted work
estimated at :data:`NOTICE_SECONDS` or more is announced, through the ``cellplan`` logger
(a warning; the command line prints it as one ``note:`` line on stderr), so a long
``validate`` or ``solve`` says what it is doing even where no progress bar is drawn.
"""

from __future__ import annotations

import logging
import math
import os
import re
import sys
from pathlib import Path

from cellplan.errors import ArgumentError, CellplanError, Problem

#: Environment variable that caps the memory cellplan assumes it may use.
LIMIT_VARIABLE = "CELLPLAN_MEMORY_LIMIT"

#: Environment variable that sets the time limit (seconds, a duration such as ``2h``, or
#: ``none``).
TIME_LIMIT_VARIABLE = "CELLPLAN_TIME_LIMIT"

#: Work estimated to take at least this long (seconds) is announced before it starts.
#: Estimates are pessimistic (the strategies model's per-cell cost was measured on a 2-D
#: grid whose moves span many cells; P6's 3-D model is estimated at 89 s and builds in
#: about 9 s), so the bar is set where no bundled scenario reaches it.
NOTICE_SECONDS = 120.0

log = logging.getLogger(__name__)

DEFAULT_TIME_LIMIT_S = 3600.0
"""Work estimated to take longer than this is refused unless ``CELLPLAN_TIME_LIMIT`` says
otherwise: an hour is well past every bundled scenario and paper experiment, and short
enough that a mistyped grid size is not left running overnight."""

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
    if n >= 1e15:  # beyond any machine; an estimate (a Python int) may exceed a float's range
        return f"10^{len(str(int(n))) - 1} B"
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


def resident_memory() -> int:
    """Bytes this process holds in memory now (its resident set; 0 if the system won't say)."""
    try:
        fields = Path("/proc/self/statm").read_text().split()
        return int(fields[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        pass
    try:
        import resource
    except ImportError:  # pragma: no cover - not POSIX
        return 0
    # The peak, in kB on Linux and bytes on macOS: an upper bound of the present size.
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak) * (1 if sys.platform == "darwin" else 1024)


def available_memory() -> int:
    """Bytes of memory this process may still allocate without swapping.

    The smallest of: the kernel's ``MemAvailable``, the room left under a cgroup limit,
    the room left under the address-space limit (``ulimit -v``), and the room left under
    ``CELLPLAN_MEMORY_LIMIT``: the limit less what this process already holds
    (:func:`resident_memory`). Falls back to the physical memory when the system says
    nothing (non-Linux). (``MemAvailable`` and the cgroup's usage already leave out what
    this process holds.)
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
            limit = parse_bytes(text)
        except ValueError:
            raise ArgumentError(
                f"expected a size such as 2GB or 512MiB, got {text!r}", LIMIT_VARIABLE
            ) from None
        found.append(max(0, limit - resident_memory()))
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


_DURATION_UNITS = {"": 1.0, "s": 1.0, "min": 60.0, "m": 60.0, "h": 3600.0}


def parse_duration(text: str) -> float:
    """``"600"``, ``"90s"``, ``"30min"``, ``"2h"`` as seconds; ``"none"`` as infinity.

    ValueError for anything else (negative, zero, not finite, unknown unit).
    """
    if text.strip().lower() == "none":
        return math.inf
    match = re.fullmatch(r"\s*([0-9]+(?:\.[0-9]+)?)\s*([A-Za-z]*)\s*", text)
    if match is None or match.group(2).lower() not in _DURATION_UNITS:
        raise ValueError(f"not a duration: {text!r}")
    seconds = float(match.group(1)) * _DURATION_UNITS[match.group(2).lower()]
    if not 0 < seconds < math.inf:
        raise ValueError(f"not a positive duration: {text!r}")
    return seconds


def format_duration(seconds: float) -> str:
    """A duration for people: ``42 s``, ``12 min``, ``3.5 h``, ``2.1e+03 days``."""
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 2 * 3600:
        return f"{seconds / 60:.0f} min"
    if seconds < 48 * 3600:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.3g} days"


def time_limit() -> float:
    """Seconds of work cellplan accepts: ``CELLPLAN_TIME_LIMIT``, or
    :data:`DEFAULT_TIME_LIMIT_S`; infinity for ``none``."""
    text = os.environ.get(TIME_LIMIT_VARIABLE)
    if not text:
        return DEFAULT_TIME_LIMIT_S
    try:
        return parse_duration(text)
    except ValueError:
        raise ArgumentError(
            f"expected seconds, a duration such as 30min or 2h, or none; got {text!r}",
            TIME_LIMIT_VARIABLE,
        ) from None


def require_time(
    seconds: float, field: str, what: str = "", error: type[CellplanError] = ArgumentError
) -> None:
    """Refuse (``error`` naming ``field``) work estimated to take longer than the time limit.

    ``seconds`` comes from a per-cell or per-task cost measured on the reference machine
    and written beside the planner; ``what`` completes the message like :func:`require`'s:
    ``would take about 3.5 h <what>; the time limit is 1.0 h (CELLPLAN_TIME_LIMIT=none
    lifts it)``.
    """
    limit = time_limit()
    if NOTICE_SECONDS <= seconds <= limit:
        extra = f" {what}" if what else ""
        log.warning(
            "%s: about %s of work%s (the time limit, %s=%s, is %s)",
            field,
            format_duration(seconds),
            extra,
            TIME_LIMIT_VARIABLE,
            os.environ.get(TIME_LIMIT_VARIABLE, "unset"),
            format_duration(limit),
        )
    if seconds > limit:
        extra = f" {what}" if what else ""
        raise error(
            [
                Problem(
                    field,
                    f"would take about {format_duration(seconds)}{extra}; the time limit is "
                    f"{format_duration(limit)} ({TIME_LIMIT_VARIABLE}=none lifts it)",
                )
            ]
        )
