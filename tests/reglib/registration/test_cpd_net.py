"""CPD-Net (``register_points(method="cpd-net")``): the shipped network on generated pairs with known truth.

The pairs are made here (a closed Fourier outline and a group of strokes, bent by a known smooth
field), not taken from the benchmark data; no test needs torch.
"""
import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from reglib import InputError, Registration, register_points
from reglib.registration._cpd_net import CPDNetOptions, load_weights, provenance


def _outline(n=90):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.c_[np.cos(t) + 0.3 * np.cos(3 * t), 0.7 * np.sin(t) + 0.2 * np.sin(2 * t)]


def _strokes(n_per=30):
    s = np.linspace(0, 1, n_per)
    return np.vstack([np.c_[s, 0.2 * np.sin(3 * s)], np.c_[0.5 + 0.1 * s, s - 0.5], np.c_[s, 0.8 - 0.4 * s**2]])


def _bend(pts, amount=0.1):
    """A known smooth deformation of a set spanning ~2 (amount: its size)."""
    return pts + amount * np.c_[np.sin(2.0 * pts[:, 1]), np.cos(1.5 * pts[:, 0])]


def _pair(shape, rng, amount=0.1, noise=0.0, outliers=0):
    model = shape
    truth = _bend(model, amount) * 2.0 + [5.0, -1.0]
    target = truth + rng.normal(0, noise, truth.shape)
    if outliers:
        lo, hi = target.min(0), target.max(0)
        target = np.vstack([target, rng.uniform(lo, hi, (outliers, 2))])
    order = rng.permutation(len(target))
    return model, target[order], truth


def _error(res, truth):
    return float(np.linalg.norm(res.registered - truth, axis=1).mean())


def _baseline(model, truth):
    """Mean error of registering by the normalization alone (centroid and scale)."""
    centered = model - model.mean(0)
    scaled = centered / np.sqrt((centered**2).sum(1).mean())
    t_c = truth - truth.mean(0)
    return float(np.linalg.norm(scaled * np.sqrt((t_c**2).sum(1).mean()) + truth.mean(0) - truth, axis=1).mean())


@pytest.mark.parametrize(("shape", "share"), [(_outline(), 0.75), (_strokes(), 0.6)], ids=["outline", "strokes"])
def test_recovers_a_known_deformation(shape, share):
    rng = np.random.default_rng(0)
    model, target, truth = _pair(shape, rng)
    res = register_points(model, target, method="cpd-net", rng=0)
    err = _error(res, truth)
    # measured with the shipped weights: 0.64 (outline) and 0.47 (strokes) of what the normalization leaves
    assert err < share * _baseline(model, truth), (err, _baseline(model, truth))


def test_noise_and_outliers_leave_the_answer_close():
    rng = np.random.default_rng(1)
    model, target, truth = _pair(_outline(), rng, noise=0.02, outliers=45)
    res = register_points(model, target, method="cpd-net", rng=0)
    assert _error(res, truth) < 0.75 * _baseline(model, truth)  # measured 0.58


def test_refinement_does_not_hurt_a_clean_pair():
    rng = np.random.default_rng(2)
    model, target, truth = _pair(_outline(), rng)
    plain = register_points(model, target, method="cpd-net", rng=0)
    refined = register_points(model, target, method="cpd-net", options=CPDNetOptions(refine=20), rng=0)
    assert refined.n_iter == 20 and plain.n_iter == 0
    assert _error(refined, truth) < _error(plain, truth)  # measured 0.107 against 0.114


def test_the_registration_contract():
    rng = np.random.default_rng(3)
    model, target, _ = _pair(_outline(), rng)
    res = register_points(model, target, method="cpd-net", rng=7)
    assert res.method == "cpd-net" and res.seed == 7 and res.n_iter == 0 and res.converged is True
    assert res.registered.shape == model.shape and res.correspondence.shape == (len(model),)
    np.testing.assert_array_equal(res.registered, res.transform(model))
    back = Registration.from_dict(json.loads(json.dumps(res.to_dict())))
    probe = np.random.default_rng(4).uniform(-3, 7, (20, 2))
    np.testing.assert_array_equal(back.transform(probe), res.transform(probe))
    np.testing.assert_array_equal(back.correspondence, res.correspondence)


def test_the_answer_does_not_depend_on_the_order_of_the_points():
    rng = np.random.default_rng(5)
    t = rng.uniform(0, 2 * np.pi, 90)  # no two distances equal: the order breaks no tie
    model, target, _ = _pair(np.c_[np.cos(t) + 0.3 * np.cos(3 * t), 0.7 * np.sin(t)], rng)
    res = register_points(model, target, method="cpd-net")
    perm_m, perm_t = rng.permutation(len(model)), rng.permutation(len(target))
    again = register_points(model[perm_m], target[perm_t], method="cpd-net")
    np.testing.assert_allclose(again.registered, res.registered[perm_m], atol=1e-7)


