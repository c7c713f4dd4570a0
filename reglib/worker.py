"""Set-up shared by reglib's own worker processes: the service's pool and batch workers."""
from __future__ import annotations

from ._alloc import retain_freed_memory

__all__ = ["prepare_worker_process"]


def prepare_worker_process() -> None:
    """Run OpenCV single-threaded, as N workers use N cores, and keep freed memory for the next
    job (:mod:`reglib._alloc`). Called once in each worker, never by the library itself."""
    import cv2

    cv2.setNumThreads(1)
    retain_freed_memory()
