"""cpd-rigid's verdict with far target outliers, and on clean, noisy and partial targets (issue 51).

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_cpd_outliers.py [--seed-offset 10]   # about half a minute

A flattened Gaussian blob of 200 points (2-D or 3-D) moved by a known rotation and shift; the target is
the moved blob with 10-60 points added at 3-30 blob radii, or with 2-5 % noise and 20-50 % of it missing.
An answer is right when its mean point error is under the blob's spacing (median nearest-neighbour
distance). Prints, per set: right answers that say ``converged=True`` and wrong ones that say ``False``.
"""
from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial import cKDTree

import reglib


def scene(seed: int, n_out: int, far: float, dim: int, keep: float, noise: float,
          n: int = 200) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The model, the target and the true place of the model's points."""
    rng = np.random.default_rng(seed)
    model = rng.normal(size=(n, dim)) * ([1.0, 0.6, 0.3][:dim])
    rot = np.eye(dim)
    rot[:2, :2] = [[np.cos(0.4), -np.sin(0.4)], [np.sin(0.4), np.cos(0.4)]]
    truth = model @ rot.T + np.array([0.2, -0.1, 0.1][:dim])
    target = truth + rng.normal(scale=noise, size=model.shape)
    target = target[model[:, 0] <= np.quantile(model[:, 0], keep)]
    out = rng.normal(size=(n_out, dim))
    out = far * out / np.linalg.norm(out, axis=1, keepdims=True)
    return model, np.r_[target, out], truth


SETS = {
    "far outliers, 3-D (10-60 points at 3-30 blob radii, seeds 0-2)":
        [(s, n, f, 3, 1.0, 0.0) for f in (3.0, 10.0, 30.0) for n in (10, 30, 60) for s in range(3)],
    "far outliers, 2-D": [(s, n, f, 2, 1.0, 0.0) for f in (3.0, 10.0, 30.0) for n in (10, 30, 60) for s in range(3)],
    "no outliers: clean, 2-5 % noise, 20-50 % of the target missing (2-D and 3-D, seeds 0-4)":
        [(s, 0, 0.0, d, k, z) for d in (2, 3) for k, z in ((1.0, 0.0), (1.0, 0.02), (0.8, 0.02), (0.7, 0.05),
                                                           (0.5, 0.02)) for s in range(5)],
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed-offset", type=int, default=0, help="added to every scene's seed (0: the seeds named)")
    offset = ap.parse_args().seed_offset
    print("| set | cases | right | right converged=True | wrong | wrong said (converged=False) |")
    print("|---|---|---|---|---|---|")
    for name, cases in SETS.items():
        right = kept = wrong = said = 0
        for seed, n_out, far, dim, keep, noise in cases:
            model, target, truth = scene(seed + offset, n_out, far, dim, keep, noise)
            res = reglib.register_points(model, target, method="cpd-rigid", rng=0)
            spacing = float(np.median(cKDTree(truth).query(truth, k=2)[0][:, 1]))
            err = float(np.linalg.norm(np.asarray(res.registered) - truth, axis=1).mean())
            if err < spacing:
                right += 1
                kept += bool(res.converged)
            else:
                wrong += 1
                said += not res.converged
        print(f"| {name} | {len(cases)} | {right} | {kept}/{right} | {wrong} | {said}/{wrong} |", flush=True)


if __name__ == "__main__":
    main()
