"""Manifests: CSV and JSON lines read alike; every bad row is reported, with its line, before any work."""
from __future__ import annotations

import json

import pytest

from reglib.batch import ManifestError, PairSpec, read_manifest
from reglib.errors import InputError

from .conftest import write_csv


def test_csv_and_json_lines_give_the_same_pairs_with_paths_from_the_manifest_folder(pairs_folder):
    folder, rows = pairs_folder
    csv_pairs = read_manifest(write_csv(folder / "m.csv", [(*row, "0.7", "") for row in rows[:2]],
                                        header="id,image_a,image_b,ratio,mutual"))
    jsonl = folder / "m.jsonl"
    jsonl.write_text("".join(json.dumps({"id": i, "image_a": a, "image_b": b, "ratio": 0.7}) + "\n"
                             for i, a, b in rows[:2]))
    assert read_manifest(jsonl) == csv_pairs
    assert csv_pairs[0] == PairSpec(id="pair-00", image_a=str((folder / rows[0][1]).resolve()),
                                    image_b=str((folder / rows[0][2]).resolve()), options={"ratio": 0.7})


def test_csv_cells_are_read_as_json_values(pairs_folder):
    folder, rows = pairs_folder
    i, a, b = rows[0]
    path = folder / "typed.csv"
    path.write_text('id,image_a,image_b,mutual,max_keypoints,method,seed,filter\n'
                    f'{i},{a},{b},TRUE,500,vfc,3,"{{""max_iter"": 50}}"\n')
    [pair] = read_manifest(path)
    assert pair.options == {"mutual": True, "max_keypoints": 500, "method": "vfc", "seed": 3,
                            "filter": {"max_iter": 50}}


def test_every_bad_row_is_reported_with_its_line(pairs_folder, tmp_path):
    folder, rows = pairs_folder
    (_, a, b), (_, a1, b1) = rows[0][:], rows[1][:]
    lines = [
        ("good", a, b),
        ("../x", a, b),                                # unsafe: leaves OUT
        (str(folder / "abs"), a, b),                   # unsafe: absolute
        ("good2", "img/missing.png", b),               # missing file
        ("GOOD", a1, b1),                              # duplicate, up to case
        ("fine", a, b, ),
    ]
    path = write_csv(tmp_path / "bad.csv", [(i, str(folder / x), str(folder / y)) for i, x, y in lines])
    path.write_text(path.read_text() + "extra,one_cell_too_few\n")
    with pytest.raises(ManifestError) as info:
        read_manifest(path)
    problems = info.value.problems
    assert len(problems) == 5, problems
    assert problems[0].startswith("line 3: unsafe id '../x'")
    assert problems[1].startswith("line 4: unsafe id ")
    assert problems[2] == f"line 5: `image_a` file not found: {folder / 'img/missing.png'}"
    assert problems[3] == "line 6: duplicate id 'GOOD' (first on line 2)"
    assert problems[4] == "line 8: expected 3 cells like the header, got 2"
    assert isinstance(info.value, InputError)
    assert str(path) in str(info.value)


def test_unknown_options_and_bad_values_are_row_problems(pairs_folder):
    folder, rows = pairs_folder
    (i, a, b), (j, c, d), (k, e, f) = rows[:3]
    path = folder / "opts.jsonl"
    path.write_text("\n".join([
        json.dumps({"id": i, "image_a": a, "image_b": b, "ratoi": 0.7}),
        json.dumps({"id": j, "image_a": c, "image_b": d, "method": "ransac"}),
        json.dumps({"id": k, "image_a": e, "image_b": f, "seed": -1}),
        "[1, 2]",
        '{"id": "broken", ',
        json.dumps({"id": "no-images"}),
    ]) + "\n")
    with pytest.raises(ManifestError) as info:
        read_manifest(path)
    problems = info.value.problems
    assert len(problems) == 6, problems
    assert problems[0].startswith("line 1: unknown option(s) ['ratoi']; valid options are [")
    assert problems[1] == "line 2: `method` must be one of ['l2e', 'vfc'], got 'ransac'"
    assert problems[2] == "line 3: `seed` must be a non-negative integer, got -1"
    assert problems[3] == "line 4: expected a JSON object, got list"
    assert problems[4].startswith("line 5: not valid JSON")
    assert problems[5] == "line 6: missing ['image_a', 'image_b']"


def test_every_bad_value_is_reported_beside_an_unknown_column_and_a_duplicate_id(pairs_folder):
    """The case a user met: an unknown column hid `ratio=1.7` on another row."""
    folder, rows = pairs_folder
    (i, a, b), (j, c, d) = rows[:2]
    path = write_csv(folder / "mixed.csv", [(i, a, b, "0.8", "x", "7"), (j, c, d, "1.7", "y", "-3"),
                                            (i, a, b, "0.8", "z", "1")],
                     header="id,image_a,image_b,ratio,colour,seed")
    with pytest.raises(ManifestError) as info:
        read_manifest(path)
    problems = info.value.problems
    assert sum("unknown option(s) ['colour']" in p for p in problems) == 3  # every row has the column
    assert any(p.startswith("line 3: `ratio` must be") and "1.7" in p for p in problems), problems
    assert any(p.startswith("line 3: `seed` must be") for p in problems), problems
    assert any(p.startswith("line 4: duplicate id") for p in problems), problems
    assert not any(p.startswith("line 2: `") for p in problems)  # its values are good


@pytest.mark.parametrize("text, message", [
    ("id,image_a\n", "line 1: the header must name columns ['id', 'image_a', 'image_b']; missing ['image_b']"),
    ("id,image_a,image_b,ratio,ratio\n", "line 1: column(s) ['ratio'] appear more than once"),
    ("id,image_a,image_b\n", "no pairs: the manifest has no data rows"),
])
def test_a_bad_header_or_an_empty_manifest_is_rejected(tmp_path, text, message):
    path = tmp_path / "m.csv"
    path.write_text(text)
    with pytest.raises(ManifestError) as info:
        read_manifest(path)
    assert info.value.problems == [message]


def test_a_missing_manifest_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="`manifest` file not found"):
        read_manifest(tmp_path / "nope.csv")
