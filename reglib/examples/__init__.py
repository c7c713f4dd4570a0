"""A small example pair for the quick start: ``cat_a.jpg`` and ``cat_b.jpg`` (360 x 239).

``cat_a.jpg`` is scikit-image's ``chelsea`` sample (public domain, bundled with scikit-image),
resized; ``cat_b.jpg`` is the same photograph warped by a random similarity composed with a smooth
non-rigid field, with a gain / gamma change and noise (made by ``benchmarks/_synthetic_pairs.py``,
``make_pair("chelsea", 7, max_side=360)``).

>>> from reglib.examples import example_pair
>>> a, b = example_pair()
>>> a.name, b.name
('cat_a.jpg', 'cat_b.jpg')
"""
from __future__ import annotations

from pathlib import Path

__all__ = ["EXAMPLES_DIR", "example_pair"]

EXAMPLES_DIR = Path(__file__).resolve().parent


def example_pair() -> tuple[Path, Path]:
    """Paths of the bundled example images (a, b)."""
    return EXAMPLES_DIR / "cat_a.jpg", EXAMPLES_DIR / "cat_b.jpg"
