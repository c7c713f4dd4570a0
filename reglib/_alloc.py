"""Allocator settings for reglib's own long-lived worker processes (service pool, batch workers).

glibc's malloc returns freed memory at the top of the heap to the system once more than
``M_TRIM_THRESHOLD`` (128 KiB by default) is free there, and serves large requests with fresh
``mmap`` regions that are unmapped again on free. A worker that matches image after image
allocates and frees the same tens of MiB of pyramids, descriptors and kernel blocks on every
request, so each request pays the kernel again to map and zero those pages (``benchmarks/README.md``
has the figures). This is also why the same call runs faster in a process whose other live
allocations happen to pin the heap.

:func:`retain_freed_memory` raises both thresholds with ``mallopt`` so a worker keeps up to
``trim_bytes`` of freed heap for reuse; it is called once per worker process, never on import of
the library (it changes process-wide behaviour). Elsewhere than glibc it does nothing.
"""
from __future__ import annotations

import ctypes
import sys

__all__ = ["retain_freed_memory"]

# From glibc's <malloc.h>.
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3


def retain_freed_memory(trim_bytes: int = 128 << 20, mmap_bytes: int = 16 << 20) -> bool:
    """Keep up to ``trim_bytes`` of freed heap mapped and serve requests under ``mmap_bytes`` from the heap.

    Returns True when the settings took effect (glibc), False where there is no ``mallopt``.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc (musl has no mallopt)
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, mmap_bytes)) and bool(mallopt(_M_TRIM_THRESHOLD, trim_bytes))
