"""``warp_image_file``: the warp tile by tile from a file to a tiled TIFF, against ``warp_image``."""
from __future__ import annotations

import numpy as np
import pytest
import tifffile

from reglib import KernelWarp, filter_matches, warp_image, warp_image_file
from reglib.dense import _tiled_warp
from reglib.errors import InputError


@pytest.fixture(scope="module")
def bent() -> KernelWarp:
    """A smooth non-rigid map (a kernel fit) moving pixels by 5-20 px."""
    rng = np.random.default_rng(3)
    src = rng.uniform(0, 600, (40, 2))
    dst = src + [14.0, -9.0] + rng.normal(0, 4, (40, 2))
    return filter_matches(src, dst, rng=0).transform


def _texture(shape: tuple[int, ...], dtype: type, seed: int = 0) -> np.ndarray:
    import cv2

    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.random(shape).astype(np.float32), (0, 0), 2.0) * 4000
    return img.astype(dtype)


@pytest.mark.parametrize("bands", [1, 3, 5])
def test_tiled_warp_matches_warp_image(tmp_path, bent, monkeypatch, bands):
    monkeypatch.setattr(_tiled_warp, "_BLOCK_W", 96)  # several blocks per tile row
    shape = (530, 610) if bands == 1 else (530, 610, bands)
    b = _texture(shape, np.uint16)
    tifffile.imwrite(tmp_path / "b.tif", b, tile=(64, 64), metadata=None, photometric="minisblack",
                     planarconfig="contig" if bands > 1 else None)
    done = warp_image_file(tmp_path / "b.tif", bent, (500, 560), tmp_path / "w.tif")
    ref, valid = warp_image(b, bent, (500, 560))
    out = tifffile.imread(tmp_path / "w.tif")
    assert out.shape == ref.shape and out.dtype == np.uint16
    assert done.shape == (500, 560) and done.bands == bands and done.levels == 1
    assert done.inside == pytest.approx(valid.mean(), abs=1e-3)
    diff = np.abs(out.astype(np.int64) - ref)
    if diff.ndim == 3:
        diff = diff.max(axis=2)
    # the field is evaluated on each block's own node grid (within 0.05 px of exact): equal up to that
    assert np.median(diff[valid]) <= 2 and np.mean(diff[valid] > 40) < 1e-3
    assert np.all(out[~valid] == 0)
    with tifffile.TiffFile(tmp_path / "w.tif") as tif:
        assert tif.pages[0].is_tiled and tif.pages[0].compression.name != "NONE"


def test_nearest_keeps_labels_and_splits_wide_blocks(tmp_path, bent, monkeypatch):
    monkeypatch.setattr(_tiled_warp, "_MAX_REGION", 2000)  # forces the split of every block
    labels = (np.arange(400 * 300).reshape(400, 300) // 997 % 13).astype(np.int32)
    tifffile.imwrite(tmp_path / "l.tif", labels, rowsperstrip=16, metadata=None)
    warp_image_file(tmp_path / "l.tif", bent, (380, 320), tmp_path / "w.tiff", interpolation="nearest")
    ref, _ = warp_image(labels, bent, (380, 320), interpolation="nearest")
    out = tifffile.imread(tmp_path / "w.tiff")
    assert out.dtype == np.int32 and set(np.unique(out)) <= set(np.unique(labels)) | {0}
    assert np.mean(out != ref) < 0.01  # a label boundary may fall the other way within the field's tolerance


def test_pyramid_levels_and_array_input(tmp_path, bent):
    b = _texture((700, 650, 3), np.uint8, seed=1)
    done = warp_image_file(b, bent, (900, 700), tmp_path / "p.tif", pyramid=True)
    with tifffile.TiffFile(tmp_path / "p.tif") as tif:
        shapes = [level.shape for level in tif.series[0].levels]
    assert shapes == [(900, 700, 3), (450, 350, 3), (225, 175, 3)] and done.levels == 3
    full = tifffile.imread(tmp_path / "p.tif")
    half = tifffile.imread(tmp_path / "p.tif", level=1)
    mean = full[:900, :700].astype(np.float64).reshape(450, 2, 350, 2, 3).mean(axis=(1, 3))
    assert np.abs(half - mean).max() <= 0.5 + 1e-9


def test_png_source_and_errors(tmp_path, bent):
    from reglib.io import encode_png

    b = _texture((200, 220), np.uint8)
    (tmp_path / "b.png").write_bytes(encode_png(b))
    warp_image_file(tmp_path / "b.png", bent, (100, 120), tmp_path / "w.tif")
    assert np.array_equal(tifffile.imread(tmp_path / "w.tif") > 0, warp_image(b, bent, (100, 120))[1])
    with pytest.raises(InputError, match=r"\.tif or \.tiff"):
        warp_image_file(b, bent, (10, 10), tmp_path / "w.png")
    with pytest.raises(InputError, match="no such folder"):
        warp_image_file(b, bent, (10, 10), tmp_path / "nope" / "w.tif")
    with pytest.raises(InputError, match="shape_a"):
        warp_image_file(b, bent, (0, 10), tmp_path / "w.tif")
    with pytest.raises(InputError, match="interpolation"):
        warp_image_file(b, bent, (10, 10), tmp_path / "w.tif", interpolation="cubic")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="too large|over the limit"):
        warp_image_file(tmp_path / "b.png", bent, (10, 10), tmp_path / "w.tif", max_pixels=100)


@pytest.mark.parametrize("suffix", [".flo", ".npy"])
def test_banded_flow_matches_dense_flow(tmp_path, bent, monkeypatch, suffix):
    from reglib.dense import _banded_flow, dense_flow
    from reglib.io import read_flow

    monkeypatch.setattr(_banded_flow, "_BAND_ROWS", 37)  # several bands, the last one short
    _banded_flow.write_flow_banded(tmp_path / f"f{suffix}", bent, (200, 150))
    flow = read_flow(tmp_path / f"f{suffix}")
    assert flow.shape == (200, 150, 2) and flow.dtype == np.float32
    assert np.abs(flow - dense_flow(bent, (200, 150))).max() < 0.05  # each band's own node grid
    with pytest.raises(InputError, match="band by band"):
        _banded_flow.write_flow_banded(tmp_path / "f.mha", bent, (20, 15))


def test_apply_writes_a_flow_over_the_limit_band_by_band(tmp_path, bent, monkeypatch, capsys):
    import json

    import reglib.io
    from reglib.cli import main
    from reglib.dense import dense_flow
    from reglib.io import read_flow

    monkeypatch.setattr(reglib.io, "DEFAULT_MAX_PIXELS", 1000)
    (tmp_path / "t.json").write_text(json.dumps(bent.to_dict()))
    assert main(["apply", str(tmp_path / "t.json"), "--out", str(tmp_path / "f.flo"), "--shape-a", "90", "70"]) == 0
    assert np.abs(read_flow(tmp_path / "f.flo") - dense_flow(bent, (90, 70))).max() < 0.05
    assert main(["apply", str(tmp_path / "t.json"), "--out", str(tmp_path / "f.mha"), "--shape-a", "90", "70"]) == 2
    assert "band by band" in capsys.readouterr().err
