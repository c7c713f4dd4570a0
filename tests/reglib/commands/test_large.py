"""``reglib match``, ``reglib apply`` and ``reglib batch`` on TIFFs over the pixel limit (in-process)."""
from __future__ import annotations

import json

import numpy as np
import tifffile

from reglib import KernelWarp, batch, warp_image
from reglib.cli import main
from reglib.io import read_image


def test_match_writes_the_json_and_small_pictures_but_no_flow_or_warp(large_pair, tmp_path, capsys):
    out = tmp_path / "M"
    assert main(["match", large_pair.path_a, large_pair.path_b, "--out", str(out), "--max-pixels", "1000000",
                 "--max-side", "800"]) == 0
    printed = capsys.readouterr().out
    assert "large pair (3000x3000 pixels of a)" in printed and "--shape-a 3000 3000" in printed
    assert sorted(p.name for p in out.iterdir()) == ["match.json", "matches.png", "overlay.png", "transform.json"]
    body = json.loads((out / "match.json").read_text())
    assert body["shape_a"] == [3000, 3000] and body["converged"]
    f = KernelWarp.from_dict(json.loads((out / "transform.json").read_text()))
    pts = np.random.default_rng(2).uniform(100, 2900, (400, 2))
    assert np.median(np.linalg.norm(f(pts) - large_pair.true_map(pts), axis=1)) < 1.0
    assert max(read_image(out / "overlay.png").shape[:2]) <= 1600  # drawn at a reduced size


def test_apply_writes_a_tiled_pyramid_that_overlays_a(large_pair, tmp_path, capsys):
    m = tmp_path / "M"
    assert main(["match", large_pair.path_a, large_pair.path_b, "--out", str(m), "--max-pixels", "1000000",
                 "--max-side", "800", "--no-pictures"]) == 0
    w = tmp_path / "W.tif"
    assert main(["apply", str(m / "transform.json"), large_pair.path_b, "--out", str(w), "--shape-a", "3000", "3000",
                 "--pyramid"]) == 0
    assert "tiled TIFF" in capsys.readouterr().out
    warped = tifffile.imread(w)
    assert warped.shape == (3000, 3000) and warped.dtype == np.uint8
    with tifffile.TiffFile(w) as tif:
        assert [level.shape for level in tif.series[0].levels][:3] == [(3000, 3000), (1500, 1500), (750, 750)]
    # the warp overlays a (b = a moved): away from the borders the two agree closely
    inner = (slice(200, 2800), slice(200, 2800))
    assert np.median(np.abs(warped[inner].astype(int) - large_pair.image_a[inner])) <= 2
    f = KernelWarp.from_dict(json.loads((m / "transform.json").read_text()))
    ref, _ = warp_image(large_pair.image_b, f, (3000, 3000))
    assert np.median(np.abs(warped.astype(int) - ref)) == 0
    assert main(["apply", str(m / "transform.json"), large_pair.path_b, "--out", str(tmp_path / "W.png"),
                 "--pyramid"]) == 2
    assert "tiled .tif" in capsys.readouterr().err


def test_batch_warped_writes_a_tiled_tif_for_a_large_pair(large_pair, tmp_path):
    manifest = tmp_path / "m.csv"
    manifest.write_text(f"id,image_a,image_b,max_pixels,max_side\nbig,{large_pair.path_a},{large_pair.path_b},"
                        "1000000,800\n")
    out = tmp_path / "out"
    assert main(["batch", str(manifest), "--out", str(out), "--workers", "1", "--no-progress", "--warped"]) == 0
    files = sorted(p.name for p in (out / "big").iterdir())
    assert files == ["match.json", "transform.json", "warped.tif"]
    assert tifffile.imread(out / "big" / "warped.tif").shape == (3000, 3000)
    line = next(iter(batch.read_results(out / "results.jsonl")))
    assert line["status"] == "ok" and line["converged"]
