"""Train the CPD-Net weights shipped in ``reglib/registration/cpd_net_weights.npz`` (needs ``reglib[train]``).

Unsupervised, as in CPD-Net (Wang et al. 2019): the loss is a robust Chamfer distance between the
warped model and the target plus a coherence term (the kernel field's RKHS norm); the truth of the
synthetic pairs is used only to print a validation error. The pairs are procedurally generated
outlines, never the Chui-Rangarajan fish or character: random star-shaped and Fourier-series closed
curves, open strokes, groups of several curves; deformed by a random affine map plus a Gaussian RBF
field with random control displacements; with noise, outliers, missing parts, random point counts
and orders; each set normalized (centered, RMS radius 1) as ``register_points`` does.

The network is the one of ``reglib/registration/cpd_net.py`` (same features, same cascade, same
coherent-field solve), written in torch for training; the weights are written as an npz the numpy
module reads, with a provenance JSON next to it.

Usage::

    python tools/train_cpd_net.py [--seed 0] [--iters 6000] [--out reglib/registration]

Deterministic for a seed on the CPU (torch on ``--threads`` threads, default 1: on a busy 2-core machine
OpenMP's spinning threads cost more than they give).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

N_STEPS = 4
N_CENTERS = 40  # kernel centres of the coherent field: farthest-point samples of the model
K = 8
K_MODEL = 4
HIDDEN = 64
WIDTH = 0.6  # kernel width of the coherent field (normalized units): exp(-|u - c|^2 / (2 WIDTH^2))
KBETA = 1.0 / (2.0 * WIDTH**2)
LAM_INIT = (4.0, 2.0, 1.0, 0.5)
N_FEATURES = 3 * K + 2 * K_MODEL + 2
RIDGE = 1e-6  # on the diagonal of every field solve
TRUNCATE = 0.3  # Chamfer distances beyond this (normalized units) count as this: outliers, missing parts
COHERENCE = 0.1
STEP_LOSS = (0.1, 0.1, 0.2, 1.0)

RECIPE = (
    "shapes: star-shaped r(t) = 1 + sum_k a_k cos(k t + p_k) (k 2..7), Fourier-series closed curves "
    "(k 1..5), smooth open strokes, groups of 2-4 curves; N 40-160 points by arc length; "
    "deformation: affine (rotation up to 25 deg, log-scales N(0, 0.12), shear N(0, 0.08)) + Gaussian RBF "
    "field (4-12 controls, width 0.4-1.2, amplitude up to 0.4); target: the deformed points or a fresh "
    "sample of the deformed curve, noise sigma up to 0.12, outliers 0-2 N uniform in the box, missing "
    "parts 0-40 % of the target or 0-25 % of the model (a nearest-to-a-point chunk), random orders; "
    "each set centered, RMS radius 1"
)


# ---- synthetic data -------------------------------------------------------------------------------

def _resample(curves: list[np.ndarray], n: int, rng: np.random.Generator) -> np.ndarray:
    """n points spread by arc length over dense polylines ``curves`` (random or jittered-even)."""
    seg = [np.linalg.norm(np.diff(c, axis=0), axis=1) for c in curves]
    lengths = np.array([s.sum() for s in seg])
    cum = np.concatenate([[0.0], np.cumsum(lengths)])
    total = cum[-1]
    if rng.random() < 0.5:
        pos = np.sort(rng.uniform(0, total, n))
    else:
        pos = (np.arange(n) + 0.5 + rng.uniform(-0.3, 0.3, n)) * total / n
        pos = np.clip(pos, 0, total * (1 - 1e-9))
    out = np.empty((n, 2))
    which = np.searchsorted(cum, pos, side="right") - 1
    for ci, c in enumerate(curves):
        sel = which == ci
        if not sel.any():
            continue
        s = np.concatenate([[0.0], np.cumsum(seg[ci])])
        local = pos[sel] - cum[ci]
        out[sel, 0] = np.interp(local, s, c[:, 0])
        out[sel, 1] = np.interp(local, s, c[:, 1])
    return out


def _closed_star(rng: np.random.Generator) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, 400)
    r = np.ones_like(t)
    for k in range(2, 8):
        r += rng.normal(0, 0.3 / k) * np.cos(k * t + rng.uniform(0, 2 * np.pi))
    r = np.maximum(r, 0.15)
    return np.c_[r * np.cos(t), r * np.sin(t) * rng.uniform(0.4, 1.0)]


def _closed_fourier(rng: np.random.Generator) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, 400)
    x, y = np.cos(t), np.sin(t) * rng.uniform(0.3, 1.0)
    for k in range(2, 6):
        a = rng.normal(0, 0.35 / k**1.3, 4)
        x += a[0] * np.cos(k * t) + a[1] * np.sin(k * t)
        y += a[2] * np.cos(k * t) + a[3] * np.sin(k * t)
    return np.c_[x, y]


def _open_stroke(rng: np.random.Generator) -> np.ndarray:
    m = 200
    turn = np.convolve(rng.normal(0, 0.08, m), np.ones(15) / 15, mode="same") + rng.normal(0, 0.01)
    heading = rng.uniform(0, 2 * np.pi) + np.cumsum(turn)
    step = rng.uniform(1.0, 3.0) / m
    return np.cumsum(np.c_[np.cos(heading), np.sin(heading)] * step, axis=0)


def _shape(rng: np.random.Generator, n: int) -> tuple[list[np.ndarray], np.ndarray]:
    """Dense curves of one random shape and n points sampled on them."""
    kind = rng.choice(4, p=[0.3, 0.3, 0.15, 0.25])
    if kind == 0:
        curves = [_closed_star(rng)]
    elif kind == 1:
        curves = [_closed_fourier(rng)]
    elif kind == 2:
        curves = [_open_stroke(rng)]
    else:
        curves = []
        for _ in range(rng.integers(2, 5)):
            c = _open_stroke(rng) if rng.random() < 0.7 else _closed_star(rng) * rng.uniform(0.2, 0.5)
            curves.append(c - c.mean(0) + rng.uniform(-1, 1, 2))
    return curves, _resample(curves, n, rng)


def _deformation(rng: np.random.Generator):
    ang = np.deg2rad(rng.uniform(-25, 25)) if rng.random() < 0.7 else 0.0
    rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    lin = rot @ np.diag(np.exp(rng.normal(0, 0.12, 2))) @ np.array([[1, rng.normal(0, 0.08)], [0, 1]])
    n_ctrl = rng.integers(4, 13)
    ctrl = rng.uniform(-1.5, 1.5, (n_ctrl, 2))
    width = rng.uniform(0.4, 1.2)
    disp = rng.normal(0, 1, (n_ctrl, 2)) * rng.uniform(0, 0.4)

    def apply(p: np.ndarray) -> np.ndarray:
        d2 = ((p[:, None, :] - ctrl[None]) ** 2).sum(-1)
        return p @ lin.T + np.exp(-d2 / (2 * width**2)) @ disp

    return apply


def _normalize(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    mean = p.mean(0)
    scale = float(np.sqrt(((p - mean) ** 2).sum(1).mean()))
    return (p - mean) / scale, mean, scale


def _chunk(p: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """Indices kept after removing the ``count`` points nearest a random point of ``p``."""
    if count <= 0:
        return np.arange(len(p))
    d = ((p - p[rng.integers(len(p))]) ** 2).sum(1)
    return np.sort(np.argsort(d)[count:])


def make_batch(rng: np.random.Generator, batch: int):
    """One batch of pairs sharing their sizes: normalized model (B, N, 2), target (B, M, 2) and the
    truth of the model points in the target's frame (B, N, 2)."""
    n = int(rng.integers(40, 161))
    noise = rng.uniform(0, 0.12) if rng.random() < 0.5 else 0.0
    n_out = int(rng.uniform(0, 2) * n) if rng.random() < 0.3 else 0
    r = rng.random()
    miss_t = int(rng.uniform(0, 0.4) * n) if r < 0.2 else 0
    miss_m = int(rng.uniform(0, 0.25) * n) if 0.2 <= r < 0.3 else 0
    fresh = rng.random() < 0.5
    models, targets, truths = [], [], []
    for _ in range(batch):
        curves, pts = _shape(rng, n + miss_m)
        warp = _deformation(rng)
        tgt_curve = warp(_resample(curves, n, rng)) if fresh else warp(pts[:n].copy())
        keep_m = _chunk(pts, miss_m, rng)
        model = pts[keep_m][:n]
        tgt = tgt_curve + rng.normal(0, noise, tgt_curve.shape) * float(np.sqrt((tgt_curve.var(0)).sum()))
        tgt = tgt[_chunk(tgt, miss_t, rng)]
        if n_out:
            lo, hi = tgt.min(0), tgt.max(0)
            pad = 0.1 * (hi - lo)
            tgt = np.vstack([tgt, rng.uniform(lo - pad, hi + pad, (n_out, 2))])
        model = model[rng.permutation(len(model))]
        tgt = tgt[rng.permutation(len(tgt))]
        u, _, _ = _normalize(model)
        # the truth in the target's normalized frame: truth mapped like the target
        y, t_mean, t_scale = _normalize(tgt)
        models.append(u)
        targets.append(y)
        truths.append((warp(model) - t_mean) / t_scale)
    return tuple(torch.tensor(np.stack(a), dtype=torch.float32) for a in (models, targets, truths))


