"""Every input the CLI accepts, malformed: one line naming the problem, exit code 2, no traceback
(without --debug), nothing written; previous results survive failed runs byte for byte."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from homofac import brdf as B
from homofac.app.cli import fit_main as main
from homofac.app.cli import run_one_line
from homofac.io.exr import write_exr
from homofac.io.hdr import write_hdr
from homofac import light as E
from homofac.light.cubemap import FACE_NAMES

LIGHTING = {
    "target": {"kind": "lighting", "brdf": {"model": "cook_torrance", "kd": 0.05, "ks": 1.0, "roughness": 0.3},
               "environment": {"file": "env.exr", "resolution": 4}},
    "parametrization": "NR", "mapper": "cube", "texture_size": 6,
    "sampling": {"kind": "texels", "size": 6, "validation": 200},
    "output": {"dir": "out", "preview": False},
}
BRDF = {
    "target": {"kind": "brdf", "brdf": {"model": "merl", "file": "m.binary"}},
    "parametrization": "PQP", "mapper": "parabolic", "texture_size": 6,
    "sampling": {"kind": "texels", "size": 6, "validation": 200},
    "output": {"dir": "out", "preview": False},
}


def _latlong(h=8):
    y = np.linspace(1, 2, h)[:, None, None]
    return np.broadcast_to(y, (h, 2 * h, 3)).astype(np.float32).copy()


def _exr_truncated(d: Path):
    write_exr(d / "full.exr", _latlong())
    data = (d / "full.exr").read_bytes()
    (d / "env.exr").write_bytes(data[: len(data) // 2])
    (d / "full.exr").unlink()


def _exr_text(d: Path):
    (d / "env.exr").write_text("this is not an image\n")


def _exr_aspect(d: Path):
    write_exr(d / "env.exr", np.ones((8, 24, 3), np.float32))


def _exr_all_zero(d: Path):
    write_exr(d / "env.exr", np.zeros((8, 16, 3), np.float32))


def _exr_all_nan(d: Path):
    write_exr(d / "env.exr", np.full((8, 16, 3), np.nan, np.float32))


def _hdr_bad_header(d: Path):
    (d / "env.exr").unlink(missing_ok=True)
    (d / "env.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 8 +X\n" + bytes(20))


def _hdr_truncated(d: Path):
    write_hdr(d / "full.hdr", _latlong())
    data = (d / "full.hdr").read_bytes()
    (d / "env.hdr").write_bytes(data[: len(data) - 100])
    (d / "full.hdr").unlink()


def _cube_unequal(d: Path):
    (d / "cube").mkdir()
    for n in FACE_NAMES:
        s = 8 if n != "nz" else 6
        write_exr(d / "cube" / f"{n}.exr", np.ones((s, s, 3), np.float32))


def _cube_missing_face(d: Path):
    (d / "cube").mkdir()
    for n in FACE_NAMES[:5]:
        write_exr(d / "cube" / f"{n}.exr", np.ones((8, 8, 3), np.float32))


def _merl_truncated(d: Path):
    B.save_merl(d / "full.binary", B.tabulate_merl(B.lambert(kd=0.5), dims=(90, 90, 180)))
    data = (d / "full.binary").read_bytes()
    (d / "m.binary").write_bytes(data[:1000])


def _merl_bad_dims(d: Path):
    (d / "m.binary").write_bytes(np.array([-5, 90, 180], np.int32).tobytes() + bytes(64))


def _merl_nan(d: Path):
    B.save_merl(d / "ok.binary", B.tabulate_merl(B.lambert(kd=0.5), dims=(90, 90, 180)))
    data = bytearray((d / "ok.binary").read_bytes())
    data[12 + 8 * 1000 : 12 + 8 * 1010] = np.full(10, np.nan).tobytes()  # 3 int32 dims, then doubles
    (d / "m.binary").write_bytes(bytes(data))
    (d / "ok.binary").unlink()


CASES = [  # (name, config, file maker, config edits, needle)
    ("exr truncated", LIGHTING, _exr_truncated, {}, "env.exr"),
    ("exr is text", LIGHTING, _exr_text, {}, "env.exr"),
    ("exr aspect 3:1", LIGHTING, _exr_aspect, {}, "2:1"),
    ("exr all zero", LIGHTING, _exr_all_zero, {}, "zero"),
    ("exr all NaN", LIGHTING, _exr_all_nan, {}, "env.exr"),
    ("hdr bad header", LIGHTING, _hdr_bad_header, {"file": "env.hdr"}, "env.hdr"),
    ("hdr truncated", LIGHTING, _hdr_truncated, {"file": "env.hdr"}, "env.hdr"),
    ("cube unequal faces", LIGHTING, _cube_unequal, {"file": "cube"}, "equal size"),
    ("cube missing face", LIGHTING, _cube_missing_face, {"file": "cube"}, "cube"),
    ("env missing", LIGHTING, lambda d: None, {"file": "nowhere.exr"}, "nowhere.exr"),
    ("merl truncated", BRDF, _merl_truncated, {}, "m.binary"),
    ("merl bad dims", BRDF, _merl_bad_dims, {}, "m.binary"),
    ("merl NaN", BRDF, _merl_nan, {}, "m.binary"),
]


def _config(tmp_path: Path, base: dict, edits: dict) -> Path:
    cfg = json.loads(json.dumps(base))
    if edits:
        cfg["target"]["environment"].update(edits)
    p = tmp_path / "c.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return p


def _one_line(capsys, needle: str) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("homofac: warning")]
    assert len(lines) == 1 and lines[0].startswith("homofac: error:"), err
    assert "Traceback" not in err
    assert needle in lines[0], lines[0]
    return lines[0]


@pytest.mark.parametrize("name,base,make,edits,needle", CASES, ids=[c[0] for c in CASES])
def test_malformed_input_is_one_line_and_writes_nothing(tmp_path, capsys, name, base, make, edits, needle):
    make(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    cfg = _config(tmp_path, base, edits)
    assert main([str(cfg)]) == 2
    _one_line(capsys, needle)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(before + ["c.yaml"])  # no out/, no temp dirs


@pytest.mark.slow
def test_nan_pixels_are_cleaned_with_a_counted_warning(tmp_path, capsys):
    """The documented choice for NaN/Inf pixels: set to 0, counted in a warning and in factorization.json."""
    img = _latlong()
    img[0, :3] = np.nan
    img[1, 0] = np.inf
    write_exr(tmp_path / "env.exr", img)
    cfg = _config(tmp_path, LIGHTING, {})
    assert main([str(cfg), "--quiet"]) == 0
    err = [ln for ln in capsys.readouterr().err.splitlines() if "non-finite" in ln]
    assert len(err) == 1 and err[0].startswith("homofac: warning:") and "4 non-finite" in err[0], err
    doc = json.loads((tmp_path / "out" / "factorization.json").read_text())
    assert doc["target"]["environment"]["nonfinite"] == 4


def test_a_nan_environment_warns_in_one_line(tmp_path, capsys):
    """The count of NaN/Inf pixels was a two-line Python RuntimeWarning (``file:line: RuntimeWarning: ...`` and
    the source line); at the CLI every warning is one ``homofac: warning:`` line."""
    img = _latlong()
    img[0, :3] = np.nan
    write_exr(tmp_path / "env.exr", img)
    assert run_one_line(lambda: E.load_environment(tmp_path / "env.exr", resolution=4) and 0, False) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("homofac: warning:") and "3 non-finite" in err[0], err


@pytest.mark.slow
def test_one_huge_environment_pixel_keeps_the_metrics_finite(tmp_path, capsys):
    """One pixel of 1e30 made every rms and nrmse null in factorization.json (float32 squares overflowed)."""
    img = _latlong()
    img[2, 3] = 1e30
    write_exr(tmp_path / "env.exr", img)
    assert main([str(_config(tmp_path, LIGHTING, {})), "--quiet"]) == 0
    doc = json.loads((tmp_path / "out" / "factorization.json").read_text())
    for split in doc["metrics"].values():
        for m in split.values():
            assert all(v is not None and np.isfinite(v) for v in m.values()), m


@pytest.mark.slow
def test_failed_rerun_keeps_the_previous_result_byte_for_byte(tmp_path, capsys):
    write_exr(tmp_path / "env.exr", _latlong())
    cfg = _config(tmp_path, LIGHTING, {})
    assert main([str(cfg), "--quiet"]) == 0
    out = tmp_path / "out"
    snapshot = {p.name: p.read_bytes() for p in out.iterdir()}
    _exr_truncated(tmp_path)  # the environment breaks; the same config runs again into the same directory
    assert main([str(cfg)]) == 2
    _one_line(capsys, "env.exr")
    assert {p.name: p.read_bytes() for p in out.iterdir()} == snapshot
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.yaml", "env.exr", "out"]


def test_output_directory_cases(tmp_path, capsys):
    write_exr(tmp_path / "env.exr", _latlong())
    cfg = _config(tmp_path, LIGHTING, {})
    foreign = tmp_path / "photos"
    foreign.mkdir()
    (foreign / "a.jpg").write_bytes(b"\xff\xd8 precious")
    assert main([str(cfg), "--out", str(foreign)]) == 2
    _one_line(capsys, "not written by homofac")
    assert (foreign / "a.jpg").read_bytes() == b"\xff\xd8 precious"
    # a directory that only looks like homofac's (factorization.json of another program) is foreign too
    fake = tmp_path / "fake"
    fake.mkdir()
    (fake / "factorization.json").write_text('{"format": "something-else"}')
    assert main([str(cfg), "--out", str(fake)]) == 2
    _one_line(capsys, "not written by homofac")
    assert (fake / "factorization.json").read_text() == '{"format": "something-else"}'
    # parent is a file
    (tmp_path / "plain").write_text("x")
    assert main([str(cfg), "--out", str(tmp_path / "plain" / "out")]) == 2
    _one_line(capsys, "plain")
