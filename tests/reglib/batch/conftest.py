"""Small generated image pairs for the batch tests: a scikit-image sample moved by a known rigid motion."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from skimage import data


def write_pairs(folder: Path, count: int, *, size: tuple[int, int] = (320, 240)) -> list[tuple[str, str, str]]:
    """Write ``count`` PNG pairs (b = a rotated and shifted, a different motion each) into ``folder``.

    Returns (id, image_a, image_b) rows with paths relative to ``folder``.
    """
    folder.mkdir(parents=True, exist_ok=True)
    base = cv2.resize(data.astronaut(), size, interpolation=cv2.INTER_AREA)
    rows = []
    for k in range(count):
        angle, shift = 0.05 * (k % 4), (4.0 + 3 * k, -2.0 - k)
        motion = np.array([[np.cos(angle), -np.sin(angle), shift[0]], [np.sin(angle), np.cos(angle), shift[1]]])
        moved = cv2.warpAffine(base, motion, size, borderMode=cv2.BORDER_REFLECT)
        name_a, name_b = f"img/p{k}_a.png", f"img/p{k}_b.png"
        (folder / "img").mkdir(exist_ok=True)
        cv2.imwrite(str(folder / name_a), cv2.cvtColor(base, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(folder / name_b), cv2.cvtColor(moved, cv2.COLOR_RGB2BGR))
        rows.append((f"pair-{k:02d}", name_a, name_b))
    return rows


def write_csv(path: Path, rows: list[tuple[str, ...]], header: str = "id,image_a,image_b") -> Path:
    path.write_text(header + "\n" + "".join(",".join(row) + "\n" for row in rows))
    return path


@pytest.fixture(scope="module")
def pairs_folder(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[tuple[str, str, str]]]:
    folder = tmp_path_factory.mktemp("pairs")
    return folder, write_pairs(folder, 6)