def test_any_number_of_points_and_more_than_the_centres():
    rng = np.random.default_rng(6)
    t = rng.uniform(0, 2 * np.pi, 700)
    model = np.c_[np.cos(t) + 0.3 * np.cos(3 * t), 0.7 * np.sin(t) + 0.2 * np.sin(2 * t)]
    truth = _bend(model) * 2.0
    res = register_points(model, truth[::-1], method="cpd-net", options={"n_centers": 100})
    assert res.transform.n_centers == 100
    assert _error(res, truth) < 0.75 * _baseline(model, truth)  # measured 0.59
    few = register_points(model[:3], truth[:4], method="cpd-net")
    assert few.registered.shape == (3, 2) and np.isfinite(few.registered).all()


def test_bad_input_is_an_input_error():
    model = _outline()
    with pytest.raises(InputError, match="2-D points"):
        register_points(np.c_[model, model[:, :1]], np.c_[model, model[:, :1]], method="cpd-net")
    with pytest.raises(InputError, match="at least 3 points"):
        register_points(model[:2], model, method="cpd-net")
    bad = model.copy()
    bad[3, 0] = np.nan
    with pytest.raises(InputError):
        register_points(bad, model, method="cpd-net")
    with pytest.raises(InputError, match="unknown field"):
        register_points(model, model, method="cpd-net", options={"beta_typo": 1})
    with pytest.raises(InputError):
        CPDNetOptions(refine=-1)


def test_the_shipped_weights_and_their_provenance():
    w = load_weights()
    assert w.n_steps >= 1 and w.kbeta > 0 and (w.lam > 0).all()
    size = sum(a.size for layer in w.layers for a in layer)
    assert size < 1_000_000  # kilobytes, not megabytes
    meta = provenance()
    for key in ("seed", "data_recipe", "commit", "training_seconds", "final_loss"):
        assert key in meta


def test_runs_with_torch_blocked_from_import():
    code = textwrap.dedent("""
        import importlib.abc
        import sys

        class NoTorch(importlib.abc.MetaPathFinder):
            # any `import torch` raises ImportError (a None in sys.modules instead would break
            # libraries that look there for torch, such as scipy's array-API check)
            def find_spec(self, name, path=None, target=None):
                if name == "torch" or name.startswith("torch."):
                    raise ImportError(f"{name} is blocked in this test")
                return None

        sys.meta_path.insert(0, NoTorch())
        import numpy as np
        from reglib import register_points
        t = np.linspace(0, 2 * np.pi, 50, endpoint=False)
        m = np.c_[np.cos(t), 0.6 * np.sin(t)]
        res = register_points(m, m * 1.5 + 0.05 * np.sin(3 * m), method="cpd-net", options={"refine": 2})
        assert res.method == "cpd-net" and np.isfinite(res.registered).all()
        assert "torch" not in {k for k, v in sys.modules.items() if v is not None}
        print("ok")
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().endswith("ok")


@pytest.mark.train
def test_a_tiny_training_writes_weights_the_numpy_network_reads(tmp_path):
    pytest.importorskip("torch")
    from pathlib import Path

    from reglib.registration._cpd_net import CPDNetWeights

    script = Path(__file__).resolve().parents[3] / "tools" / "train_cpd_net.py"
    out = subprocess.run([sys.executable, str(script), "--iters", "20", "--seed", "3", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr
    with np.load(tmp_path / "cpd_net_weights.npz") as arrays:
        w = CPDNetWeights.from_arrays(arrays)
    assert w.n_steps == load_weights().n_steps and all(len(layer) == 6 for layer in w.layers)
    meta = json.loads((tmp_path / "cpd_net_weights.json").read_text())
    assert meta["seed"] == 3 and meta["iterations"] == 20


def test_a_poor_fit_says_so_and_a_close_one_is_an_answer():
    """The network answers in one pass whatever the input; its own fit (``chamfer_spacings``) decides."""
    model = np.random.default_rng(0).uniform(-1, 1, (200, 2))
    target = model @ [[0.9, -0.3], [0.3, 0.9]] + 0.1   # a rotation and scale its training outlines lack
    far = register_points(model, target, method="cpd-net", rng=0)
    extent = float(np.ptp(target, axis=0).max())
    assert np.linalg.norm(far.registered - target, axis=1).mean() > 0.02 * extent  # the truth: it is off
    assert not far.converged and far.reason == "poor_fit"
    t = np.linspace(0, 2 * np.pi, 100, endpoint=False)
    outline = np.c_[np.cos(t) * (1 + 0.3 * np.cos(3 * t)), np.sin(t) * (1 + 0.2 * np.sin(2 * t))]
    bent = outline + 0.06 * np.sin(outline[:, ::-1] * 2)
    close = register_points(outline, bent, method="cpd-net", rng=0)
    assert np.linalg.norm(close.registered - bent, axis=1).mean() < 0.02 * float(np.ptp(bent, axis=0).max())
    assert close.converged and close.reason is None


def test_chamfer_spacings_is_zero_on_coinciding_sets_and_grows_with_a_shift():
    from scipy.spatial import cKDTree

    from reglib.registration._support import chamfer_spacings

    grid = np.mgrid[0:10, 0:10].reshape(2, -1).T.astype(float)  # spacing 1
    tree = cKDTree(grid)
    assert chamfer_spacings(grid, grid, tree) == 0.0
    assert chamfer_spacings(grid + [0.5, 0.0], grid, tree) == pytest.approx(0.5)
