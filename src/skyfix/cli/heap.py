"""The board commands' heap: one malloc arena for every thread, and large blocks given back.

glibc gives each thread that allocates its own arena (up to eight per core), and what is freed in
one stays with the process. In ``skyfix locate`` the database search's block reader and zarr's
decompression threads each grew one: on the 7 x 7 km database, one core, the peak anonymous memory
was 245 MB with them and 204 MB with one arena, in the same time (22.8 s). A rover's 256 MB is
worth more than the few lock waits one arena costs threads that allocate rarely.

glibc also raises its mmap threshold each time a large block is freed (up to 32 MB), so numpy's
large temporaries soon come from the heap and stay in it after they are freed: reading the DEM
and building its pyramid left 56 MB of anonymous memory for 11 MB of arrays. A fixed threshold
keeps every array from that size up in a mapping of its own, returned when it is freed, at the
price of fresh (zeroed) pages for each. Measured on one core (7 x 7 km database, 12 navcam
frames), peak anonymous MB and seconds: dynamic 155 / 126 MB, locate 14.5 s, heading 3.1 s;
16 MiB 135 MB heading, 3.0 s; **4 MiB 145-149 / 116-127 MB, 14.7 / 3.1 s**; 1 MiB 140-147 /
113-115 MB but 18 / 4.1 s (page faults on every working-scale array).

The heap's top is given back once more than TRIM_THRESHOLD lies free there, not at the mmap
threshold as before 2026-11-27: detection frees a frame's working-scale arrays (15-20 MB of
blocks under 4 MiB) before its full-resolution refinement and allocates them again for the next
frame, and a heap trimmed at 4 MiB faulted them in afresh every time (176 000 page faults in
`heading`, 0.42 s of system time in 2.2 s). At 32 MiB: 56 000 faults, heading 2.2 -> 1.8-1.9 s,
locate 9.1-9.7 -> 8.3-9.1 s, peak RSS 176-177 -> 176-182 MB, anonymous 102-103 -> 102-108 MB
(three cases, one core; 16 MiB: 119 000 faults, 2.0 s; 8 MiB: 148 000, 2.1 s).

The mmap threshold went from 4 to 8 MiB the same day: the refinement's band costs (8 MB each when
the band spans a navcam frame) were mapped and unmapped for every frame, fresh zeroed pages each
time. At 8 MiB (trim 32 MiB): heading's faults 82 000 -> 32 000, 1.9-2.0 -> 1.7-1.9 s; locate
8.4-9.0 -> 8.2-8.9 s, peak RSS 176-178 MB, anonymous 102-104 MB; heading's peak 144-155 -> 156-158
MB, anonymous 70-80 -> 81-84 MB (16 MiB: the same time, tilted locate's peak 184 MB).

16 MiB since `heading` reads its DEM before any image (the rough position is checked on it before
detection, 2026-11-27): at 8 MiB that order took heading's faults from 22 000 to 118 000 and its
system time from 0.07 to 0.29 s (1.83 -> 2.09 s on one core), detection's blocks now falling
where the heap's top is trimmed; at 16 MiB 23 000 faults, and the three cases measured in turn
(one core, load 0.6-1.2): heading 1.7-1.8 s (1.8-1.9 s before, detection first), peak RSS
168-172 MB (156-158: the DEM is now held while the frames are detected), anonymous 94-97 MB;
locate 6.1-7.2 s (6.4-7.3), peak RSS 181-183 MB (178-182); fixes and headings identical.
"""

from __future__ import annotations

import ctypes
import sys

#: glibc's mallopt parameters (malloc.h)
M_ARENA_MAX = -8
M_MMAP_THRESHOLD = -3
M_TRIM_THRESHOLD = -1

#: [bytes] blocks from this size up get a mapping of their own (fixed: see the module's text)
MMAP_THRESHOLD = 16 << 20
#: [bytes] free memory at the heap's top beyond which it is given back (see the module's text)
TRIM_THRESHOLD = 32 << 20


def _mallopt():
    if not sys.platform.startswith("linux"):
        return None
    try:
        f = ctypes.CDLL(None).mallopt  # the process's own C library
    except (OSError, AttributeError):
        return None
    f.argtypes = (ctypes.c_int, ctypes.c_int)
    return f


def one_malloc_arena() -> bool:
    """Ask glibc for a single arena from now on (threads started later share it). True when the
    C library took it; False where there is no glibc ``mallopt`` (macOS, musl), a no-op."""
    mallopt = _mallopt()
    return bool(mallopt and mallopt(M_ARENA_MAX, 1))


def board_heap() -> bool:
    """One arena (:func:`one_malloc_arena`), a fixed mmap threshold of MMAP_THRESHOLD and the
    heap's top trimmed beyond TRIM_THRESHOLD. True when glibc took all three settings."""
    mallopt = _mallopt()
    if mallopt is None:
        return False
    return all([mallopt(M_ARENA_MAX, 1), mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD),
                mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD)])
