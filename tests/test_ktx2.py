"""KTX2 writer and reader (homofac.io.ktx2): round trips, and the independent reader ktx-parse under node."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
import yaml

import homofac as hf
from helpers import smooth_texture, two_terms
from homofac.app import config as cfgmod
from homofac.app.cli import fit_main
from homofac.errors import HomofacError
from homofac.factorization import Factor, Factorization, Term, Texture
from homofac.fit.result import Result
from homofac.io.exr import read_exr
from homofac.io.ktx2 import decode_ktx2, encode_ktx2, mip_chain, read_ktx2, write_ktx2

JS = Path(__file__).resolve().parents[1] / "js"


def _levels(kind: str, n: int, channels: int, rng) -> list[np.ndarray]:
    """A random mip chain of ``kind`` (level-0 sizes chosen so that the dimensions differ)."""
    out = []
    for i in range(n):
        w, h = max(1, 8 >> i), max(1, 4 >> i)
        shape = {"2d": (h, w), "array": (3, h, w), "3d": (max(1, 2 >> i), h, w), "cube": (6, w, w)}[kind]
        out.append(rng.uniform(-4, 4, size=shape + (channels,)).astype(np.float32))
    return out


VARIANTS = [(k, f) for k in ("2d", "array", "3d", "cube") for f in ("half", "float")]


@pytest.mark.parametrize("kind,fmt", VARIANTS)
def test_round_trip(tmp_path, kind, fmt):
    """Every kind and format reads back with its shapes, levels, keys; float exactly, half to its rounding."""
    rng = np.random.default_rng(1)
    lv = _levels(kind, 3, 3, rng)
    p = write_ktx2(tmp_path / "t.ktx2", lv, kind, fmt, {"homofac": '{"mapper": "cube"}'})
    im = read_ktx2(p)
    assert (im.kind, im.format, len(im.levels)) == (kind, fmt, 3)
    for a, b in zip(lv, im.levels):
        assert b.shape == a.shape[:-1] + (4,)
        want = a.astype(np.float16).astype(np.float32) if fmt == "half" else a
        np.testing.assert_array_equal(b[..., :3], want)
        np.testing.assert_array_equal(b[..., 3], 1.0)
    assert im.text("KTXorientation") == ("rdi" if kind == "3d" else "rd")
    assert im.text("KTXwriter").startswith("homofac ")
    assert json.loads(im.text("homofac")) == {"mapper": "cube"}


def test_layout_alignment_and_rgba():
    """Levels are stored smallest first, aligned to lcm(texel bytes, 4); RGBA input keeps its alpha."""
    rng = np.random.default_rng(2)
    lv = _levels("2d", 4, 4, rng)
    data = encode_ktx2(lv, "2d", "float")
    offsets = [int.from_bytes(data[80 + 24 * i:88 + 24 * i], "little") for i in range(4)]
    assert offsets == sorted(offsets, reverse=True)
    assert all(o % 16 == 0 for o in offsets)
    np.testing.assert_array_equal(decode_ktx2(data).levels[2], lv[2])


def test_refusals(tmp_path):
    """Bad shapes, out-of-range halves, foreign files and truncation: one-line errors, nothing written."""
    with pytest.raises(HomofacError, match="cube level"):
        write_ktx2(tmp_path / "c.ktx2", np.zeros((6, 4, 2, 3)), "cube")
    with pytest.raises(HomofacError, match="level 1 must be shaped"):
        write_ktx2(tmp_path / "m.ktx2", [np.zeros((4, 4, 3)), np.zeros((4, 4, 3))], "2d")
    with pytest.raises(HomofacError, match="half-float range"):
        write_ktx2(tmp_path / "h.ktx2", np.full((2, 2, 3), 1e6), "2d", "half")
    assert not list(tmp_path.iterdir())
    with pytest.raises(HomofacError, match="not a KTX2"):
        decode_ktx2(b"\x89PNG" + b"\0" * 100)
    data = encode_ktx2(np.ones((4, 4, 3)), "2d", "half")
    with pytest.raises(HomofacError, match="level 0"):
        decode_ktx2(data[:-8])


@pytest.fixture(scope="module")
def ktx_parse():
    """node with js/'s ktx-parse installed (``npm ci`` when the Makefile's set-up has not run it)."""
    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not installed")
    if not (JS / "node_modules" / "ktx-parse").is_dir():
        subprocess.run(["npm", "ci", "--no-audit", "--no-fund"], cwd=JS, check=True, capture_output=True, timeout=300)
    return node


def test_ktx_parse_reads_every_variant(tmp_path, ktx_parse):
    """ktx-parse (npm) sees the same format, dimensions, levels, DFD and key/value data for every variant."""
    rng = np.random.default_rng(3)
    files = {}
    for kind, fmt in VARIANTS:
        lv = _levels(kind, 3, 3, rng)
        files[(kind, fmt)] = (write_ktx2(tmp_path / f"{kind}_{fmt}.ktx2", lv, kind, fmt,
                                         {"homofac": json.dumps({"kind": kind})}), lv)
    out = subprocess.run([ktx_parse, str(JS / "ktx2-info.mjs"), *[str(p) for p, _ in files.values()]],
                         check=True, capture_output=True, text=True, timeout=60)
    infos = json.loads(out.stdout)
    for ((kind, fmt), (p, lv)), info in zip(files.items(), infos):
        cb = 2 if fmt == "half" else 4
        a0 = lv[0]
        assert info["vkFormat"] == (97 if fmt == "half" else 109) and info["typeSize"] == cb
        assert info["supercompressionScheme"] == 0
        assert info["pixelWidth"] == a0.shape[-2]
        assert info["pixelHeight"] == a0.shape[-3]
        assert info["pixelDepth"] == (a0.shape[0] if kind == "3d" else 0)
        assert info["layerCount"] == (a0.shape[0] if kind == "array" else 0)
        assert info["faceCount"] == (6 if kind == "cube" else 1)
        assert info["levelCount"] == len(lv)
        assert info["levelBytes"] == [int(np.prod(a.shape[:-1])) * 4 * cb for a in lv]
        dfd = info["dfd"]
        assert (dfd["colorModel"], dfd["colorPrimaries"], dfd["transferFunction"]) == (1, 1, 1)
        assert dfd["bytesPlane"][0] == 4 * cb
        assert [s["channelType"] for s in dfd["samples"]] == [0xC0, 0xC1, 0xC2, 0xCF]
        assert [s["bitLength"] for s in dfd["samples"]] == [8 * cb - 1] * 4
        kv = info["keyValue"]
        assert kv["KTXorientation"] == ("rdi" if kind == "3d" else "rd")
        assert kv["KTXwriter"].startswith("homofac ")
        assert json.loads(kv["homofac"]) == {"kind": kind}


def _cube_result():
    """A one-term factorization on a cube texture (made-up smooth values)."""
    tex = Texture("C", "cube", 4, jnp.asarray(smooth_texture("cube", 4, 5)))
    return Result(Factorization("lighting", "lighting", (tex,), (Term((Factor("r", "C"),), jnp.ones(3)),), {}, "cube1"))


def test_factorization_output_writes_ktx2(tmp_path):
    """``ktx2=True``: every texture also as <name>.ktx2 (half), listed in factorization.json, equal to the EXR
    texels (cube maps as KTX2 cubes, face for face); the directory still loads; without it, no KTX2."""
    for fac, kinds in ((Result(two_terms()), ["2d", "2d", "2d"]), (_cube_result(), ["cube"])):
        out = fac.save(tmp_path / fac.model.name, ktx2=True)
        doc = json.loads((out / "factorization.json").read_text())
        for t, kind in zip(doc["textures"], kinds):
            assert t["ktx2"] == f"{t['name']}.ktx2" and t["ktx2_format"] == "half"
            im = read_ktx2(out / t["ktx2"])
            assert (im.kind, im.format, len(im.levels)) == (kind, "half", 1)
            exr = read_exr(out / t["file"])
            data = im.levels[0][..., :3]
            if kind == "cube":
                data = np.concatenate(list(data), axis=1)  # faces side by side: the pinned (S, 6S) layout
            np.testing.assert_allclose(data, exr.astype(np.float16).astype(np.float32), rtol=0, atol=0)
            layout = json.loads(im.text("homofac"))
            assert layout["mapper"] == t["mapper"] and layout["texture"] == t["name"]
            assert layout["uses"] == t["uses"] and layout["frame"] == "+z up"
        assert hf.load(out).model.name == fac.model.name
    plain = Result(two_terms()).save(tmp_path / "plain")
    assert not list(plain.glob("*.ktx2"))
    assert "ktx2" not in json.loads((plain / "factorization.json").read_text())["textures"][0]


def _small_config(tmp_path, **output) -> Path:
    cfg = {"target": {"kind": "brdf", "brdf": {"model": "cook_torrance", "kd": 0.1, "ks": 1.0, "roughness": 0.3,
                                                 "f0": [1.0, 0.78, 0.34]}},
           "parametrization": "PQP", "mapper": "parabolic", "texture_size": 8,
           "sampling": {"kind": "texels", "size": 8, "validation": 200, "seed": 0},
           "solver": {"method": "lsmr", "tolerance": 1e-4, "max_iterations": 100},
           "output": {"dir": "out", "samples": False, "preview": False, **output}}
    p = tmp_path / "c.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return p


def test_ktx2_option_in_config_and_cli(tmp_path, capsys):
    """``output: {ktx2: true}`` is a config key, and ``--ktx2`` sets it (the resolved config says so)."""
    assert cfgmod.load(_small_config(tmp_path, ktx2=True))[0].output.ktx2 is True
    assert fit_main([str(_small_config(tmp_path)), "--ktx2", "--print-config"]) == 0
    assert "ktx2: true" in capsys.readouterr().out
    assert fit_main([str(_small_config(tmp_path)), "--print-config"]) == 0
    assert "ktx2: false" in capsys.readouterr().out


@pytest.mark.slow
def test_fit_cli_ktx2(tmp_path):
    """A fit run with ``--ktx2`` writes its textures as KTX2 beside the EXR files."""
    assert fit_main([str(_small_config(tmp_path)), "--quiet", "--ktx2", "--out", str(tmp_path / "a")]) == 0
    doc = json.loads((tmp_path / "a" / "factorization.json").read_text())
    assert [read_ktx2(tmp_path / "a" / t["ktx2"]).kind for t in doc["textures"]] == ["2d", "2d"]


@pytest.mark.parametrize("kind", ["2d", "array", "3d", "cube"])
def test_mip_chain_is_box_averages(kind):
    """Each level is the average of the 2 x 2 (x 2 for 3D) block below it (one axis of size 1 stays); array
    layers and cube faces stay apart; the chain ends at 1 texel; it round-trips through the container."""
    rng = np.random.default_rng(5)
    shape = {"2d": (8, 16), "array": (3, 8, 16), "3d": (4, 8, 16), "cube": (6, 8, 8)}[kind]
    a = rng.uniform(0, 1, shape + (3,)).astype(np.float32)
    chain = mip_chain(a, kind)
    assert len(chain) == (4 if kind == "cube" else 5)
    axes = {"2d": (0, 1), "array": (1, 2), "3d": (0, 1, 2), "cube": (1, 2)}[kind]
    for hi, lo in zip(chain, chain[1:]):
        want = hi
        for ax in axes:
            if want.shape[ax] > 1:
                even = np.take(want, np.arange(0, want.shape[ax], 2), axis=ax)
                odd = np.take(want, np.arange(1, want.shape[ax], 2), axis=ax)
                want = (even + odd) / 2
        np.testing.assert_allclose(lo, want, rtol=1e-6)
    assert all(chain[-1].shape[ax] == 1 for ax in axes)
    if kind in ("array", "cube"):
        assert chain[-1].shape[0] == a.shape[0]  # layers and faces are kept
    im = decode_ktx2(encode_ktx2(chain, kind, "float"))
    for x, y in zip(im.levels, chain):
        np.testing.assert_array_equal(x[..., :3], y)


def test_layout_key_and_mips_read_by_ktx_parse(tmp_path, ktx_parse):
    """``write_ktx2(..., mips=None, layout={...})``: a 2D array and a 3D texture with their full mip chains, read
    back by ktx-parse with the level count and the layout key naming kind, format and levels."""
    rng = np.random.default_rng(6)
    arr = rng.uniform(0, 2, (5, 16, 32, 3)).astype(np.float32)
    vol = rng.uniform(0, 2, (8, 16, 16, 4)).astype(np.float32)
    pa = write_ktx2(tmp_path / "a.ktx2", arr, "array", "half", mips=None, layout={"texture": "P0", "layer": "roughness j"})
    pv = write_ktx2(tmp_path / "v.ktx2", vol, "3d", "float", mips=3, layout={"texture": "P0", "depth": "roughness"})
    out = subprocess.run([ktx_parse, str(JS / "ktx2-info.mjs"), str(pa), str(pv)], check=True, capture_output=True,
                         text=True, timeout=60)
    a, v = json.loads(out.stdout)
    assert (a["layerCount"], a["pixelDepth"], a["levelCount"]) == (5, 0, 6)
    assert a["levelBytes"] == [5 * max(1, 16 >> i) * max(1, 32 >> i) * 4 * 2 for i in range(6)]
    assert (v["layerCount"], v["pixelDepth"], v["levelCount"]) == (0, 8, 3)
    assert v["levelBytes"] == [(8 >> i) * (16 >> i) * (16 >> i) * 4 * 4 for i in range(3)]
    la, lv = json.loads(a["keyValue"]["homofac"]), json.loads(v["keyValue"]["homofac"])
    assert la == {"texture": "P0", "layer": "roughness j",
                  "ktx2": {"kind": "array", "format": "half", "levels": 6, "mip_filter": "2x2 box"}}
    assert lv["ktx2"] == {"kind": "3d", "format": "float", "levels": 3, "mip_filter": "2x2 box"}
    np.testing.assert_array_equal(read_ktx2(pv).levels[0], vol)
    with pytest.raises(HomofacError, match="levels asked"):
        write_ktx2(tmp_path / "x.ktx2", vol, "3d", mips=9)
    assert not (tmp_path / "x.ktx2").exists()



def test_bake_cli_ktx2_flag_sets_the_option(tmp_path):
    """``python -m homofac.bake ENV --ktx2`` (and ``ktx2: true`` in its config) turn on the bake's KTX2 output, which
    ``Bake.save`` reads from the options (tests/test_bake.py reads the files back with ktx-parse)."""
    from homofac.app import bake_cli
    assert bake_cli.options(bake_cli.parser().parse_args(["forest", "--out", "o", "--ktx2"])).ktx2 is True
    assert bake_cli.options(bake_cli.parser().parse_args(["forest", "--out", "o"])).ktx2 is False
    cfg = tmp_path / "bake.yaml"
    cfg.write_text("ktx2: true\n")
    assert bake_cli.options(bake_cli.parser().parse_args(["forest", "--out", "o", "--config", str(cfg)])).ktx2 is True
