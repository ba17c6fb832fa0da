"""Allocator tuning for the vectorised planner (see docs/design.md, "Performance").

The cost makes many short-lived temporaries of a few hundred kB. glibc returns such blocks to the OS
(mmap above 128 kB, heap trimming on free), so every temporary costs fresh page faults: measured 4×
slower evaluation. Raising the two thresholds keeps the memory in the process. No-op off glibc.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging

log = logging.getLogger(__name__)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_done = False


def tune_allocator(trim_bytes: int = 256 << 20, mmap_bytes: int = 32 << 20) -> bool:
    """Keep freed temporaries in the process; returns True when glibc accepted the settings."""
    global _done
    if _done:
        return True
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        ok = bool(libc.mallopt(_M_TRIM_THRESHOLD, trim_bytes)) and bool(
            libc.mallopt(_M_MMAP_THRESHOLD, mmap_bytes))
    except (OSError, AttributeError):
        ok = False
    log.debug("allocator tuning %s", "applied" if ok else "unavailable")
    _done = ok
    return ok
