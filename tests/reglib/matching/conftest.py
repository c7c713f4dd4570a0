"""What the tests of ``match_images``' second tries share: a first answer replaced by a known one."""
from __future__ import annotations

import dataclasses

import numpy as np

import reglib.matching._pipeline as pipeline
from reglib import KernelWarp
from reglib.dense import rate_over_no_motion
from reglib.matching._inputs import read_images, run_of


def replaced_first_answer(a: np.ndarray, b: np.ndarray, features: str, answer: KernelWarp, *,
                          sparse_too: bool = False):
    """The stages on the pair, their answer replaced by ``answer`` (and the sparse fit too with ``sparse_too``),
    and the images' rating of it: (images, run, sparse, dense, rating), as a second try receives them."""
    run = run_of(features, "l2e", None, 0)
    images = read_images(a, b, None, None, run)
    sparse, dense, _, _ = pipeline._try(images, run)
    if sparse_too:
        sparse = dataclasses.replace(sparse, fit=dataclasses.replace(sparse.fit, transform=answer))
    dense = dataclasses.replace(dense, transform=answer)
    return images, run, sparse, dense, rate_over_no_motion(dense.field_a, dense.field_b, answer, dense.options)

