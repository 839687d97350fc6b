"""The board commands' heap: one malloc arena for every thread.

glibc gives each thread that allocates its own arena (up to eight per core), and what is freed in
one stays with the process. In ``skyfix locate`` the database search's block reader and zarr's
decompression threads each grew one: on the 7 x 7 km database, one core, the peak anonymous memory
was 245 MB with them and 204 MB with one arena, in the same time (22.8 s). A rover's 256 MB is
worth more than the few lock waits one arena costs threads that allocate rarely.
"""

from __future__ import annotations

import ctypes
import sys

#: glibc's mallopt parameter for the number of arenas (malloc.h)
M_ARENA_MAX = -8


def one_malloc_arena() -> bool:
    """Ask glibc for a single arena from now on (threads started later share it). True when the
    C library took it; False where there is no glibc ``mallopt`` (macOS, musl), a no-op."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the process's own C library
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    return bool(mallopt(M_ARENA_MAX, 1))
