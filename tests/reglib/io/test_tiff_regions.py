"""Large TIFFs read by region and at a working size (``TiffRegions``, ``read_working_image``)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import tifffile

from reglib.errors import ImageTooLarge, InputError
from reglib.io import TiffRegions, encode_png, read_working_image
from reglib.io._working import working_factor


def _image(shape: tuple[int, ...], dtype: type = np.uint8, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 250, shape).astype(dtype)


@pytest.mark.parametrize("layout", [{"tile": (64, 48)}, {"rowsperstrip": 7}, {}])
@pytest.mark.parametrize("shape", [(301, 250), (301, 250, 3), (120, 97, 5)])
def test_regions_equal_the_slices_of_the_image(tmp_path, layout, shape):
    img = _image(shape, np.uint16)
    path = tmp_path / "i.tif"
    tifffile.imwrite(path, img, photometric="rgb" if shape[-1:] == (3,) else "minisblack", metadata=None,
                     planarconfig="contig" if len(shape) == 3 else None, **layout)
    with TiffRegions(path) as tif:
        assert tif.shape == shape[:2] and tif.bands == (shape[2] if len(shape) == 3 else 1)
        assert tif.dtype == np.uint16
        for y0, y1, x0, x1 in [(0, 1, 0, 1), (5, 77, 13, 96), (60, 120, 40, 97), (0, shape[0], 0, shape[1])]:
            assert np.array_equal(tif.read(y0, y1, x0, x1), img[y0:y1, x0:x1])


@pytest.mark.parametrize("dtype", [np.uint8, np.int16, np.float32])
def test_reduced_is_the_block_mean_without_the_partial_blocks(tmp_path, dtype):
    img = _image((203, 158), dtype, seed=1)
    tifffile.imwrite(tmp_path / "i.tif", img, tile=(32, 32), metadata=None)
    with TiffRegions(tmp_path / "i.tif") as tif:
        small = tif.reduced(4)
    assert small.shape == (50, 39) and small.dtype == dtype
    expected = img[:200, :156].astype(np.float64).reshape(50, 4, 39, 4).mean(axis=(1, 3))
    assert np.abs(small.astype(np.float64) - expected).max() <= (0.5 if dtype != np.float32 else 1e-3)


def test_reduced_reads_the_pyramid_level_that_divides_the_factor(tmp_path):
    full = _image((512, 384), seed=2)
    level = np.full((256, 192), 7, np.uint8)  # not the mean of full: proves where the pixels came from
    with tifffile.TiffWriter(tmp_path / "p.tif") as w:
        w.write(full, tile=(64, 64), metadata=None)
        w.write(level, tile=(64, 64), subfiletype=1, metadata=None)
    with TiffRegions(tmp_path / "p.tif") as tif:
        assert tif.factors == (1, 2)
        assert np.array_equal(tif.read(0, 10, 0, 10, level=1), level[:10, :10])
        assert np.all(tif.reduced(4) == 7)  # 2 from the level, then 2 x 2 means of it
        assert not np.all(tif.reduced(3) == 7)  # 3 is no multiple of 2: from the full image


def test_read_working_image_reads_a_large_tiff_reduced(tmp_path):
    img = _image((900, 700), seed=3)
    tifffile.imwrite(tmp_path / "i.tif", img, tile=(128, 128), metadata=None)
    small = read_working_image(tmp_path / "i.tif", max_side=1000, max_pixels=100_000, name="image_a")
    k = working_factor((900, 700), 1000, 100_000)
    assert small.factor == k == 3 and small.shape == (900, 700)
    assert small.image.shape == (300, 233) and small.image.size <= 100_000
    assert np.array_equal(small.image, cv2.resize(img[:900, :699], (233, 300), interpolation=cv2.INTER_AREA))
    within = read_working_image(tmp_path / "i.tif", max_side=1000, max_pixels=1_000_000)
    assert within.factor == 1 and np.array_equal(within.image, img)
    assert read_working_image(tmp_path / "i.tif", max_side=200, max_pixels=100_000).image.shape[0] <= 200


def test_other_formats_and_bytes_keep_the_limit(tmp_path):
    img = _image((400, 300), seed=4)
    (tmp_path / "i.png").write_bytes(encode_png(img))
    with pytest.raises(ImageTooLarge, match="only a TIFF file that large is read"):
        read_working_image(tmp_path / "i.png", max_side=100, max_pixels=10_000)
    with pytest.raises(ImageTooLarge, match="over the limit"):
        read_working_image((tmp_path / "i.png").read_bytes(), max_side=100, max_pixels=10_000)
    with pytest.raises(InputError, match="max_side"):
        read_working_image(tmp_path / "i.png", max_side=0)


def test_bad_tiffs_are_named(tmp_path):
    (tmp_path / "bad.tif").write_bytes(b"II*\x00garbage")
    with pytest.raises(InputError, match="bad.tif"):
        TiffRegions(tmp_path / "bad.tif", "image_b")
    tifffile.imwrite(tmp_path / "stack.tif", _image((3, 40, 30)), photometric="minisblack", metadata=None)
    with pytest.raises(InputError, match="axes"):
        TiffRegions(tmp_path / "stack.tif")


def test_a_codec_tifffile_lacks_names_the_extra(tmp_path):
    try:
        import imagecodecs  # noqa: F401
    except ImportError:
        pass
    else:
        pytest.skip("imagecodecs is installed: LZW decodes")
    tifffile.imwrite(tmp_path / "c.tif", _image((64, 64)), tile=(32, 32), metadata=None)
    with tifffile.TiffFile(tmp_path / "c.tif") as tif:
        offset = tif.pages[0].tags["Compression"].valueoffset
    data = bytearray((tmp_path / "c.tif").read_bytes())
    data[offset] = 5  # the compression tag now says LZW, which tifffile decodes only through imagecodecs
    (tmp_path / "c.tif").write_bytes(bytes(data))
    with TiffRegions(tmp_path / "c.tif") as tif, pytest.raises(InputError, match=r"reglib\[large\]"):
        tif.read(0, 10, 0, 10)
