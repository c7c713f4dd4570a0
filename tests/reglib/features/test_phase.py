"""Tests of reglib.features._phase: the log-Gabor bank and phase congruency."""
from __future__ import annotations

import numpy as np

from reglib.features import log_gabor_bank, phase_congruency

# ----------------------------------------------------------------------------- phase congruency

def test_log_gabor_bank_is_one_sided_and_cached():
    bank = log_gabor_bank((64, 80))
    assert bank.filters.shape == (24, 64, 80) and bank.filters[:, 0, 0].max() == 0.0
    assert log_gabor_bank((64, 80)) is bank
    # orientation 0 passes +x frequencies only: the response to a real image is analytic-like
    fx = np.fft.fftfreq(80)
    assert bank.filters[0][0, fx < 0].max() == 0.0 and bank.filters[0][0, fx > 0].max() > 0.1


def test_phase_congruency_is_contrast_invariant_and_finds_a_step():
    img = np.zeros((64, 64))
    img[:, 32:] = 1.0
    pc = phase_congruency(img)
    pc_low = phase_congruency(0.2 + 0.3 * img)
    assert pc.edge.shape == (64, 64) and 0.0 <= pc.edge.min() and pc.edge.max() <= 1.0
    col = int(np.argmax(pc.edge[32]))
    assert col in (31, 32)
    assert pc.edge[32, col] > 0.3 and pc.edge[32, 10] < 0.05
    np.testing.assert_allclose(pc_low.edge[:, 16:48], pc.edge[:, 16:48], atol=0.05)


def test_phase_congruency_of_an_image_thinner_than_its_padding():
    # 12 rows: too few to reflect 16 px of padding, so none is added; 362 columns are padded to an FFT
    # size (375), and the maps were then cut from the wrong offset (empty)
    img = np.zeros((12, 362))
    img[:, 181:] = 1.0
    pc = phase_congruency(img)
    assert pc.edge.shape == (12, 362) and pc.corner.shape == (12, 362)
    assert int(np.argmax(pc.edge[6, 100:260])) + 100 in (180, 181)
