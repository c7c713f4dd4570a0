"""Tests of the ``reglib`` command line as a new user meets it: misspellings, --out paths, help text."""
from __future__ import annotations

import re

import numpy as np
import pytest

from reglib import io
from reglib.cli import build_parser, main


def _usage_error(argv, capsys) -> str:
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    return capsys.readouterr().err


@pytest.mark.parametrize("argv, usage, words", [
    (["match", "a.png", "b.png", "--out", "o", "--ratoi", "0.7"], "usage: reglib match",
     "unrecognized arguments: --ratoi 0.7; --ratoi: did you mean --ratio?"),
    (["match", "a.png", "b.png", "--out", "o", "--featurs=auto"], "usage: reglib match", "did you mean --features?"),
    (["match", "a.png", "b.png", "--otu", "o"], "usage: reglib match",
     "required: --out; --otu: did you mean --out?"),
    (["filter", "m.txt", "--out", "f.json", "--methd", "vfc"], "usage: reglib filter", "did you mean --method?"),
    (["register", "m.txt", "t.txt", "--out", "r.json", "--no-rotaton"], "usage: reglib register",
     "did you mean --no-rotation?"),
    (["mach", "a.png", "b.png"], "usage: reglib [-h]", "'mach': did you mean 'match'"),
    (["aply", "t.json", "p.txt"], "usage: reglib [-h]", "'aply': did you mean 'apply'?"),
])
def test_a_misspelling_names_the_nearest_valid_words(capsys, argv, usage, words):
    err = _usage_error(argv, capsys)
    assert usage in err and words in err


def test_no_suggestion_when_nothing_is_close(capsys):
    err = _usage_error(["match", "a.png", "b.png", "--out", "o", "--zzzzzz"], capsys)
    assert "unrecognized arguments: --zzzzzz" in err and "did you mean" not in err


def test_out_under_a_missing_folder_is_refused_and_nothing_is_created(tmp_path, shift_json, capsys):
    missing = tmp_path / "missing"
    np.savetxt(tmp_path / "m.txt", np.c_[np.eye(6, 2) * 10, np.eye(6, 2) * 10 + 1])
    np.savetxt(tmp_path / "p.txt", np.ones((3, 2)))
    (tmp_path / "a.png").write_bytes(io.encode_png(np.zeros((20, 20), np.uint8)))
    runs = [["filter", str(tmp_path / "m.txt"), "--out", str(missing / "f.json")],
            ["apply", str(shift_json), str(tmp_path / "p.txt"), "--out", str(missing / "q.txt")],
            ["register", str(tmp_path / "p.txt"), str(tmp_path / "p.txt"), "--out", str(missing / "r.json")],
            ["match", str(tmp_path / "a.png"), str(tmp_path / "a.png"), "--out", str(missing / "deeper" / "o")]]
    for argv in runs:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert f"--out {argv[-1]}" in err and f"folder {missing}" in err and "does not exist" in err, err
        assert not missing.exists()


def test_match_makes_its_out_folder_but_not_over_a_file(tmp_path, capsys):
    (tmp_path / "a.png").write_bytes(io.encode_png(np.zeros((20, 20), np.uint8)))
    (tmp_path / "taken").write_text("a file")
    assert main(["match", str(tmp_path / "a.png"), str(tmp_path / "a.png"), "--out", str(tmp_path / "taken")]) == 2
    err = capsys.readouterr().err
    assert f"--out {tmp_path / 'taken'} exists and is not a folder" in err and "out_dir" not in err
    assert main(["filter", str(tmp_path / "a.png"), "--out", str(tmp_path)]) == 2
    assert f"--out {tmp_path} is a folder" in capsys.readouterr().err


def test_match_help_lists_every_file_and_readable_bounds(capsys):
    sub = build_parser()._subparsers._group_actions[0].choices["match"]
    text = sub.format_help()
    flat = " ".join(text.split())
    for name in ("match.json", "transform.json", "flow.flo", "confidence.png", "warped.png", "matches.png",
                 "overlay.png", "flow.mha"):
        assert name in flat, name
    assert not re.search(r"\d[eE][+-]?\d", text), "a bound in exponent notation"
    assert "<= 1000000" in flat  # max_keypoints, in full
    seed = flat[flat.index("--seed N"):]
    assert seed[:80].count("<=") == 0  # 2**53 is an implementation limit: no upper bound shown


def test_apply_help_lists_only_what_it_writes():
    sub = build_parser()._subparsers._group_actions[0].choices["apply"]
    out_help = next(a.help for a in sub._actions if "--out" in a.option_strings)
    assert all(s in out_help for s in (".png", ".tif", ".bmp", ".mha"))
    assert ".jpg" not in out_help and ".webp" not in out_help  # read as input, not written
