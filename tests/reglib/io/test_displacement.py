"""Tests of the ITK displacement fields (reglib.io.write_flow / read_flow with .mha, .nrrd, .nii, .nii.gz).

The files are checked against SimpleITK, the reader medical tools build on: it must see a 2-D field
of 2-component vectors on the pixel grid, and its DisplacementFieldTransform must map a point the
way the transform a -> b does.
"""
from __future__ import annotations

import gzip

import numpy as np
import pytest

from reglib import KernelWarp, dense_flow, io, warp_image
from reglib._transforms import LinearPart
from reglib.errors import InputError

SUFFIXES = [".mha", ".nrrd", ".nii", ".nii.gz"]


def _warp() -> KernelWarp:
    """A non-rigid a -> b map on a 60 x 80 image: rotation, scale, shift and smooth bumps (several px)."""
    rng = np.random.default_rng(3)
    ang = np.deg2rad(6.0)
    lin = LinearPart(kind="affine", matrix=np.c_[1.05 * np.array([[np.cos(ang), -np.sin(ang)],
                                                                   [np.sin(ang), np.cos(ang)]]), [0.04, -0.03]])
    return KernelWarp(dim=2, src_mean=np.array([40.0, 30.0]), src_scale=40.0, dst_mean=np.array([42.0, 27.0]),
                      dst_scale=40.0, linear=lin, beta=3.0, centers=rng.uniform(-1, 1, (8, 2)),
                      weights=rng.normal(0, 0.05, (8, 2)))


def _pixels(h: int, w: int) -> np.ndarray:
    ys, xs = np.mgrid[0:h, 0:w]
    return np.c_[xs.ravel(), ys.ravel()].astype(np.float64)  # (x, y): x the column


def _exact_flow(t: KernelWarp, h: int, w: int) -> np.ndarray:
    p = _pixels(h, w)
    return (t(p) - p).reshape(h, w, 2).astype(np.float32)


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_round_trip_is_exact(tmp_path, suffix):
    flow = np.random.default_rng(0).normal(0, 5, (7, 11, 2)).astype(np.float32)
    path = tmp_path / f"flow{suffix}"
    io.write_flow(path, flow)
    got = io.read_flow(path)
    assert got.dtype == np.float32 and got.shape == (7, 11, 2)
    assert np.array_equal(got, flow)
    assert io.encode_flow(flow, suffix) == path.read_bytes()


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_simpleitk_reads_a_2d_vector_field_on_the_pixel_grid(tmp_path, suffix):
    sitk = pytest.importorskip("SimpleITK")
    flow = np.random.default_rng(1).normal(0, 3, (9, 13, 2)).astype(np.float32)
    io.write_flow(tmp_path / f"f{suffix}", flow)
    image = sitk.ReadImage(str(tmp_path / f"f{suffix}"))
    assert image.GetDimension() == 2 and image.GetSize() == (13, 9)  # ITK sizes are (W, H)
    assert image.GetNumberOfComponentsPerPixel() == 2
    assert image.GetSpacing() == (1.0, 1.0) and image.GetOrigin() == (0.0, 0.0)
    assert image.GetDirection() == (1.0, 0.0, 0.0, 1.0)
    assert np.array_equal(sitk.GetArrayFromImage(image), flow)  # [row, col, (dx, dy)]


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_itk_displacement_transform_maps_points_like_the_transform(tmp_path, suffix):
    sitk = pytest.importorskip("SimpleITK")
    t = _warp()
    h, w = 60, 80
    io.write_flow(tmp_path / f"f{suffix}", _exact_flow(t, h, w))
    field = sitk.Cast(sitk.ReadImage(str(tmp_path / f"f{suffix}")), sitk.sitkVectorFloat64)
    itk_transform = sitk.DisplacementFieldTransform(field)
    rng = np.random.default_rng(2)
    points = _pixels(h, w)[rng.choice(h * w, 200, replace=False)]  # pixel centres (x = column, y = row)
    want = t(points)
    assert np.abs(want - points).max() > 2.0  # the map moves points by pixels: the test can fail
    got = np.array([itk_transform.TransformPoint(tuple(p)) for p in points])
    np.testing.assert_allclose(got, want, atol=1e-4)


def test_the_flow_dense_flow_writes_is_the_transform_within_the_contract(tmp_path):
    sitk = pytest.importorskip("SimpleITK")
    t = _warp()
    io.write_flow(tmp_path / "f.mha", dense_flow(t, (60, 80)))
    field = sitk.Cast(sitk.ReadImage(str(tmp_path / "f.mha")), sitk.sitkVectorFloat64)
    itk_transform = sitk.DisplacementFieldTransform(field)
    points = _pixels(60, 80)[::37]
    got = np.array([itk_transform.TransformPoint(tuple(p)) for p in points])
    assert np.abs(got - t(points)).max() < 0.05  # dense_flow's own budget (CONTRACTS.md)


