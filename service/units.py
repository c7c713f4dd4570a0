"""Sizes in the words people read them in: ``32 MiB``, not ``33554432``, in log lines and problem details."""
from __future__ import annotations

__all__ = ["human_bytes", "size_over_limit"]

_UNITS = (("GiB", 30), ("MiB", 20), ("KiB", 10))


def human_bytes(n: int) -> str:
    """``n`` bytes to three significant digits in the largest binary unit it fills.

    >>> human_bytes(33554432), human_bytes(96063136), human_bytes(9496860672), human_bytes(512)
    ('32 MiB', '91.6 MiB', '8.84 GiB', '512 bytes')
    """
    for unit, shift in _UNITS:
        if n >= 1 << shift:
            return f"{n / (1 << shift):.3g} {unit}"
    return f"{n} bytes"


def size_over_limit(size: int, limit: int) -> str:
    """``"91.6 MiB, over the limit of 32 MiB"``; with the exact bytes when the rounded sizes read the same.

    >>> size_over_limit(33554433, 33554432)
    '32 MiB (33554433 bytes), over the limit of 32 MiB (33554432 bytes)'
    """
    shown, allowed = human_bytes(size), human_bytes(limit)
    if shown == allowed:
        shown, allowed = f"{shown} ({size} bytes)", f"{allowed} ({limit} bytes)"
    return f"{shown}, over the limit of {allowed}"
