"""Tests of ``reglib evaluate`` (in-process, through reglib.cli.main)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from reglib import KernelWarp
from reglib._transforms import LinearPart
from reglib.cli import main


def _shift_json(tmp_path, *, match: bool):
    t = KernelWarp(dim=2, src_mean=np.zeros(2), src_scale=1.0, dst_mean=np.zeros(2), dst_scale=1.0,
                   linear=LinearPart(kind="affine", matrix=np.array([[1.0, 0, 3.0], [0, 1.0, 4.0]])), beta=1.0,
                   centers=np.zeros((0, 2)), weights=np.zeros((0, 2)))
    path = tmp_path / ("match.json" if match else "t.json")
    body = {"transform": t.to_dict(), "shape_a": [50, 60], "shape_b": [60, 80]} if match else t.to_dict()
    path.write_text(json.dumps(body))
    return path


def test_evaluate_a_match_with_anhir_and_plain_landmark_files(tmp_path, capsys):
    match = _shift_json(tmp_path, match=True)
    a = tmp_path / "a.csv"
    a.write_text(",X,Y\n0,10,20\n1,30,40\n2,5,5\n")  # ANHIR's form: an index column under an empty header cell
    b = tmp_path / "b.txt"
    b.write_text("13 24\n33 44\n8 15\n")  # the shift maps a onto b exactly but for the last landmark (6 px in y)
    out = tmp_path / "ev.json"
    assert main(["evaluate", str(match), str(a), str(b), "--out", str(out)]) == 0
    assert "3 landmarks" in capsys.readouterr().out
    d = json.loads(out.read_text())
    assert d["tre"] == pytest.approx([0.0, 0.0, 6.0])
    assert d["diagonal"] == pytest.approx(100.0) and d["rtre_max"] == pytest.approx(0.06)  # b is 60 x 80
    assert d["fold_fraction"] == 0.0 and d["hausdorff"] == pytest.approx(6.0)


def test_evaluate_a_transform_with_shape_flags_and_headers(tmp_path, capsys):
    t = _shift_json(tmp_path, match=False)
    a = tmp_path / "a.csv"
    a.write_text("x,y\n10,20\n")
    b = tmp_path / "b.csv"
    b.write_text("x,y\n13,34\n")
    out = tmp_path / "ev.json"
    assert main(["evaluate", str(t), str(a), str(b), "--out", str(out)]) == 0
    d = json.loads(out.read_text())
    assert d["tre"] == pytest.approx([10.0]) and d["rtre"] is None and d["fold_fraction"] is None
    assert main(["evaluate", str(t), str(a), str(b), "--shape-b", "30", "40", "--shape-a", "8", "8",
                 "--out", str(out)]) == 0
    d = json.loads(out.read_text())
    assert d["rtre_median"] == pytest.approx(0.2) and d["fold_fraction"] == 0.0
    capsys.readouterr()


def test_evaluate_errors_are_one_line(tmp_path, capsys):
    t = _shift_json(tmp_path, match=False)
    a = tmp_path / "a.txt"
    a.write_text("1 2\n3 4\n")
    b = tmp_path / "b.txt"
    b.write_text("1 2\n")
    assert main(["evaluate", str(t), str(a), str(b)]) == 2
    assert "same number of landmarks" in capsys.readouterr().err
    assert main(["evaluate", str(t), str(a), str(tmp_path / "none.txt")]) == 2
    assert "no such landmark file" in capsys.readouterr().err
    bad = tmp_path / "bad.txt"
    bad.write_text("1 2\n3 x\n")
    assert main(["evaluate", str(t), str(a), str(bad)]) == 2
    assert "not a numeric table" in capsys.readouterr().err
    four = tmp_path / "four.txt"
    four.write_text("1 2 3 4\n5 6 7 9\n")
    assert main(["evaluate", str(t), str(a), str(four)]) == 2
    assert "4 columns" in capsys.readouterr().err