def test_itk_resampling_b_with_the_field_is_warp_image(tmp_path):
    """a is ITK's fixed image, b the moving one: Resample(b, a, field) overlays a, like warp_image."""
    sitk = pytest.importorskip("SimpleITK")
    t = _warp()
    h, w = 60, 80
    ys, xs = np.mgrid[0:70, 0:90]
    b = (100 + 50 * np.sin(xs / 7.0) * np.cos(ys / 9.0)).astype(np.float32)  # smooth: interpolators agree
    io.write_flow(tmp_path / "f.nrrd", _exact_flow(t, h, w))
    field = sitk.Cast(sitk.ReadImage(str(tmp_path / "f.nrrd")), sitk.sitkVectorFloat64)
    reference = sitk.Image(w, h, sitk.sitkFloat32)
    resampled = sitk.GetArrayFromImage(sitk.Resample(sitk.GetImageFromArray(b), reference,
                                                     sitk.DisplacementFieldTransform(field), sitk.sitkLinear, 0.0))
    warped, valid = warp_image(b, t, (h, w))
    inner = valid.copy()
    inner[[0, -1], :] = inner[:, [0, -1]] = False
    assert inner.mean() > 0.5
    assert np.abs(resampled[inner] - warped[inner]).max() < 0.5  # on values of 50..150
    shifted = sitk.GetArrayFromImage(sitk.Resample(sitk.GetImageFromArray(b), reference, sitk.Transform()))
    assert np.abs(shifted[inner] - warped[inner]).max() > 5  # without the field they differ


@pytest.mark.parametrize("suffix", SUFFIXES)
@pytest.mark.parametrize("compressed", [False, True])
def test_fields_written_by_simpleitk_are_read(tmp_path, suffix, compressed):
    sitk = pytest.importorskip("SimpleITK")
    flow = np.random.default_rng(4).normal(0, 2, (5, 6, 2)).astype(np.float32)
    image = sitk.Cast(sitk.GetImageFromArray(flow.astype(np.float64), isVector=True), sitk.sitkVectorFloat64)
    sitk.WriteImage(image, str(tmp_path / f"s{suffix}"), useCompression=compressed)
    assert np.array_equal(io.read_flow(tmp_path / f"s{suffix}"), flow)


@pytest.mark.parametrize("suffix", [".mha", ".nrrd", ".nii.gz"])
@pytest.mark.parametrize("what, change", [("spacing", "SetSpacing"), ("origin", "SetOrigin"),
                                          ("direction", "SetDirection")])
def test_a_field_off_the_pixel_grid_is_refused_by_name(tmp_path, suffix, what, change):
    sitk = pytest.importorskip("SimpleITK")
    image = sitk.GetImageFromArray(np.zeros((4, 5, 2), np.float32), isVector=True)
    value = {"SetSpacing": (0.5, 1.0), "SetOrigin": (3.0, 0.0), "SetDirection": (0.0, -1.0, 1.0, 0.0)}[change]
    getattr(image, change)(value)
    sitk.WriteImage(image, str(tmp_path / f"g{suffix}"))
    with pytest.raises(InputError, match=f"{what} is .*pixel grid"):
        io.read_flow(tmp_path / f"g{suffix}")


def test_bad_fields_are_named_input_errors(tmp_path):
    flow = np.zeros((3, 4, 2), np.float32)
    good = io.encode_mha(flow)
    cases = {
        "short.mha": good[:-8],
        "three.mha": good.replace(b"ElementNumberOfChannels = 2", b"ElementNumberOfChannels = 3"),
        "int.mha": good.replace(b"MET_FLOAT", b"MET_UCHAR"),
        "huge.mha": good.replace(b"DimSize = 4 3", b"DimSize = 100000 100000"),
        "text.mha": b"hello\n",
        "short.nrrd": io.encode_nrrd(flow)[:-4],
        "magic.nrrd": b"PNG" + io.encode_nrrd(flow)[3:],
        "short.nii.gz": gzip.compress(io.encode_nifti(flow, compress=False)[:-4]),
        "tiny.nii": b"\x00" * 20,
    }
    words = {"short.mha": "data hold", "three.mha": "2-component", "int.mha": "MET_FLOAT or MET_DOUBLE",
             "huge.mha": "implausible", "text.mha": "not a MetaImage", "short.nrrd": "data hold",
             "magic.nrrd": "not a NRRD", "short.nii.gz": "data hold", "tiny.nii": "too short"}
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(InputError, match=words[name]):
            io.read_flow(tmp_path / name)
    with pytest.raises(InputError, match="no such flow file"):
        io.read_flow(tmp_path / "missing.mha")
    with pytest.raises(InputError, match="NaN or inf"):
        io.write_flow(tmp_path / "nan.mha", np.full((2, 2, 2), np.nan, np.float32))
    with pytest.raises(InputError, match=r"\(H, W, 2\)"):
        io.write_flow(tmp_path / "bad.nrrd", np.zeros((2, 2, 3)))
    assert not (tmp_path / "nan.mha").exists() and not (tmp_path / "bad.nrrd").exists()


