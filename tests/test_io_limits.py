"""homofac.io.limits: header-only probes, the memory cap on whole reads, strip reads in bounded memory.

"Trust nothing on disk": a 0.8 MB ZIP EXR declaring 8192 x 16384 half pixels must be refused (or read in
strips) without gigabytes of memory; a patched header gives a clear one-line error.
"""

from __future__ import annotations

import ast
import json
import struct
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from homofac.errors import HomofacError
from homofac.io import exr as exr_mod
from homofac.io.exr import BUILTIN_STRIP_COMPRESSIONS, exr_info, iter_exr_strips, read_exr, write_exr
from homofac.io.files import DEFAULT_MAX_BYTES, MAX_PIXELS, strip_rows
from homofac.io.hdr import hdr_info, iter_hdr_strips, read_hdr, rgbe_to_float, write_hdr
from homofac.io.limits import box_downsample, image_info, iter_strips, read_downsampled

SRC = Path(__file__).resolve().parents[1] / "src" / "homofac"


def _one_line_error(excinfo, *needles):
    msg = str(excinfo.value)
    assert "\n" not in msg
    for n in needles:
        assert n in msg, (n, msg)
    return msg


def _image(h, w, seed=0):
    rng = np.random.default_rng(seed)
    a = np.exp(rng.normal(0.0, 2.0, (h, w, 3))).astype(np.float32)
    a[: h // 3] = [1.5, 0.25, 3.0]  # long runs: compressible, RLE runs
    return a


def _gather(strips, h, w):
    out = np.full((h, w, 3), np.nan, np.float32)
    seen = 0
    for y0, s in strips:
        assert s.dtype == np.float32 and s.shape[1:] == (w, 3)
        out[y0 : y0 + s.shape[0]] = s
        seen += s.shape[0]
    assert seen == h
    return out


# ------------------------------------------------------------------ hand-written EXR files (no big arrays)


def _attr(name: str, typ: str, value: bytes) -> bytes:
    return name.encode() + b"\0" + typ.encode() + b"\0" + struct.pack("<i", len(value)) + value


def _zip_chunk(raw: bytes) -> bytes:
    """OpenEXR's ZIP encoding: even bytes then odd bytes, byte-delta predictor (+128), zlib."""
    b = np.frombuffer(raw, np.uint8)
    t = np.concatenate([b[0::2], b[1::2]])
    d = t.copy()
    d[1:] = t[1:] - t[:-1] + np.uint8(128)
    return zlib.compress(d.tobytes(), 9)


def write_constant_exr(path: Path, width: int, height: int, value: float = 0.5, *, chunks: int | None = None) -> Path:
    """A scanline ZIP half RGB EXR whose pixels are all ``value``, built from one compressed chunk.

    8192 x 16384 gives the 0.8 MB file of the issue without ever allocating the image. ``chunks``
    writes only the first chunks (offsets 0 for the others): a file declaring more than it holds.
    """
    chans = b"".join(c + b"\0" + struct.pack("<iB3xii", 1, 0, 1, 1) for c in (b"B", b"G", b"R")) + b"\0"
    box = struct.pack("<iiii", 0, 0, width - 1, height - 1)
    header = (
        b"\x76\x2f\x31\x01" + struct.pack("<I", 2)
        + _attr("channels", "chlist", chans) + _attr("compression", "compression", b"\x03")
        + _attr("dataWindow", "box2i", box) + _attr("displayWindow", "box2i", box)
        + _attr("lineOrder", "lineOrder", b"\x00") + _attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
        + _attr("screenWindowCenter", "v2f", struct.pack("<ff", 0, 0))
        + _attr("screenWindowWidth", "float", struct.pack("<f", 1.0)) + b"\0"
    )
    n = -(-height // 16)
    line = np.full(width, value, np.float16).tobytes() * 3
    full = _zip_chunk(line * 16)
    last = full if height % 16 == 0 else _zip_chunk(line * (height % 16))
    pos = len(header) + 8 * n
    offsets, body = [], []
    for k in range(n if chunks is None else chunks):
        data = last if k == n - 1 else full
        offsets.append(pos)
        body.append(struct.pack("<ii", 16 * k, len(data)) + data)
        pos += 8 + len(data)
    offsets += [0] * (n - len(offsets))
    with open(path, "wb") as f:
        f.write(header + struct.pack(f"<{n}Q", *offsets))
        for b in body:
            f.write(b)
    return path


def _patch_data_window(path: Path, out: Path, box: tuple[int, int, int, int]) -> Path:
    data = bytearray(path.read_bytes())
    i = data.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
    data[i : i + 16] = struct.pack("<iiii", *box)
    out.write_bytes(bytes(data))
    return out


# ------------------------------------------------------------------------------------------ header probe


def test_image_info_exr_reads_the_header(tmp_path):
    a = _image(20, 30)
    p = write_exr(tmp_path / "h.exr", a, half=True, header={"envmap": OpenEXR.ENVMAP_LATLONG}, compression="piz")
    info = image_info(p)
    assert (info.kind, info.width, info.height, info.channels) == ("exr", 30, 20, ("B", "G", "R"))
    assert (info.pixel_type, info.bytes_per_channel, info.stored_bytes_per_pixel) == ("half", 2, 6)
    assert (info.envmap, info.compression, info.tiled, info.block_rows) == ("latlong", "piz", False, 32)
    assert info == exr_info(p)
    assert info.whole_read_bytes == 30 * 20 * (6 + 12)
    p = write_exr(tmp_path / "f.exr", a, header={"envmap": OpenEXR.ENVMAP_CUBE}, compression="none")
    info = image_info(p)
    assert (info.pixel_type, info.bytes_per_channel, info.envmap, info.compression) == ("float", 4, "cube", "none")
    # RGBA + depth: all channels listed, the colour channels give the type
    hdr = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    rgba = np.concatenate([a, np.ones((20, 30, 1), np.float32)], -1).astype(np.float16)
    OpenEXR.File(hdr, {"RGBA": rgba, "Z": np.ones((20, 30), np.float32)}).write(str(tmp_path / "z.exr"))
    info = image_info(tmp_path / "z.exr")
    assert info.channels == ("A", "B", "G", "R", "Z") and info.pixel_type == "half" and info.stored_bytes_per_pixel == 12
    assert info.envmap is None
    # a data window that does not start at 0
    box = (np.array([-5, 10], np.int32), np.array([24, 29], np.int32))
    OpenEXR.File({**hdr, "dataWindow": box}, {"RGB": a}).write(str(tmp_path / "dw.exr"))
    assert (image_info(tmp_path / "dw.exr").width, image_info(tmp_path / "dw.exr").height) == (30, 20)


def test_image_info_tiled_exr(tmp_path):
    td = OpenEXR.TileDescription()
    td.xSize, td.ySize, td.mode = 32, 8, OpenEXR.ONE_LEVEL
    a = _image(45, 70)
    OpenEXR.File({"type": OpenEXR.tiledimage, "tiles": td}, {"RGB": a}).write(str(tmp_path / "t.exr"))
    info = image_info(tmp_path / "t.exr")
    assert info.tiled and info.block_rows == 8 and (info.width, info.height) == (70, 45)
    assert np.array_equal(_gather(iter_strips(tmp_path / "t.exr", 10), 45, 70), a)


def test_image_info_hdr(tmp_path):
    a = _image(12, 40)
    info = image_info(write_hdr(tmp_path / "a.hdr", a))
    assert (info.kind, info.width, info.height, info.pixel_type, info.compression) == ("hdr", 40, 12, "rgbe", "rle")
    assert info == hdr_info(tmp_path / "a.hdr")
    assert image_info(write_hdr(tmp_path / "b.hdr", a, rle=False)).compression == "flat"


def test_image_info_of_the_issue_file_is_instant(tmp_path):
    p = write_constant_exr(tmp_path / "big.exr", 8192, 16384)
    assert p.stat().st_size < 1_000_000  # the 0.8 MB file of the issue
    t = time.perf_counter()
    info = image_info(p)
    assert time.perf_counter() - t < 0.5
    assert (info.width, info.height, info.pixel_type, info.compression) == (8192, 16384, "half", "zip")
    assert info.float32_bytes == 8192 * 16384 * 12


def test_not_an_image(tmp_path):
    p = tmp_path / "x.png"
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(20))
    with pytest.raises(HomofacError) as e:
        image_info(p)
    _one_line_error(e, "x.png", "not an OpenEXR or Radiance HDR")
    with pytest.raises(HomofacError) as e:
        image_info(tmp_path / "missing.exr")
    _one_line_error(e, "missing.exr", "no such file")


# ------------------------------------------------------------------------------------- absurd headers


@pytest.mark.parametrize(
    "box",
    [
        (0, 0, 131071, 65535),  # 8.6 G pixels: the patched header that tried 56 GiB
        (0, 0, -5, 10),  # negative width
        (10, 10, 9, 20),  # zero width
        (-(2**31), 0, 2**31 - 1, 0),  # 2^32 wide
    ],
)
def test_absurd_exr_size_is_a_one_line_error(tmp_path, box):
    good = write_exr(tmp_path / "good.exr", _image(16, 16))
    p = _patch_data_window(good, tmp_path / "patched.exr", box)
    for call in (image_info, read_exr, lambda q: read_exr(q, max_bytes=None), iter_strips,
                 lambda q: read_downsampled(q, 2)):
        t = time.perf_counter()
        with pytest.raises(HomofacError) as e:
            call(p)
        assert time.perf_counter() - t < 0.5
        _one_line_error(e, "patched.exr", "bad image size")


def test_patched_header_within_the_pixel_limit(tmp_path):
    """40000 x 40000 is not absurd: the cap refuses it with the estimate; without the cap the offset
    table (read where the header now says it is) points outside the file: refused before OpenEXR."""
    good = write_exr(tmp_path / "good.exr", _image(64, 64))
    p = _patch_data_window(good, tmp_path / "p.exr", (0, 0, 39999, 39999))
    with pytest.raises(HomofacError) as e:
        read_exr(p)
    _one_line_error(e, "p.exr", "40000 x 40000 pixels need", "GiB to read whole; limit 1.0 GiB")
    for call in (lambda q: read_exr(q, max_bytes=None), iter_strips):
        t = time.perf_counter()
        with pytest.raises(HomofacError) as e:
            call(p)
        assert time.perf_counter() - t < 0.5
        _one_line_error(e, "p.exr", "corrupt or truncated")


def test_corrupt_exr_headers(tmp_path):
    good = write_exr(tmp_path / "good.exr", _image(8, 8)).read_bytes()
    p = tmp_path / "c.exr"
    i = good.index(b"channels\0chlist\0") + len(b"channels\0chlist\0")
    p.write_bytes(good[:i] + struct.pack("<i", 10**8) + good[i + 4 :])  # attribute size beyond the file
    with pytest.raises(HomofacError) as e:
        image_info(p)
    _one_line_error(e, "c.exr", "beyond the end of the file")
    p.write_bytes(good[:4] + struct.pack("<I", 3) + good[8:])
    with pytest.raises(HomofacError) as e:
        read_exr(p)
    _one_line_error(e, "c.exr", "version")
    p.write_bytes(good[:60])
    with pytest.raises(HomofacError) as e:
        image_info(p)
    _one_line_error(e, "c.exr", "truncated")


@pytest.mark.parametrize(
    "res, needle",
    [(b"-Y 0 +X 16", "bad image size"), (b"-Y 100000 +X 100000", "bad image size"),
     (b"-Y 99999999999999999999999 +X 16", "bad image size")],
)
def test_absurd_hdr_size_is_a_one_line_error(tmp_path, res, needle):
    good = write_hdr(tmp_path / "g.hdr", _image(8, 16)).read_bytes()
    p = tmp_path / "bad.hdr"
    p.write_bytes(good.replace(b"-Y 8 +X 16", res))
    for call in (image_info, read_hdr, iter_strips):
        with pytest.raises(HomofacError) as e:
            call(p)
        _one_line_error(e, "bad.hdr", needle)


# ------------------------------------------------------------------------------------------ memory cap


def test_the_issue_file_is_refused_up_front_with_the_estimate(tmp_path):
    p = write_constant_exr(tmp_path / "x.exr", 8192, 16384)
    t = time.perf_counter()
    with pytest.raises(HomofacError) as e:
        read_exr(p)
    assert time.perf_counter() - t < 0.5  # before any pixel is decoded (it took 28 s and 8.1 GB)
    msg = _one_line_error(e, "x.exr: 8192 x 16384 pixels need 2.2 GiB to read whole; limit 1.0 GiB", "read_downsampled")
    assert DEFAULT_MAX_BYTES == 1 << 30 and "max_bytes" in msg


def test_max_bytes_is_the_callers(tmp_path):
    a = _image(32, 64)
    p = write_exr(tmp_path / "a.exr", a)
    need = image_info(p).whole_read_bytes
    with pytest.raises(HomofacError) as e:
        read_exr(p, max_bytes=need - 1)
    _one_line_error(e, "a.exr", "64 x 32 pixels need", "limit")
    assert np.array_equal(read_exr(p, max_bytes=need), a)
    assert np.array_equal(read_exr(p, max_bytes=None), a)
    q = write_hdr(tmp_path / "a.hdr", a)
    with pytest.raises(HomofacError) as e:
        read_hdr(q, max_bytes=1000)
    _one_line_error(e, "a.hdr", "64 x 32 pixels need", "limit 1000 B")
    assert read_hdr(q, max_bytes=None).shape == (32, 64, 3)


def test_declared_size_over_tiny_data_fails_fast_without_the_cap(tmp_path):
    """8192 x 16384 declared, ten chunks present: refused from the offset table, before any allocation."""
    p = write_constant_exr(tmp_path / "cut.exr", 8192, 16384, chunks=10)
    assert p.stat().st_size < 50_000
    for call in (lambda q: read_exr(q, max_bytes=None), lambda q: iter_strips(q, max_bytes=None),
                 lambda q: read_downsampled(q, 64, max_bytes=None)):
        t = time.perf_counter()
        with pytest.raises(HomofacError) as e:
            call(p)
        assert time.perf_counter() - t < 0.5
        _one_line_error(e, "cut.exr", "corrupt or truncated", "chunk 10 of 1024 lies outside the file")


# ------------------------------------------------------------------------------------------------ strips


@pytest.mark.parametrize("compression", ["none", "rle", "zips", "zip", "piz", "pxr24", "b44", "dwaa", "dwab"])
@pytest.mark.parametrize("half", [True, False])
def test_exr_strips_equal_the_whole_read(tmp_path, compression, half):
    a = _image(203, 77)
    p = write_exr(tmp_path / "a.exr", a, half=half, compression=compression)
    whole = read_exr(p)
    decoders = ["openexr"] + (["builtin"] if compression in BUILTIN_STRIP_COMPRESSIONS else [])
    for decoder in decoders:
        for rows in (1, 7, 16, 100, None):
            assert np.array_equal(_gather(iter_exr_strips(p, rows, decoder=decoder), 203, 77), whole), (decoder, rows)
    if compression not in BUILTIN_STRIP_COMPRESSIONS:
        with pytest.raises(HomofacError) as e:
            iter_exr_strips(p, decoder="builtin")
        _one_line_error(e, "a.exr", f"{compression.upper()} compression", "NONE, RLE, ZIPS, ZIP")


@pytest.mark.parametrize("decoder", ["openexr", "builtin"])
def test_exr_strips_channel_layouts(tmp_path, decoder):
    rng = np.random.default_rng(2)
    a = rng.random((37, 21, 3)).astype(np.float32)
    hdr = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    rgba = np.concatenate([a, np.full((37, 21, 1), 0.5, np.float32)], axis=-1)
    files = {
        "rgba": ({"RGBA": rgba}, a),
        "y": ({"Y": np.ascontiguousarray(a[..., 0])}, np.repeat(a[..., :1], 3, -1)),
        "extra": ({"RGB": a.astype(np.float16), "Z": np.ones((37, 21), np.float32)}, a.astype(np.float16).astype(np.float32)),
        "uint": ({"Y": (a[..., 0] * 1e6).astype(np.uint32)}, np.repeat((a[..., :1] * 1e6).astype(np.uint32), 3, -1).astype(np.float32)),
        "decreasing": ({"RGB": a}, a),
    }
    for name, (channels, expect) in files.items():
        order = {"lineOrder": OpenEXR.DECREASING_Y} if name == "decreasing" else {}
        OpenEXR.File({**hdr, **order}, channels).write(str(tmp_path / f"{name}.exr"))
        got = _gather(iter_exr_strips(tmp_path / f"{name}.exr", 5, decoder=decoder), 37, 21)
        assert np.array_equal(got, expect), name
        assert np.array_equal(got, read_exr(tmp_path / f"{name}.exr")), name
    OpenEXR.File(hdr, {"Z": np.ones((3, 4), np.float32)}).write(str(tmp_path / "depth.exr"))
    with pytest.raises(HomofacError) as e:
        iter_exr_strips(tmp_path / "depth.exr", decoder=decoder)
    _one_line_error(e, "depth.exr", "no RGB")


def test_builtin_decoder_refuses_corrupt_chunks(tmp_path):
    p = write_exr(tmp_path / "a.exr", _image(64, 40), compression="zip")
    data = bytearray(p.read_bytes())
    info = exr_mod._parse_header(p)
    (first,) = struct.unpack_from("<Q", data, info.end)
    bad = tmp_path / "bad.exr"
    d = data.copy()
    d[first + 8 : first + 40] = bytes(32)  # garbage zlib stream
    bad.write_bytes(bytes(d))
    with pytest.raises(HomofacError) as e:
        list(iter_exr_strips(bad, decoder="builtin"))
    _one_line_error(e, "bad.exr", "chunk 0")
    d = data.copy()
    struct.pack_into("<i", d, first, 5)  # the chunk says it holds line 5
    bad.write_bytes(bytes(d))
    with pytest.raises(HomofacError) as e:
        list(iter_exr_strips(bad, decoder="builtin"))
    _one_line_error(e, "bad.exr", "chunk 0 is for line 5")
    d = data.copy()
    struct.pack_into("<i", d, first + 4, 10**7)  # a chunk size bigger than its decoded lines
    bad.write_bytes(bytes(d))
    with pytest.raises(HomofacError) as e:
        list(iter_exr_strips(bad, decoder="builtin"))
    _one_line_error(e, "bad.exr", "bad size")


def test_auto_without_openexr_scanline_reader(tmp_path, monkeypatch):
    """If a future OpenEXR drops the deprecated InputFile: builtin for ZIP, whole read below the cap, else refused."""
    a = _image(48, 32)
    zp = write_exr(tmp_path / "z.exr", a, compression="zip")
    pz = write_exr(tmp_path / "p.exr", a, compression="piz")
    monkeypatch.delattr(OpenEXR, "InputFile")
    assert np.array_equal(_gather(iter_exr_strips(zp, 8), 48, 32), a)
    assert np.array_equal(_gather(iter_exr_strips(pz, 8), 48, 32), a)
    assert np.array_equal(read_downsampled(pz, 4), box_downsample(a, 4))
    with pytest.raises(HomofacError) as e:
        iter_exr_strips(pz, 8, max_bytes=image_info(pz).whole_read_bytes - 1)
    _one_line_error(e, "p.exr", "PIZ compression", "too big to read whole")


def test_hdr_strips_equal_the_whole_read(tmp_path):
    a = _image(45, 80)
    for rle in (True, False):
        p = write_hdr(tmp_path / f"a{rle}.hdr", a, rle=rle)
        whole = read_hdr(p)
        for rows in (1, 4, 45, 100, None):
            assert np.array_equal(_gather(iter_hdr_strips(p, rows), 45, 80), whole), (rle, rows)
        # +Y: bottom row first in the file; strips come bottom to top, each placed by y0
        q = tmp_path / "flip.hdr"
        q.write_bytes(p.read_bytes().replace(b"-Y 45 +X 80", b"+Y 45 +X 80"))
        flipped = read_hdr(q)
        assert np.array_equal(flipped, whole[::-1])
        y0s = [y0 for y0, _ in iter_strips(q, 10)]
        assert y0s == [35, 25, 15, 5, 0]
        assert np.array_equal(_gather(iter_strips(q, 10), 45, 80), flipped)
        assert np.allclose(read_downsampled(q, 5), box_downsample(flipped, 5), rtol=1e-6, atol=0)


def test_hdr_truncated_in_strips(tmp_path):
    good = write_hdr(tmp_path / "g.hdr", _image(30, 64)).read_bytes()
    p = tmp_path / "cut.hdr"
    p.write_bytes(good[: len(good) // 2])
    strips = iter_strips(p, 4)  # the header is fine: the error comes with the missing rows
    with pytest.raises(HomofacError) as e:
        list(strips)
    _one_line_error(e, "cut.hdr", "truncated")


def test_rgbe_decode_is_exact_for_every_code():
    m, e = np.meshgrid(np.arange(256), np.arange(256))
    rgbe = np.stack([m, 255 - m, (m * 7) % 256, e], -1).astype(np.uint8)
    ref = (rgbe[..., :3].astype(np.float64) + 0.5) * np.where(e > 0, np.ldexp(1.0, e - 136), 0.0)[..., None]
    got = rgbe_to_float(rgbe)
    assert got.dtype == np.float32 and np.array_equal(got, ref.astype(np.float32))


def test_read_downsampled_equals_box_average_of_whole_read(tmp_path):
    a = _image(96, 160)
    for p in (write_exr(tmp_path / "a.exr", a, half=True), write_hdr(tmp_path / "a.hdr", a)):
        whole = read_exr(p) if p.suffix == ".exr" else read_hdr(p)
        for f, rows in ((1, None), (2, None), (4, 4), (8, 24), (16, None), (32, 32)):
            got = read_downsampled(p, f, rows=rows)
            assert got.shape == (96 // f, 160 // f, 3) and got.dtype == np.float32
            assert np.allclose(got, box_downsample(whole, f), rtol=1e-6, atol=0), (p, f)
    ref = a.reshape(12, 8, 20, 8, 3).astype(np.float64).mean(axis=(1, 3))
    assert np.allclose(box_downsample(a, 8), ref, rtol=1e-6, atol=0)


def test_read_downsampled_refuses_bad_factors(tmp_path):
    p = write_exr(tmp_path / "a.exr", _image(30, 40))
    for f in (0, -2, 7, 2.5):
        with pytest.raises(HomofacError) as e:
            read_downsampled(p, f)
        _one_line_error(e, "a.exr", "factor")
    with pytest.raises(HomofacError) as e:
        read_downsampled(p, 2, rows=3)
    _one_line_error(e, "a.exr", "multiple of the factor 2")
    with pytest.raises(HomofacError) as e:
        list(iter_strips(p, 4, max_bytes=100))
    _one_line_error(e, "a.exr", "strips of 4 rows of 40 pixels need")


def test_strip_rows_follow_blocks_and_factor(tmp_path):
    p = write_exr(tmp_path / "a.exr", _image(100, 8), compression="piz")
    info = image_info(p)
    assert strip_rows(info) == 128  # whole image, rounded up to the 32-line PIZ blocks
    assert strip_rows(info, 3) % 3 == 0
    big = write_constant_exr(tmp_path / "big.exr", 16384, 64)
    n = strip_rows(image_info(big), 8)
    assert n % 16 == 0 and n * 16384 * 12 <= 8 << 20


def test_big_half_zip_downsampled_in_strips(tmp_path):
    """4096 x 2048 half ZIP: strips + 8 x 8 box average equal the whole read followed by the same average."""
    y = np.linspace(0.0, 1.0, 2048, dtype=np.float32)[:, None]
    x = np.linspace(0.0, 1.0, 4096, dtype=np.float32)[None, :]
    a = np.empty((2048, 4096, 3), np.float16)
    a[..., 0], a[..., 1], a[..., 2] = np.sin(20 * x) * y + 1, x * y * 5, np.cos(7 * y + x) + 1.5
    p = write_exr(tmp_path / "big.exr", a, half=True)
    del a
    ref = box_downsample(read_exr(p), 8)
    for decoder in ("openexr", "builtin"):
        out = np.empty_like(ref)
        for y0, s in iter_exr_strips(p, 64, decoder=decoder):
            out[y0 // 8 : (y0 + s.shape[0]) // 8] = box_downsample(s, 8)
        assert np.allclose(out, ref, rtol=1e-6, atol=0), decoder
    assert np.allclose(read_downsampled(p, 8), ref, rtol=1e-6, atol=0)


# ------------------------------------------------------------------------------ peak memory (subprocess)

# Runs homofac.io without homofac/__init__ (which imports jax), so the peak RSS is the reader's own;
# that it works also shows homofac.io imports nothing above it.
_PEAK = r"""
import json, sys, time, types

def hwm_mib():  # peak RSS of this process image (VmHWM is reset by exec; ru_maxrss keeps the parent's)
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024

src = sys.argv[1]
for name, d in (("homofac", src), ("homofac.io", src + "/io")):
    m = types.ModuleType(name); m.__path__ = [d]; sys.modules[name] = m
from homofac.io.limits import box_downsample, read_downsampled
from homofac.io.exr import read_exr
from homofac.io.hdr import read_hdr
path, mode, f = sys.argv[2], sys.argv[3], int(sys.argv[4])
base = hwm_mib()
t = time.perf_counter()
if mode == "whole":
    r = box_downsample((read_hdr if path.endswith(".hdr") else read_exr)(path, max_bytes=None), f)
else:
    r = read_downsampled(path, f)
print(json.dumps({"base_mib": base, "peak_mib": hwm_mib(),
                  "seconds": time.perf_counter() - t, "shape": r.shape, "mean": float(r.mean())}))
"""


def _peak(path: Path, mode: str, factor: int) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", _PEAK, str(SRC), str(path), mode, str(factor)], capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout)


def _gradient_exr(path: Path, w: int, h: int) -> Path:
    a = np.empty((h, w, 3), np.float16)
    rows = np.linspace(0.0, 1.0, h, dtype=np.float32)[:, None]
    cols = np.linspace(0.0, 1.0, w, dtype=np.float32)[None, :]
    a[..., 0], a[..., 1], a[..., 2] = rows + cols, rows * cols, 2.0 - rows
    return write_exr(path, a, half=True)


def _flat_hdr(path: Path, w: int, h: int) -> Path:
    """A flat (not RLE) RGBE file written row by row: a horizontal gradient, brighter down the image."""
    row = np.zeros((w, 4), np.uint8)
    row[:, 0] = np.linspace(0, 255, w).astype(np.uint8)
    row[:, 1], row[:, 2] = 128, 255 - row[:, 0]
    with open(path, "wb") as f:
        f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {h} +X {w}\n".encode())
        for y in range(h):
            row[:, 3] = 128 + 4 * y // h
            f.write(row.tobytes())
    return path


@pytest.mark.slow  # compile- or subprocess-heavy: with the slow set, to keep the fast suite under 5 min
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")
def test_peak_memory_strips_vs_whole(tmp_path):
    p = _gradient_exr(tmp_path / "m.exr", 4096, 2048)  # float32 whole: 96 MiB; with the half read: 144 MiB
    whole, strips = _peak(p, "whole", 8), _peak(p, "strips", 8)
    print("\n4096x2048 half ZIP EXR: whole", whole, "\n                        strips", strips)
    assert whole["peak_mib"] - whole["base_mib"] > 120
    assert strips["peak_mib"] - strips["base_mib"] < 60
    assert abs(whole["mean"] - strips["mean"]) < 1e-5
    q = _flat_hdr(tmp_path / "m.hdr", 4096, 2048)  # float32 whole: 96 MiB
    whole, strips = _peak(q, "whole", 8), _peak(q, "strips", 8)
    print("4096x2048 flat HDR:     whole", whole, "\n                        strips", strips)
    assert whole["peak_mib"] - whole["base_mib"] > 90
    assert strips["peak_mib"] - strips["base_mib"] < 60
    assert abs(whole["mean"] - strips["mean"]) < 1e-5 * whole["mean"]


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")
def test_peak_memory_8192x4096(tmp_path):
    """The measurement of the issue's size class: whole read about 0.6 GiB, strips under 100 MiB."""
    p = _gradient_exr(tmp_path / "m.exr", 8192, 4096)
    whole, strips = _peak(p, "whole", 8), _peak(p, "strips", 8)
    print("\n8192x4096 half ZIP EXR: whole", whole, "\n                        strips", strips)
    assert whole["peak_mib"] - whole["base_mib"] > 500
    assert strips["peak_mib"] - strips["base_mib"] < 100


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")
def test_the_issue_file_reads_downsampled_in_bounded_memory(tmp_path):
    """8192 x 16384 half (2.2 GiB to read whole) from 0.8 MB: 64 x 64 box average in strips, < 100 MiB."""
    p = write_constant_exr(tmp_path / "x.exr", 8192, 16384, 0.5)
    r = _peak(p, "strips", 64)
    assert r["shape"] == [256, 128, 3] and r["mean"] == 0.5
    assert r["peak_mib"] - r["base_mib"] < 100


# --------------------------------------------------------------------------------------------- layering


def test_io_modules_import_only_errors_and_io_at_top():
    for name in ("exr.py", "hdr.py", "files.py", "limits.py"):
        tree = ast.parse((SRC / "io" / name).read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.level:
                assert node.level == 1 or node.module == "errors", (name, node.module)
            elif isinstance(node, ast.ImportFrom):
                assert not (node.module or "").startswith("homofac"), (name, node.module)
        top = set(tree.body)
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)) and node not in top:
                mods = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module]
                assert set(mods) <= {"OpenEXR", "Imath", "PIL"}, (name, mods)


def test_max_pixels_is_two_to_the_31():
    assert MAX_PIXELS == 2**31
