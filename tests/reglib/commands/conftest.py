"""Fixtures shared by the CLI commands' tests."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from reglib import KernelWarp


@pytest.fixture
def shift_json(tmp_path: Path) -> Path:
    """A transform file that maps a's pixel (x, y) to (x + 3, y + 2) in b."""
    t = KernelWarp(dim=2, src_mean=np.zeros(2), src_scale=1.0, dst_mean=np.array([3.0, 2.0]), dst_scale=1.0,
                   linear=None, beta=1.0, centers=np.zeros((0, 2)), weights=np.zeros((0, 2)))
    path = tmp_path / "t.json"
    path.write_text(json.dumps(t.to_dict()))
    return path
