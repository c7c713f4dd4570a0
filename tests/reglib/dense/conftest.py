"""Pairs and transforms the dense stage's tests share: made from scikit-image sample images with known warps."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import skimage.data

from reglib import KernelWarp
from reglib._transforms import LinearPart


def descriptor_fields(img: np.ndarray) -> np.ndarray:
    """A 3-channel descriptor-like field: blurred intensity, |gradient|, and a channel flat everywhere."""
    g = cv2.GaussianBlur(img, (0, 0), 1.0)
    gx, gy = cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1)
    return np.dstack([g / 255.0, np.sqrt(gx * gx + gy * gy) / 255.0, np.zeros_like(g)]).astype(np.float32)


def affine(matrix) -> KernelWarp:
    """The affine map x -> matrix[:, :2] x + matrix[:, 2] as a KernelWarp."""
    return KernelWarp(dim=2, src_mean=np.zeros(2), src_scale=1.0, dst_mean=np.zeros(2), dst_scale=1.0,
                      linear=LinearPart(kind="affine", matrix=np.asarray(matrix, np.float64)),
                      beta=1.0, centers=np.zeros((0, 2)), weights=np.zeros((0, 2)))


def bent_pair(size: int = 256):
    """b(q) = a(G(q)) with G a rotation by 12 degrees, 1.1x scale and two strong bumps (up to ~9 % of the size).

    Returns a, b, and G at (N, 2) points q of b: a point q of b shows a(G(q)), so the true a -> b map sends G(q) to q.
    """
    a = cv2.resize(skimage.data.astronaut()[..., 1], (size, size), interpolation=cv2.INTER_AREA).astype(np.float32)
    c = np.array([size / 2, size / 2])
    th = np.deg2rad(12.0)
    rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]]) / 1.1
    bumps = [(np.array([0.3, 0.35]) * size, np.array([9.0, -12.0]) * size / 256, 0.17 * size),
             (np.array([0.7, 0.65]) * size, np.array([-11.0, 8.0]) * size / 256, 0.2 * size)]

    def g(q: np.ndarray) -> np.ndarray:
        p = c + (q - c) @ rot.T
        for centre, amp, rad in bumps:
            p = p + np.exp(-((q - centre) ** 2).sum(1) / (2 * rad * rad))[:, None] * amp
        return p

    ys, xs = np.mgrid[0:size, 0:size]
    m = g(np.c_[xs.ravel(), ys.ravel()].astype(float)).astype(np.float32).reshape(size, size, 2)
    b = cv2.remap(a, m[..., 0], m[..., 1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    return a, b, g, c, rot


@pytest.fixture
def fields():
    return descriptor_fields


@pytest.fixture
def make_affine():
    return affine


@pytest.fixture
def make_bent_pair():
    return bent_pair
