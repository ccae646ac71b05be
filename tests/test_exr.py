"""homofac.io.exr and homofac.io.hdr: round trips, channel layouts, and one-line errors on bad files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from homofac.errors import HomofacError
from homofac.io.exr import envmap_kind, read_exr, read_exr_with_header, write_exr
from homofac.io.hdr import float_to_rgbe, read_hdr, rgbe_to_float, write_hdr

BUNDLED_STUDIO = Path(__file__).resolve().parents[1] / "src" / "homofac" / "data" / "hdri" / "studio.exr"


def _hdr_image(rng, h=13, w=40):
    """Positive HDR-like data over many decades, with a few exact zeros."""
    a = np.exp(rng.normal(0.0, 3.0, (h, w, 3))).astype(np.float32)
    a[0, :3] = 0.0
    return a


def _one_line_error(excinfo, *needles):
    msg = str(excinfo.value)
    assert "\n" not in msg
    for n in needles:
        assert n in msg, (n, msg)


# ---------------------------------------------------------------------------------------------- EXR


def test_exr_float32_round_trip_is_bit_exact(tmp_path):
    rng = np.random.default_rng(0)
    a = (rng.normal(size=(17, 31, 3)) * 10.0 ** rng.integers(-20, 20, size=(17, 31, 3))).astype(np.float32)
    a[0, 0] = [np.inf, -np.inf, np.nan]  # special values survive too
    p = write_exr(tmp_path / "a.exr", a)
    b = read_exr(p)
    assert b.dtype == np.float32 and b.shape == a.shape
    assert np.array_equal(a.view(np.uint32), b.view(np.uint32))


def test_exr_half_round_trip_within_half_precision(tmp_path):
    rng = np.random.default_rng(1)
    a = rng.uniform(1e-3, 6e4, size=(9, 12, 3)).astype(np.float32)
    p = write_exr(tmp_path / "h.exr", a, half=True)
    b = read_exr(p)
    assert b.dtype == np.float32
    assert np.all(np.abs(b - a) <= np.abs(a) * 2.0**-11 * 1.0001)
    assert np.array_equal(b, a.astype(np.float16).astype(np.float32))
    f = OpenEXR.File(str(p))
    assert f.channels()["RGB"].pixels.dtype == np.float16  # really stored as half


def test_exr_header_envmap_attribute(tmp_path):
    a = np.ones((4, 24, 3), np.float32)
    p = write_exr(tmp_path / "c.exr", a, header={"envmap": OpenEXR.ENVMAP_CUBE})
    assert envmap_kind(read_exr_with_header(p)[1]) == "cube"
    p = write_exr(tmp_path / "l.exr", a[:, :8], header={"envmap": OpenEXR.ENVMAP_LATLONG})
    assert envmap_kind(read_exr_with_header(p)[1]) == "latlong"
    p = write_exr(tmp_path / "n.exr", a)
    assert envmap_kind(read_exr_with_header(p)[1]) is None


def test_exr_channel_layouts(tmp_path):
    rng = np.random.default_rng(2)
    a = rng.random((5, 7, 3)).astype(np.float32)
    hdr = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    # separate R, G, B channels
    OpenEXR.File(hdr, {c: np.ascontiguousarray(a[..., i]) for i, c in enumerate("RGB")}).write(str(tmp_path / "sep.exr"))
    assert np.array_equal(read_exr(tmp_path / "sep.exr"), a)
    # RGBA: alpha dropped
    rgba = np.concatenate([a, np.full((5, 7, 1), 0.5, np.float32)], axis=-1)
    OpenEXR.File(hdr, {"RGBA": rgba}).write(str(tmp_path / "rgba.exr"))
    assert np.array_equal(read_exr(tmp_path / "rgba.exr"), a)
    # grey Y: copied to three channels
    OpenEXR.File(hdr, {"Y": np.ascontiguousarray(a[..., 0])}).write(str(tmp_path / "y.exr"))
    y = read_exr(tmp_path / "y.exr")
    assert y.shape == (5, 7, 3) and np.array_equal(y[..., 2], a[..., 0])
    # half channels come back as float32
    OpenEXR.File(hdr, {"RGB": a.astype(np.float16)}).write(str(tmp_path / "half.exr"))
    assert read_exr(tmp_path / "half.exr").dtype == np.float32


def test_exr_reads_a_real_map_and_a_full_size_one(tmp_path):
    b = read_exr(BUNDLED_STUDIO)
    assert b.shape == (128, 256, 3) and b.dtype == np.float32 and b.min() >= 0.0 and np.isfinite(b).all()
    big = np.repeat(np.repeat(b, 4, axis=0), 4, axis=1)  # 1024 x 512, the size of the original maps
    p = write_exr(tmp_path / "big.exr", big, half=True, compression="piz")
    a = read_exr(p)
    assert a.shape == (512, 1024, 3) and a.dtype == np.float32
    np.testing.assert_allclose(a, big, rtol=1e-3, atol=1e-6)


def test_exr_missing_file(tmp_path):
    with pytest.raises(HomofacError) as e:
        read_exr(tmp_path / "nope.exr")
    _one_line_error(e, "nope.exr", "no such file")


def test_exr_not_an_exr(tmp_path):
    p = tmp_path / "text.exr"
    p.write_text("this is not an image\nsecond line\n")
    with pytest.raises(HomofacError) as e:
        read_exr(p)
    _one_line_error(e, "text.exr", "not an OpenEXR file")


@pytest.mark.parametrize("fraction", [0.5, 0.9, 0.002])
def test_exr_truncated_file(tmp_path, fraction):
    data = BUNDLED_STUDIO.read_bytes()
    p = tmp_path / "cut.exr"
    p.write_bytes(data[: int(len(data) * fraction)])
    with pytest.raises(HomofacError) as e:
        read_exr(p)
    _one_line_error(e, "cut.exr")


def test_exr_without_rgb_channels(tmp_path):
    p = tmp_path / "depth.exr"
    OpenEXR.File({}, {"Z": np.ones((3, 4), np.float32)}).write(str(p))
    with pytest.raises(HomofacError) as e:
        read_exr(p)
    _one_line_error(e, "depth.exr", "no RGB")


def test_exr_write_failure_leaves_no_partial_file(tmp_path):
    with pytest.raises(HomofacError) as e:
        write_exr(tmp_path / "bad.exr", np.ones((4, 4, 2), np.float32))
    _one_line_error(e, "bad.exr")
    with pytest.raises(HomofacError):
        write_exr(tmp_path / "missing_dir" / "x.exr", np.ones((4, 4, 3), np.float32))
    assert list(tmp_path.iterdir()) == []
    # an existing file is replaced atomically
    p = write_exr(tmp_path / "x.exr", np.zeros((2, 2, 3), np.float32))
    write_exr(p, np.ones((3, 3, 3), np.float32))
    assert read_exr(p).shape == (3, 3, 3)
    assert [q.name for q in tmp_path.iterdir()] == ["x.exr"]


# ---------------------------------------------------------------------------------------------- HDR


@pytest.mark.parametrize("rle", [True, False])
def test_hdr_round_trip_within_rgbe_precision(tmp_path, rle):
    rng = np.random.default_rng(3)
    a = _hdr_image(rng)
    # long runs, to exercise run codes as well as literals
    a[5:8] = [1.5, 0.25, 3.0]
    p = write_hdr(tmp_path / "a.hdr", a, rle=rle)
    b = read_hdr(p)
    assert b.shape == a.shape and b.dtype == np.float32
    # RGBE: each component within half a mantissa step of the largest one, i.e. <= 1/256 of the max
    tol = a.max(axis=-1, keepdims=True) / 256.0
    assert np.all(np.abs(b - a) <= tol * (1 + 1e-6))
    assert np.all(b[0, :3] == 0.0)


def test_hdr_rgbe_codec():
    x = np.array([[1.0, 0.5, 0.25], [0.0, 0.0, 0.0], [1e-3, 2e3, 7.0]])
    e = float_to_rgbe(x)
    assert e[0].tolist() == [127, 63, 31, 129]  # Radiance setcolr: mantissa * 255.9999
    assert e[1].tolist() == [0, 0, 0, 0]
    y = rgbe_to_float(e)
    assert np.all(np.abs(y - x) <= x.max(axis=-1, keepdims=True) / 256)


def test_hdr_flipped_orientation(tmp_path):
    rng = np.random.default_rng(4)
    a = _hdr_image(rng, 6, 10)
    p = write_hdr(tmp_path / "a.hdr", a, rle=False)
    data = p.read_bytes().replace(b"-Y 6 +X 10", b"+Y 6 +X 10")
    q = tmp_path / "flip.hdr"
    q.write_bytes(data)
    assert np.array_equal(read_hdr(q), read_hdr(p)[::-1])


def test_hdr_bad_files(tmp_path):
    with pytest.raises(HomofacError) as e:
        read_hdr(tmp_path / "nope.hdr")
    _one_line_error(e, "nope.hdr", "no such file")
    p = tmp_path / "x.hdr"
    p.write_bytes(b"P6\n2 2\n255\n" + bytes(12))
    with pytest.raises(HomofacError) as e:
        read_hdr(p)
    _one_line_error(e, "x.hdr", "not a Radiance")
    good = write_hdr(tmp_path / "g.hdr", _hdr_image(np.random.default_rng(5), 8, 16)).read_bytes()
    p.write_bytes(good[: len(good) // 2])
    with pytest.raises(HomofacError) as e:
        read_hdr(p)
    _one_line_error(e, "x.hdr", "truncated")
    p.write_bytes(good.replace(b"-Y 8 +X 16", b"-Y 8 -X 16"))
    with pytest.raises(HomofacError) as e:
        read_hdr(p)
    _one_line_error(e, "x.hdr")
    p.write_bytes(good.replace(b"32-bit_rle_rgbe", b"32-bit_rle_xyze"))
    with pytest.raises(HomofacError) as e:
        read_hdr(p)
    _one_line_error(e, "x.hdr", "xyze")
