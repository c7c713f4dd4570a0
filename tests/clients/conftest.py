"""Shared fixtures of the client tests: the real app in-process, and textured test images."""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np
import pytest

# The in-process app: one worker, and a pixel limit small enough to test 413 with a modest image.
SETTINGS = {"workers": 1, "queue_size": 8, "max_pixels": 250_000}
SHIFT = np.array([5.0, -7.0])  # image b is image a moved by this much: a point (x, y) of a is at (x, y) + SHIFT in b


@dataclass(frozen=True)
class Pair:
    a: np.ndarray
    b: np.ndarray
    shift: np.ndarray


def textured(seed: int, shape: tuple[int, int] = (260, 340)) -> np.ndarray:
    """A smooth random texture (blurred noise) with plenty of SIFT keypoints, uint8 grey."""
    noise = np.random.default_rng(seed).normal(128.0, 60.0, shape).clip(0, 255).astype(np.uint8)
    return cv2.GaussianBlur(noise, (0, 0), 2.0)


def shifted_pair(seed: int) -> Pair:
    """Two 200 x 280 crops of one texture: b(x, y) = a(x - 5, y + 7), so f(p) = p + SHIFT."""
    img = textured(seed)
    a = img[20:220, 20:300]
    b = img[27:227, 15:295]
    return Pair(a=a, b=b, shift=SHIFT)


@pytest.fixture(scope="module")
def pair() -> Pair:
    return shifted_pair(0)


@pytest.fixture(scope="module")
def app_client() -> Iterator[object]:
    """Starlette's TestClient (an httpx2.Client) of the real app, its pool started by the lifespan."""
    from fastapi.testclient import TestClient

    from service.app import create_app
    from service.config import Settings

    with TestClient(create_app(Settings(**SETTINGS))) as client:
        yield client
