"""How much memory a request may take: the memory available now, and a check with a clear error before allocating."""

from __future__ import annotations

import os


def available_bytes() -> int | None:
    """The memory available to a new allocation without swapping (Linux `MemAvailable`), or the free physical
    memory where that is unknown; None where neither can be read (then nothing is refused)."""
    try:
        with open("/proc/meminfo", "rb") as meminfo:
            for line in meminfo:
                if line.startswith(b"MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def memory_problem(needed: float) -> str | None:
    """None if `needed` bytes fit in the available memory, else a phrase for an error message: "about 800 GB of
    memory, more than the 23 GB available"."""
    available = available_bytes()
    if available is None or needed <= available:
        return None
    return f"about {_size(needed)} of memory, more than the {_size(available)} available"


def _size(nbytes: float) -> str:
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if nbytes >= scale:
            return f"{nbytes / scale:.3g} {unit}"
    return f"{nbytes / 1e3:.3g} kB"