# ---- the network (mirrors reglib/registration/cpd_net.py) ----------------------------------------------

class Step(nn.Module):
    def __init__(self):
        super().__init__()
        self.l1 = nn.Linear(N_FEATURES, HIDDEN)
        self.l2 = nn.Linear(2 * HIDDEN, HIDDEN)
        self.l3 = nn.Linear(HIDDEN, K + 3)
        with torch.no_grad():
            self.l3.weight.mul_(0.01)
            self.l3.bias.zero_()

    def forward(self, feat):
        h1 = torch.relu(self.l1(feat))
        pooled = h1.max(1, keepdim=True).values.expand_as(h1)
        h2 = torch.relu(self.l2(torch.cat([h1, pooled], -1)))
        return self.l3(h2)


class CPDNet(nn.Module):
    def __init__(self):
        super().__init__()
        self.steps = nn.ModuleList(Step() for _ in range(N_STEPS))
        self.log_lam = nn.Parameter(torch.log(torch.tensor(LAM_INIT)))

    def forward(self, u, y):
        """Positions after each step (B, N, 2), their squared distances to the target (B, N, M), and
        the fields' RKHS norm."""
        b, n, d = u.shape
        du = _sqdist(u, u)
        nbrs = du.topk(min(K_MODEL + 1, n), dim=-1, largest=False).indices[..., 1:]  # (B, N, Km)
        bidx = torch.arange(b)[:, None, None]
        centers = farthest_points(u, min(N_CENTERS, n))
        basis = torch.exp(-KBETA * _sqdist(u, centers))  # (B, N, C)
        gram = torch.exp(-KBETA * _sqdist(centers, centers))
        eye = torch.eye(centers.shape[1], dtype=u.dtype)
        x = u
        d2 = _sqdist(x, y)
        outs, coh = [], 0.0
        for s, step in enumerate(self.steps):
            idx = d2.topk(K, dim=-1, largest=False).indices  # (B, N, K), nearest first
            offsets = y[bidx, idx] - x[:, :, None, :]
            dist = torch.sqrt((offsets**2).sum(-1) + 1e-12)
            x_nbrs = x[bidx, nbrs] - x[:, :, None, :]
            feat = torch.cat([offsets.reshape(b, n, -1), dist, x_nbrs.reshape(b, n, -1), x], -1)
            out = step(feat)
            attn = torch.softmax(out[..., :K], -1)
            v = (attn[..., None] * offsets).sum(2) + out[..., K:K + 2]
            conf = torch.sigmoid(out[..., K + 2])
            uc = basis * conf[..., None]
            a = uc.transpose(1, 2) @ basis + torch.exp(self.log_lam[s]) * gram + RIDGE * eye
            w = torch.linalg.solve(a, uc.transpose(1, 2) @ v)
            gw = basis @ w
            coh = coh + (w * (gram @ w)).sum((1, 2)).mean() / n
            x = x + gw
            d2 = _sqdist(x, y)
            outs.append((x, d2))
        return outs, coh


