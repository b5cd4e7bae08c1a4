"""The fusion node's native memory: glibc's malloc arenas bounded at start-up.

Measured (session 22, ``scripts/soak_hostile.py --memory-probe``, 16 sensors x 30 Hz plus the 1 kHz adversary,
two 10-min soaks side by side on one machine, so both saw the same backlogs): with glibc's default arenas (up to
8 per core, one taken by each thread that allocates: zenoh's receive threads copy every payload there) a 1.1 s
backlog left 9.3 MB of freed memory held in the arenas for good (RSS +11.8 MB after the 5-min warm-up; malloc
in use flat at 38-39 MB); with ``MALLOC_ARENA_MAX=2`` the same backlog left 0.4 MB (+2.8 MB after warm-up).
Session 21's 1-h soak: +11.9 MB after warm-up, all of it freed-but-held (5 -> 18.4 MB). Fewer arenas: the
memory freed after one backlog is reused by the next instead of each thread's arena keeping its own high water.
"""

from __future__ import annotations

import ctypes
import logging
import os

log = logging.getLogger("skelfuse.service.memory")

NODE_MALLOC_ARENAS = 2
"""glibc malloc arenas the fusion node allows (glibc's default: 8 per core)."""
_M_ARENA_MAX = -8  # mallopt's parameter number (glibc malloc.h)


def bound_malloc_arenas(arenas: int = NODE_MALLOC_ARENAS) -> str:
    """Cap glibc's malloc arenas for this process (threads started afterwards); returns what was done, in words.

    Call before any thread starts (the zenoh session). An operator's ``MALLOC_ARENA_MAX`` in the environment is
    left to rule (glibc read it at start-up). Not glibc (musl, macOS): nothing to do.
    """
    if "MALLOC_ARENA_MAX" in os.environ:
        return f"malloc arenas: MALLOC_ARENA_MAX={os.environ['MALLOC_ARENA_MAX']} from the environment"
    try:
        libc = ctypes.CDLL("libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return "malloc arenas: not glibc, left as they are"
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    if mallopt(_M_ARENA_MAX, int(arenas)) != 1:
        return "malloc arenas: mallopt(M_ARENA_MAX) refused, left as they are"
    return f"malloc arenas: at most {int(arenas)}"