FLOW = np.random.default_rng(5).normal(0, 3, (3, 4, 2)).astype(np.float32)
NRRD_HEAD = ("NRRD0004\n# a comment\ntype: float\ndimension: 3\nspace dimension: 2\nsizes: 2 4 3\n"
             "space directions: none (1,0) (0,1)\nkinds: vector domain domain\nendian: little\nencoding: raw\n"
             "space origin: (0,0)\n\n")


def _nrrd(tmp_path, head: str, raw: bytes | None = None):
    """A .nrrd file of ``head`` (header text ending in a blank line) and ``raw`` (FLOW's little-endian floats)."""
    path = tmp_path / "f.nrrd"
    path.write_bytes(head.encode("ascii") + (FLOW.astype("<f4").tobytes() if raw is None else raw))
    return path


@pytest.mark.parametrize("old, new", [
    ("", ""),
    ("space directions: none (1,0) (0,1)\n", ""),  # no grid given: spacing 1 by default
    ("space directions: none (1,0) (0,1)\n", "spacings: nan 1 1\n"),
    ("space origin: (0,0)\n", ""),
    ("type: float\n", "Type: float\nold key:=type: int\n"),  # keys in any case; key/value pairs are not fields
    ("endian: little\nencoding: raw\n", ""),
])
def test_nrrd_header_variants_read_the_same_field(tmp_path, old, new):
    assert old in NRRD_HEAD
    assert np.array_equal(io.read_flow(_nrrd(tmp_path, NRRD_HEAD.replace(old, new))), FLOW)


@pytest.mark.parametrize("encoding", ["gzip", "gz"])
def test_nrrd_gzip_double_and_big_endian_data(tmp_path, encoding):
    head = NRRD_HEAD.replace("encoding: raw", f"encoding: {encoding}").replace("type: float", "type: double")
    head = head.replace("endian: little", "endian: big")
    got = io.read_flow(_nrrd(tmp_path, head, gzip.compress(FLOW.astype(">f8").tobytes())))
    assert got.dtype == np.float32 and np.array_equal(got, FLOW)


@pytest.mark.parametrize("old, new, words", [
    ("\n\n", "\n", r"f.nrrd: the NRRD header has no end \(a blank line before the data\)"),
    ("type: float\n", "", "f.nrrd: the NRRD header has no `type`"),
    ("type: float", "type: short", "f.nrrd: NRRD type must be float or double, got 'short'"),
    ("sizes: 2 4 3\n", "", "the NRRD header has no `sizes`"),
    ("sizes: 2 4 3", "sizes: 2 4 x", "f.nrrd: bad sizes '2 4 x'"),
    ("dimension: 3\n", "", "the NRRD header has no `dimension`"),
    ("sizes: 2 4 3", "sizes: 3 4 3", r"f.nrrd: a flow is a 2-D field of 2-component vectors \(NRRD sizes 2 W H\), "
                                     "got dimension 3 and sizes 3 4 3"),
    ("sizes: 2 4 3", "sizes: 2 4 3 1", "got dimension 3 and sizes 2 4 3 1"),
    ("dimension: 3", "dimension: 4", "got dimension 4 and sizes 2 4 3"),
    ("kinds: vector domain domain", "kinds: domain domain domain",
     "f.nrrd: NRRD kinds must be a vector axis, then two domain axes, got 'domain domain domain'"),
    ("kinds: vector domain domain", "kinds: vector domain", "NRRD kinds must be"),
    ("kinds: vector domain domain", "kinds: vector space list", "NRRD kinds must be"),
    ("encoding: raw\n", "encoding: raw\ndata file: f.raw\n", "f.nrrd: detached NRRD data are not read"),
    ("encoding: raw\n", "encoding: raw\ndatafile: f.raw\n", "detached NRRD data are not read"),
    ("encoding: raw", "encoding: bzip2", "f.nrrd: NRRD encoding must be raw or gzip, got 'bzip2'"),
    ("sizes: 2 4 3", "sizes: 2 0 3", "f.nrrd: implausible field size 0x3"),
    ("space directions: none (1,0) (0,1)\n", "spacings: 1 1 1\n",
     r"f.nrrd: NRRD space directions must give two 2-D axes, got \[1.0, 1.0, 1.0\]"),
    ("space directions: none (1,0) (0,1)", "space directions: none (1,0,0) (0,1,0)",
     "NRRD space directions must give two 2-D axes"),
    ("space directions: none (1,0) (0,1)", "space directions: none (1,0) (a,1)", "f.nrrd: bad space directions"),
    ("space directions: none (1,0) (0,1)\n", "spacings: nan 0.5 1\n", r"f.nrrd: the field's spacing is \[0.5, 1.0\]"),
    ("space origin: (0,0)", "space origin: (2,0)", r"f.nrrd: the field's origin is \[2.0, 0.0\]"),
    ("encoding: raw", "encoding: gzip", "f.nrrd: the compressed data cannot be decompressed"),
])
def test_bad_nrrd_headers_are_named_input_errors(tmp_path, old, new, words):
    assert old in NRRD_HEAD
    with pytest.raises(InputError, match=words):
        io.read_flow(_nrrd(tmp_path, NRRD_HEAD.replace(old, new)))