def farthest_points(u, m):
    """(B, m, D) farthest-point samples of each set, the first its point farthest from the origin (as
    ``reglib.registration._cpd_net.field_centers``; the sets are centered)."""
    b, n, _ = u.shape
    with torch.no_grad():
        cur = (u * u).sum(-1).argmax(1)
        chosen = [cur]
        d2 = ((u - u[torch.arange(b), cur][:, None]) ** 2).sum(-1)
        for _ in range(1, m):
            cur = d2.argmax(1)
            chosen.append(cur)
            d2 = torch.minimum(d2, ((u - u[torch.arange(b), cur][:, None]) ** 2).sum(-1))
        idx = torch.stack(chosen, 1)
    return u[torch.arange(b)[:, None], idx]


def _sqdist(a, b):
    """(B, N, M) squared distances without a (B, N, M, D) temporary."""
    return (torch.baddbmm((b * b).sum(-1)[:, None, :], a, b.transpose(1, 2), alpha=-2.0)
            + (a * a).sum(-1)[:, :, None]).clamp(min=0.0)


def chamfer(d2):
    """Robust symmetric Chamfer distance from squared distances (B, N, M)."""
    m2t = d2.min(2).values.clamp(max=TRUNCATE**2).mean(1)
    t2m = d2.min(1).values.clamp(max=TRUNCATE**2).mean(1)
    return (m2t + t2m).mean()


