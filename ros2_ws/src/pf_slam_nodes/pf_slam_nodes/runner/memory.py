"""Keep freed memory in the process (glibc's malloc), so large numpy temporaries are not page-faulted in anew.

The filter's vectorised steps allocate and free arrays of megabytes many times per scan (THOR's
window search: 900 candidate poses x 270 points, a few 2 MB float64 arrays per call). With glibc's
defaults such an array is mmap-ed and unmapped, or the top of the heap is trimmed after it is
freed, and the next one is faulted in page by page: on THOR half the run's page faults and, in
the window search, more time than its arithmetic. Raising the mmap threshold (to 32 MB, glibc's
upper bound) and the trim threshold (64 MB) keeps them in the heap. No effect on any result;
elsewhere than glibc (no ``mallopt``) nothing changes.
"""

from __future__ import annotations

import ctypes

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3


def keep_freed_memory(mmap_threshold_mb: int = 32, trim_threshold_mb: int = 64) -> bool:
    """Set glibc's mmap and trim thresholds for this process; True if both were accepted."""
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the process's own C library
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    ok = mallopt(_M_MMAP_THRESHOLD, mmap_threshold_mb << 20) == 1
    return mallopt(_M_TRIM_THRESHOLD, trim_threshold_mb << 20) == 1 and ok
