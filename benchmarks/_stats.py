"""Small statistics shared by the benchmarks."""
from __future__ import annotations

import numpy as np


def roc_auc(scores: np.ndarray, bad: np.ndarray) -> float:
    """ROC AUC of "a low score means bad" (Mann-Whitney, ties count half); nan without both classes."""
    scores, bad = np.asarray(scores, float), np.asarray(bad, bool)
    s_bad, s_good = scores[bad], scores[~bad]
    if not len(s_bad) or not len(s_good):
        return float("nan")
    wins = (s_good[:, None] > s_bad[None, :]).sum() + 0.5 * (s_good[:, None] == s_bad[None, :]).sum()
    return float(wins / (len(s_good) * len(s_bad)))