def export(net: CPDNet) -> dict[str, np.ndarray]:
    arrays: dict[str, np.ndarray] = {"n_steps": np.array(N_STEPS), "k": np.array(K), "k_model": np.array(K_MODEL),
                                     "n_centers": np.array(N_CENTERS), "ridge": np.array(RIDGE),
                                     "kbeta": np.array(KBETA), "lam": torch.exp(net.log_lam).detach().numpy().copy()}
    for s, st in enumerate(net.steps):
        for name, lin in (("1", st.l1), ("2", st.l2), ("3", st.l3)):
            arrays[f"step{s}_w{name}"] = lin.weight.detach().numpy().T.astype(np.float32).copy()
            arrays[f"step{s}_b{name}"] = lin.bias.detach().numpy().astype(np.float32).copy()
    return arrays


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True,
                              cwd=Path(__file__).parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--iters", type=int, default=5000)
    ap.add_argument("--batch", type=int, default=12)
    ap.add_argument("--lr", type=float, default=2e-3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "reglib" / "registration")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    torch.set_default_dtype(torch.float32)
    rng = np.random.default_rng(args.seed)
    val = [make_batch(np.random.default_rng(10_000 + args.seed + i), 16) for i in range(8)]
    net = CPDNet()
    opt = torch.optim.Adam(net.parameters(), lr=args.lr)
    # (a warm-up of at least 2 steps: OneCycleLR divides by its length less one)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=args.lr, total_steps=args.iters,
                                                pct_start=max(0.05, 2.5 / args.iters))
    t0 = time.perf_counter()
    running = None
    with torch.no_grad():
        errs = [float((net(vu, vy)[0][-1][0] - vt).norm(dim=-1).mean()) for vu, vy, vt in val]
    best = (float(np.mean(errs)), 0, export(net))
    print(f"iter      0  val error {best[0]:.4f}", flush=True)
    for it in range(1, args.iters + 1):
        u, y, _ = make_batch(rng, args.batch)
        outs, coh = net(u, y)
        loss = sum(wt * chamfer(d2) for wt, (_, d2) in zip(STEP_LOSS, outs, strict=True)) + COHERENCE * coh
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
        opt.step()
        sched.step()
        value = loss.item()
        running = value if running is None else 0.98 * running + 0.02 * value
        if it % 250 == 0 or it == args.iters:
            with torch.no_grad():
                errs = [float((net(vu, vy)[0][-1][0] - vt).norm(dim=-1).mean()) for vu, vy, vt in val]
                start = [float((vu - vt).norm(dim=-1).mean()) for vu, _, vt in val]
            if np.mean(errs) < best[0]:
                best = (float(np.mean(errs)), it, export(net))
            print(f"iter {it:6d}  loss {running:.4f}  val error {np.mean(errs):.4f} (identity {np.mean(start):.4f})"
                  f"  {time.perf_counter() - t0:.0f} s", flush=True)
    elapsed = time.perf_counter() - t0
    args.out.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out / "cpd_net_weights.npz", **best[2])
    meta = {"seed": args.seed, "iterations": args.iters, "batch": args.batch, "lr": args.lr,
            "threads": args.threads, "torch": torch.__version__, "commit": _commit(),
            "training_seconds": round(elapsed, 1), "final_loss": round(running or 0.0, 5),
            "final_val_error": round(float(np.mean(errs)), 5), "kept_iteration": best[1],
            "kept_val_error": round(best[0], 5), "kept": (
                "the weights at the check (every 250 iterations, and the initial ones) with the lowest mean "
                "error against the truth on 128 synthetic validation pairs of the same recipe (seeds 10000+)"),
            "loss": (
                "robust Chamfer (squared distances truncated at 0.3^2, both directions) at every step, weights "
                f"{list(STEP_LOSS)}, + {COHERENCE} x the field's RKHS norm"),
            "network": {"n_steps": N_STEPS, "k": K, "k_model": K_MODEL, "hidden": HIDDEN, "kernel_width": WIDTH,
                        "n_centers": N_CENTERS},
            "data_recipe": RECIPE}
    (args.out / "cpd_net_weights.json").write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    print(json.dumps(meta, indent=2))


if __name__ == "__main__":
    main()
