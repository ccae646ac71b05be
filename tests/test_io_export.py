"""Export and import of the output directory: EXR float32/half, 8-bit RGBA PNG with the alpha trick,
cube faces and the envmap = cube EXR, the png_decode rule, load() round trips and bad files."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

import homofac as hf
from homofac.errors import HomofacError
from homofac.fit.samples import Samples
from homofac.fit import pipeline, precision
from homofac.app.cli import fit_main as main
from homofac import load
from homofac.io.exr import envmap_kind, read_exr, read_exr_with_header
from homofac.io.png import read_png

SMALL = dict(sampling={"kind": "texels", "size": 8, "validation": 400}, keep_samples=True)


@pytest.fixture(scope="module")
def brdf_fac():
    target = hf.fit.brdf_target(hf.brdf.cook_torrance(kd=0.1, ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34)))
    return target, hf.fit.factorize(target, "PQP", mapper="parabolic", texture_size=8, **SMALL)


@pytest.fixture(scope="module")
def cube_fac():
    target = hf.fit.brdf_target(hf.brdf.cook_torrance(kd=0.1, ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34)))
    return target, hf.fit.factorize(target, "PQP", mapper="cube", texture_size=4, **SMALL)


def _doc(d):
    return json.loads((d / "factorization.json").read_text())


def test_exr_float32_is_bit_exact_and_half_is_half(brdf_fac, tmp_path):
    _, fac = brdf_fac
    out = fac.save(tmp_path / "f32")
    doc = _doc(out)
    for k, t in enumerate(doc["textures"]):
        assert t["exr_type"] == "float32"
        a = read_exr(out / t["file"], native=True)
        assert a.dtype == np.float32 and np.array_equal(a, np.asarray(fac.textures[k], np.float32))
    out = fac.save(tmp_path / "half", exr="half")
    doc = _doc(out)
    for k, t in enumerate(doc["textures"]):
        assert t["exr_type"] == "half"
        a = read_exr(out / t["file"], native=True)
        assert a.dtype == np.float16
        assert np.array_equal(a, np.asarray(fac.textures[k], np.float32).astype(np.float16))
    with pytest.raises(HomofacError, match="output.exr"):
        fac.save(tmp_path / "bad", exr="float16")


def test_png_round_trip_and_decode_rule(brdf_fac, tmp_path):
    _, fac = brdf_fac
    out = fac.save(tmp_path / "o", png=True)
    doc = _doc(out)
    enc = fac.encoded()
    rule = doc["png_decode"]
    assert rule["alpha"] is True and rule["written"] is True and rule["transfer"] == "linear"
    assert rule["scale"] == enc.rule["scale"] and np.log2(rule["scale"]) == int(np.log2(rule["scale"]))
    assert max(rule["colour"]) <= 1.0
    np.testing.assert_allclose(np.asarray(rule["colour"]) * rule["scale"] * rule["prescale"][0],
                               np.asarray(doc["correction"]), rtol=1e-6)
    for key in ("textures", "factors", "correction", "metrics", "solver", "timings", "counts"):
        assert key in doc  # every pinned key is still there
    used = []
    for k, t in enumerate(doc["textures"]):
        q = read_png(out / t["png"])
        assert q.dtype == np.uint8 and q.shape == tuple(t["shape"]) + (4,)
        assert np.array_equal(q, enc.rgba[k])
        used.append(np.any((q[..., 3] < 255) & (q[..., 3] > 0)))
        # 8-bit precision: rgb * alpha / 255^2 reproduces the float texture within half a code
        d = precision.decode_rgba8(q).astype(np.float64)
        err = np.abs(d[..., :3] * d[..., 3:] - np.asarray(fac.textures[k], np.float64))
        assert err.max() <= 0.5 / 255 + 1e-7
    assert any(used)  # the alpha channel is in use on this HDR BRDF


@pytest.mark.parametrize("png", [False, True])
def test_load_reproduces_stored_metrics(brdf_fac, tmp_path, png):
    target, fac = brdf_fac
    out = fac.save(tmp_path / "o", png=png)
    doc = _doc(out)
    modes = ("exr", "png") if png else ("exr",)
    for mode in modes:
        lf = load(out, textures=mode)
        m = pipeline.measure(lf, target, fac.samples)
        for split in ("train", "validation"):
            for kind in ("float", "quantized"):
                if mode == "png" and kind == "float":
                    continue  # the float textures are not in the PNGs
                for name, v in doc["metrics"][split][kind].items():
                    assert m[split][kind][name] == pytest.approx(v, rel=1e-5, abs=1e-9), (mode, split, kind, name)
        if mode == "png":  # evaluate() of a PNG-loaded result is the 8-bit decode
            lf_q = lf.evaluate(fac.samples.val_a, fac.samples.val_b)
            np.testing.assert_allclose(np.asarray(lf_q), np.asarray(fac.evaluate(fac.samples.val_a, fac.samples.val_b, quantized=True)),
                                       rtol=1e-6, atol=1e-9)


def test_cube_faces_and_envmap_cube_exr(cube_fac, tmp_path):
    _, fac = cube_fac
    out = fac.save(tmp_path / "c", png=True)
    doc = _doc(out)
    S = fac.texture_size
    for k, t in enumerate(doc["textures"]):
        tex = np.asarray(fac.textures[k], np.float32)
        assert tex.shape == (S, 6 * S, 3)
        assert [f.rsplit("_", 1)[1] for f in t["faces"]] == ["px.exr", "nx.exr", "py.exr", "ny.exr", "pz.exr", "nz.exr"]
        for i, f in enumerate(t["faces"]):
            assert np.array_equal(read_exr(out / f), tex[:, i * S : (i + 1) * S])
        for i, f in enumerate(t["png_faces"]):
            assert np.array_equal(read_png(out / f), fac.encoded().rgba[k][:, i * S : (i + 1) * S])
        cube, header = read_exr_with_header(out / t["cube_file"])
        assert envmap_kind(header) == "cube"
        assert cube.shape == (6 * S, S, 3)
        assert np.array_equal(cube, np.concatenate([tex[:, i * S : (i + 1) * S] for i in range(6)], axis=0))
    # homofac's environment loader reads the cube file back as the same cube map (faces, order, orientation)
    env = hf.light.load_environment(str(out / doc["textures"][1]["cube_file"]), resolution=S)
    assert env.info["kind"] == "cube"
    np.testing.assert_allclose(np.asarray(env.radiance)[: 6 * S * S], np.asarray(fac.textures[1]).reshape(-1, 3),
                               rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("kind", ["png", "exr"])
@pytest.mark.parametrize("damage", ["missing", "truncated"])
def test_bad_files_are_one_line_errors_naming_the_file(brdf_fac, tmp_path, kind, damage):
    _, fac = brdf_fac
    out = fac.save(tmp_path / "o", png=True)
    victim = out / f"q.{kind}"
    if damage == "missing":
        victim.unlink()
    else:
        data = victim.read_bytes()
        victim.write_bytes(data[: len(data) // 2])
    with pytest.raises(HomofacError) as e:
        load(out, textures=kind)
    msg = str(e.value)
    assert "\n" not in msg and str(victim) in msg


def test_png_load_without_pngs_is_refused(brdf_fac, tmp_path):
    _, fac = brdf_fac
    out = fac.save(tmp_path / "o")
    with pytest.raises(HomofacError, match="no PNG file"):
        load(out, textures="png")
    with pytest.raises(HomofacError, match="textures must be"):
        load(out, textures="tga")


CLI_CFG = {
    "target": {"kind": "brdf", "brdf": {"model": "cook_torrance", "kd": 0.1, "ks": 1.0, "roughness": 0.3,
                                         "f0": [1.0, 0.78, 0.34]}},
    "parametrization": "PQP", "mapper": "parabolic", "texture_size": 8,
    "sampling": {"kind": "texels", "size": 8, "validation": 300, "seed": 0},
    "solver": {"method": "lsmr", "tolerance": 1e-5, "max_iterations": 300, "laplacian": 1.0},
    "output": {"dir": "out", "png": True, "samples": False, "exr": "half", "alpha": False, "prescale": [0.5, 1.0, 2.0]},
}


def test_cli_output_png_half_alpha_prescale(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump(CLI_CFG))
    assert main([str(cfg), "--quiet"]) == 0
    out = tmp_path / "out"
    doc = _doc(out)
    assert not (out / "samples.npz").exists()
    rule = doc["png_decode"]
    assert rule["alpha"] is False
    assert rule["prescale"][0] * rule["prescale"][1] ** 2 * rule["prescale"][2] == pytest.approx(1.0)
    assert rule["prescale"] != [1.0, 1.0, 1.0]
    for t in doc["textures"]:
        assert t["exr_type"] == "half" and read_exr(out / t["file"], native=True).dtype == np.float16
        assert np.all(read_png(out / t["png"])[..., 3] == 255)  # alpha off
    # the stored quantized metrics are those of the written PNGs
    lf = load(out, textures="png")
    target = hf.fit.brdf_target(hf.brdf.cook_torrance(kd=0.1, ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34)))
    val = hf.fit.sampling.random_pairs("brdf", 300, 1)
    y = np.asarray(hf.fit.evaluate(target, val.a, val.b))
    s = Samples(val.a, val.b, y, val.a, val.b, y)
    m = pipeline.measure(lf, target, s)
    assert m["validation"]["quantized"]["avg_rel"] == pytest.approx(doc["metrics"]["validation"]["quantized"]["avg_rel"], rel=1e-5)

    bad = {**CLI_CFG, "output": {**CLI_CFG["output"], "prescale": [1.0, 2.0]}}
    cfg.write_text(yaml.safe_dump(bad))
    assert main([str(cfg), "--quiet", "--out", str(tmp_path / "o2")]) == 2
    assert not (tmp_path / "o2").exists()
