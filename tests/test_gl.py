"""The GL preview: generated GLSL equals the Python mappers/projections/lookups, the render equals
``Factorization.evaluate`` at the same pixels, the picture and the CLIs (headless EGL)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

import homofac as hf
import homofac.gl  # noqa: F401 - hf.gl
from homofac.errors import HomofacError
from homofac.factorization import Factor, Factorization, Term, Texture
from homofac.fit.result import Result
from homofac.gl import picture
from homofac.gl.engine import Camera, Light, load_mesh, render, run_glsl
from homofac.param import mappers
from homofac.param import parametrizations as pz
from homofac.param import projections as pj
from homofac.shader import LANGUAGES, generate, languages
from helpers import two_terms

RNG = np.random.default_rng(7)


def unit(n: int, rng=RNG) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    return (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)


def edge_directions() -> np.ndarray:
    """Axes, cube-edge ties, the equator and the diagonals: the branch points of the mappers."""
    s = np.float32(np.sqrt(0.5))
    t = np.float32(1 / np.sqrt(3))
    d = [*np.eye(3), *-np.eye(3), [s, s, 0], [s, 0, s], [0, s, -s], [-s, -s, 0], [t, t, t], [-t, t, -t],
         [0.6, 0.8, 0], [0.6, 0, -0.8]]
    return np.asarray(d, np.float32)


# --------------------------------------------------------------------------------------------------
# The exported shader's functions, traced from the records, equal the Python functions on the GPU


@pytest.mark.parametrize("language", sorted(LANGUAGES))
def test_every_mapper_and_projection_traces_to_every_language(language):
    """A record whose math cannot be traced (a plugin missing its shader half) fails here."""
    for name in mappers.MAPPERS:
        src, _ = generate.mapper_function(languages.get(language), name)
        assert f"hf_map_{name}" in src
    for name in pj.PROJECTIONS:
        src, _ = generate.projection_function(languages.get(language), name, pj.example_context())
        assert f"hf_proj_{name}" in src


def _library(mapper=None, projections=(), context=None):
    """GLSL of some traced records (with their constant tables), for run_glsl."""
    lang = languages.GLSL
    parts, tables = [], {}
    if mapper is not None:
        src, tb = generate.mapper_function(lang, mapper)
        parts.append(src)
        tables.update(tb)
    for name in projections:
        src, tb = generate.projection_function(lang, name, context or {})
        parts.append(src)
        tables.update(tb)
    return "\n".join([languages.table_source(lang, n, v) for n, v in tables.items()] + parts)


@pytest.mark.parametrize("name", sorted(mappers.MAPPERS))
def test_glsl_mapper_equals_python(name):
    m = mappers.get(name)
    if m.scalar:
        x = np.concatenate([RNG.uniform(0, 1, 4000), [0.0, 1.0, 0.5]]).astype(np.float32)
        d = np.stack([x, x, x], axis=-1)
        gpu = run_glsl(_library(name), f"hf_map_{name}(a.x)", d, d)
        face, u, v = m.to_face_uv(jnp.asarray(x))
    else:
        d = np.concatenate([unit(4000), edge_directions()])
        gpu = run_glsl(_library(name), f"hf_map_{name}(a)", d, d)
        face, u, v = m.to_face_uv(jnp.asarray(d))
    assert np.array_equal(gpu[:, 0], np.broadcast_to(np.asarray(face, np.float32), gpu[:, 0].shape))
    np.testing.assert_allclose(gpu[:, 1:], np.stack(np.broadcast_arrays(u, v), -1), atol=2e-6, rtol=1e-6)


def _pairs(kind: str, n: int):
    a, b = unit(n), unit(n)
    if kind == "brdf":  # local frame: both above the surface
        a[:, 2], b[:, 2] = np.abs(a[:, 2]), np.abs(b[:, 2])
    else:  # valid (n, v): n.v > 0
        b = np.where(np.sum(a * b, axis=1, keepdims=True) < 0, -b, b)
    return a, b


@pytest.mark.parametrize("name", sorted(pj.PROJECTIONS))
def test_glsl_projection_equals_python(name):
    proj = pj.PROJECTIONS[name]
    a, b = _pairs(proj.kind, 4000)
    ctx = pj.example_context()  # the dominant light of NRHD, the shift of r_off
    expr = f"vec3(hf_proj_{name}(a, b))" if proj.scalar else f"hf_proj_{name}(a, b)"
    gpu = run_glsl(_library(projections=[name], context=ctx), expr, a, b)
    cpu = np.asarray(proj.fn(jnp.asarray(a), jnp.asarray(b), {k: jnp.asarray(v, jnp.float32) for k, v in ctx.items()}))
    if proj.scalar:
        cpu = np.repeat(cpu[:, None], 3, axis=1)
    # float32 rounding (GPU FMA, sqrt). At a highlight's peak (h' = n: r on a light's disc, nhs_dom) the
    # coordinate 1 - (1 - n.h')^(1/4) takes the fourth root of float32 rounding of n.h' (1e-15 -> 2e-4):
    # there both must read the peak to within a 128-texel line's eighth of a texel, 1e-3.
    peak = proj.scalar & (cpu > 1.0 - 1e-3)
    np.testing.assert_allclose(gpu[~peak], cpu[~peak], atol=1e-5)
    np.testing.assert_allclose(gpu[peak], cpu[peak], atol=1e-3)


def _one_texture(mapper: str, S: int, rng=RNG):
    """A one-texture, one-factor model on ``mapper`` (dilated, as fitted models are): its value is the lookup."""
    m = mappers.get(mapper)
    H, W = mappers.texture_shape(mapper, S)
    tex = mappers.dilate(mapper, S, rng.uniform(0.1, 1.0, size=(H, W, 3)).astype(np.float32))
    kind = "lighting" if m.covers_sphere or m.scalar else "brdf"
    proj = ("nv" if kind == "lighting" else "cos_i") if m.scalar else ("n" if kind == "lighting" else "wi")
    model = Factorization(kind, "lighting" if kind == "lighting" else "brdf", (Texture("t", mapper, S, jnp.asarray(tex)),),
                          (Term((Factor(proj, "t"),), jnp.ones(3)),), {}, "lookup")
    return Result(model), tex


@pytest.mark.parametrize("name", sorted(mappers.MAPPERS))
def test_hardware_filtered_lookup_equals_mappers_lookup(name):
    """The exported shader reads the texture with linear filtering and clamp to edge at the pinned
    clamped coordinate: the same value as mappers.lookup, inside and outside the mapped domain."""
    S = 8
    fac, tex = _one_texture(name, S)
    a = np.concatenate([unit(3000), edge_directions()])  # includes z < 0 for the hemisphere mappers
    b = a.copy()
    if fac.kind == "brdf" or mappers.get(name).scalar:
        b = np.tile(np.array([[0.0, 0.0, 1.0]], np.float32), (len(a), 1))
        a = np.where(np.sum(a * b, axis=1, keepdims=True) < 0, -a, a) if fac.kind == "lighting" else a
    gpu = hf.gl.evaluate(fac, a, b)
    cpu = np.asarray(fac.evaluate(a, b))
    # float32 texel coordinates differ by ~1e-7 relative between the GPU and XLA; over a texel whose
    # values change by O(1) that is ~1e-6 in value (measured up to 2.2e-6); a wrong lookup is O(0.1)
    np.testing.assert_allclose(gpu, cpu, atol=1e-5)


# --------------------------------------------------------------------------------------------------
# Lighting factorizations (small: light resolution 8, texture size 8, sampling size 8)


@pytest.fixture(scope="module")
def lighting():
    """One NR fit on the dual paraboloid; its textures resampled onto the cube (as NRHD) and octahedral (as NRV)
    maps stand in for fits there: what these tests compare is a model's GL and CPU evaluation, not a fit."""
    env = hf.light.load_environment("forest", resolution=8)
    brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    target = hf.light.lighting_target(brdf, env, parametrization="NRHD")
    samples = hf.fit.draw_samples(target, "NR", {"kind": "texels", "size": 8, "validation": 1000}, lambda m: None)
    dp = hf.fit.factorize(target, "NR", mapper="dual_paraboloid", texture_size=8, samples=samples)
    facs = {"dual_paraboloid": dp, "cube": resampled(dp, "cube", "NRHD", target.context),
            "octahedral": resampled(dp, "octahedral", "NRV", target.context)}
    return {"env": env, "brdf": brdf, "target": target, "facs": facs}


def resampled(fac, mapper: str, name: str, context: dict):
    """``fac``'s textures looked up at the texel centres of ``mapper`` (cyclically) as the textures of
    parametrization ``name``: a smooth, positive model on any mapper without a fit."""
    d = jnp.asarray(mappers.texel_directions(mapper, fac.texture_size), jnp.float32)
    data = [mappers.lookup(fac.mapper, jnp.asarray(fac.textures[k % len(fac.textures)]), d)
            for k in range(pz.get(name).T)]
    model = Factorization.product(fac.kind, fac.quantity, name, mapper, fac.texture_size, data, fac.correction,
                                  dict(context))
    return Result(model)


def as_parametrization(fac, name: str):
    """The fitted textures of ``fac`` reused (cyclically) as the textures of parametrization ``name``."""
    T = pz.get(name).T
    tex = tuple(fac.textures[k % len(fac.textures)] for k in range(T))
    model = Factorization.product(fac.kind, fac.quantity, name, fac.mapper, fac.texture_size, tex, fac.correction,
                                  dict(fac.context))
    return Result(model)


MAX_DIFF: dict = {}


@pytest.mark.parametrize("mapper", ["dual_paraboloid", "cube", "octahedral"])
@pytest.mark.parametrize("param", ["NR", "NRV", "NRHD"])
def test_render_equals_cpu_evaluate(lighting, mapper, param):
    """Every covered pixel: the GL value equals Factorization.evaluate at the read-back (n, v) within 2/255."""
    fac = as_parametrization(lighting["facs"][mapper], param)
    mesh = "torus" if param == "NRV" else "sphere"
    frame = render(fac, mesh, size=96, camera=Camera(azimuth=40.0, elevation=25.0))
    m = frame.mask
    assert 0.2 < m.mean() < 0.9
    n, v = frame.a[m], frame.b[m]
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1, atol=1e-5)
    cpu = np.asarray(fac.evaluate(n, v))
    cpu = np.where((np.sum(n * v, axis=1) > 0)[:, None], cpu, 0.0)  # invalid pairs are 0 (docs/conventions.md)
    gl = frame.value[m]
    exposure = picture.auto_exposure(cpu)
    show = lambda x: np.round(picture.srgb(x * exposure) * 255)  # noqa: E731 - what the PNG shows
    diff = np.abs(show(gl) - show(cpu)).max()
    MAX_DIFF[(param, mapper)] = (diff, float(np.abs(gl - cpu).max() * exposure))
    assert diff <= 2, (param, mapper, diff)
    assert np.abs(gl - cpu).max() * exposure <= 2 / 255
    assert np.abs(gl - cpu).max() <= 1e-4 * np.abs(cpu).max()  # in fact to float rounding


def test_multi_term_gpu_equals_cpu():
    """A sum of products (diffuse E(n) + P(r) W(n.v), one 1D texture) on the GPU: float and 8-bit textures."""
    fac = Result(two_terms())
    a, b = _pairs("lighting", 4000)
    cpu = np.asarray(fac.evaluate(a, b))
    np.testing.assert_allclose(hf.gl.evaluate(fac, a, b), cpu, rtol=1e-5, atol=1e-6)
    q_cpu = np.asarray(fac.evaluate(a, b, quantized=True))
    np.testing.assert_allclose(hf.gl.evaluate(fac, a, b, quantized=True), q_cpu, atol=1.5 / 255 * np.abs(q_cpu).max())
    frame = render(fac, "sphere", size=64)
    m = frame.mask
    ref = np.asarray(fac.evaluate(frame.a[m], frame.b[m]))
    ref = np.where((np.sum(frame.a[m] * frame.b[m], axis=1) > 0)[:, None], ref, 0.0)
    assert np.abs(frame.value[m] - ref).max() <= 1e-4 * ref.max()


def test_gpu_evaluate_equals_cpu(lighting):
    fac = lighting["facs"]["cube"]
    a, b = _pairs("lighting", 5000)
    np.testing.assert_allclose(hf.gl.evaluate(fac, a, b), np.asarray(fac.evaluate(a, b)), rtol=1e-5, atol=1e-6)


def test_brdf_render_under_one_light_equals_cpu():
    """A PQP BRDF factorization under a directional light: f(wi, wo) cos(theta_i) E, as the CPU computes it."""
    S = 8
    H, W = mappers.texture_shape("parabolic", S)
    yy, xx = np.mgrid[0:H, 0:W] / S
    tex = tuple(np.stack([0.5 + 0.4 * np.sin(3 * xx + k), 0.6 + 0.3 * np.cos(2 * yy), 0.4 + 0.2 * xx * yy], -1)
                .astype(np.float32) for k in range(2))
    fac = Result(Factorization.product("brdf", "brdf", "PQP", "parabolic", S, tex, jnp.asarray([0.9, 0.8, 0.7])))
    light = Light(direction=(0.3, 0.5, 0.8), irradiance=(2.0, 2.0, 2.0))
    frame = render(fac, "sphere", size=80, light=light)
    m = frame.mask
    wi, wo = frame.a[m], frame.b[m]
    cpu = np.asarray(fac.evaluate(wi, wo)) * np.maximum(wi[:, 2:3], 0) * 2.0
    cpu = np.where(((wi[:, 2] > 0) & (wo[:, 2] > 0))[:, None], cpu, 0.0)
    assert np.abs(frame.value[m] - cpu).max() <= 1e-5 * cpu.max()
    assert (cpu > 0).mean() > 0.3  # the lit side is visible
    # the preview with the exact BRDF target shows the three panels
    target = hf.target.brdf_target(hf.brdf.cook_torrance(kd=0.1, ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34)))
    img, data = hf.gl.preview(fac, target, size=64, light=light, return_data=True)
    assert img.dtype == np.uint8 and img.shape[1] > 3 * 64 and np.isfinite(data["nrmse"])


@pytest.mark.slow
def test_preview_exact_panel_is_the_lighting(lighting):
    """The exact panel is hf.light.lighting at the pixels' (n, v); the error is measured against it."""
    fac = lighting["facs"]["dual_paraboloid"]
    img, data = hf.gl.preview(fac, lighting["target"], size=64, return_data=True)
    frame = data["frame"]
    m = frame.mask
    n, v = frame.a[m], frame.b[m]
    ref = np.asarray(hf.light.lighting(lighting["brdf"], lighting["env"], n, v))
    np.testing.assert_allclose(data["exact"], ref, rtol=1e-5, atol=1e-7)
    assert data["exact"].max() > 0 and 0 < data["nrmse"] < 1
    assert img.shape[0] > 64 and img.shape[1] > 3 * 64
    # background, the object and the colour bar: many colours
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 500
    # without a target: the factorized panel only
    only = hf.gl.preview(fac.replace(target=None), size=64)
    assert only.shape[1] < img.shape[1]


def test_meshes():
    s, t = load_mesh("sphere"), load_mesh("torus")
    for m in (s, t):
        assert np.abs(np.linalg.norm(m.positions, axis=1)).max() <= 1 + 1e-6
        np.testing.assert_allclose(np.linalg.norm(m.normals, axis=1), 1, atol=1e-5)
    with pytest.raises(HomofacError, match="no such file"):
        load_mesh("/nonexistent/bunny.obj")


def test_obj_mesh(tmp_path, lighting):
    obj = tmp_path / "tet.obj"
    obj.write_text("v 0 0 1\nv 1 0 -0.5\nv -0.5 0.8 -0.5\nv -0.5 -0.8 -0.5\nf 1 2 3\nf 1 3 4\nf 1 4 2\nf 2 4 3\n")
    frame = render(lighting["facs"]["cube"], str(obj), size=48)
    assert frame.mask.mean() > 0.1
    (tmp_path / "bad.obj").write_text("this is not a mesh\n")
    with pytest.raises(HomofacError):
        load_mesh(tmp_path / "bad.obj")


# --------------------------------------------------------------------------------------------------
# CLIs


def _run(args, out):
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    r = subprocess.run([sys.executable, "-m", "homofac.fit", "--quiet", "--out", str(out), *args],
                       capture_output=True, text=True, timeout=600, env=env)
    assert r.returncode == 0, r.stderr
    return out


@pytest.fixture(scope="module")
def default_run(tmp_path_factory):
    """`python -m homofac.fit CONFIG --out DIR` as a user would run it, on a small lighting config."""
    d = tmp_path_factory.mktemp("small")
    cfg = {"target": {"kind": "lighting", "brdf": {"model": "cook_torrance"}, "environment": {"file": "studio",
                                                                                           "resolution": 4}},
           "parametrization": "NR", "texture_size": 8, "sampling": {"size": 6, "validation": 300}}
    (d / "c.yaml").write_text(json.dumps(cfg))
    return _run([str(d / "c.yaml")], d / "out")


@pytest.mark.slow
def test_preview_cli_writes_a_png(default_run, tmp_path, capsys):
    from homofac.preview import main

    out = tmp_path / "p.png"
    assert main([str(default_run), "-o", str(out), "--size", "64", "--mesh", "torus"]) == 0
    img = np.asarray(Image.open(out))
    assert img.ndim == 3 and img.shape[0] > 64 and img.shape[1] > 3 * 64
    assert "wrote" in capsys.readouterr().out
    assert [p.name for p in tmp_path.iterdir()] == ["p.png"]  # no temporary files left


def _one_line_error(capsys, code: int) -> str:
    err = capsys.readouterr().err.strip()
    assert code == 2
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("homofac: error:"), err
    assert "Traceback" not in err
    return lines[0]


@pytest.mark.slow
def test_preview_cli_refuses_bad_input(tmp_path, capsys, monkeypatch, default_run):
    from homofac.preview import main

    assert "no such directory" in _one_line_error(capsys, main([str(tmp_path / "missing")]))
    (tmp_path / "notes.txt").write_text("x")
    assert "not a homofac output directory" in _one_line_error(capsys, main([str(tmp_path)]))
    assert "bunny.obj" in _one_line_error(capsys, main([str(default_run), "--mesh", str(tmp_path / "bunny.obj"),
                                                        "-o", str(tmp_path / "x.png")]))
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert "display" in _one_line_error(capsys, main([str(default_run), "--window"]))
    assert not (tmp_path / "x.png").exists()
    with pytest.raises(HomofacError):
        main([str(tmp_path), "--debug"])


SMALL_BRDF = {
    "target": {"kind": "brdf", "brdf": {"model": "cook_torrance", "kd": 0.1, "ks": 1.0, "roughness": 0.3,
                                         "f0": [1.0, 0.78, 0.34]}},
    "parametrization": "PQP", "mapper": "parabolic", "texture_size": 8,
    "sampling": {"kind": "texels", "size": 8, "validation": 200, "seed": 0},
    "solver": {"method": "lsmr", "tolerance": 1e-4, "max_iterations": 100},
    "output": {"dir": "out", "samples": False},
}


@pytest.mark.slow
def test_fit_without_gl_warns_and_skips_the_preview(tmp_path, capsys, monkeypatch):
    import yaml

    from homofac.app.cli import fit_main as main
    from homofac.gl import device

    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump(SMALL_BRDF))
    # A GL device process that cannot create a context (as on a machine without EGL): it says so first.
    fake = tmp_path / "no_egl.py"
    fake.write_text("import pickle, sys\npickle.dump(('error', 'context', 'test'), sys.stdout.buffer)\n")
    device._stop()
    monkeypatch.setattr(device, "SERVER", fake)
    assert main([str(cfg), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert [ln for ln in err.splitlines() if "preview" in ln] == [
        "homofac: warning: preview.png skipped: no headless OpenGL (EGL) context: test (install libegl1 libgl1, "
        "see Makefile)"]
    assert (tmp_path / "out" / "factorization.json").is_file()
    assert not (tmp_path / "out" / "preview.png").exists()
    monkeypatch.undo()
    device._stop()
    # --no-preview: nothing rendered, nothing said
    assert main([str(cfg), "--quiet", "--no-preview"]) == 0
    assert "preview" not in capsys.readouterr().err
    assert not (tmp_path / "out" / "preview.png").exists()


def test_window_viewer_renders_headless(lighting, tmp_path):
    """The --window viewer's code path, on moderngl-window's headless (EGL) window for a few frames. The
    viewer draws in its own process (its window owns the context), so it runs in a child here: this
    process must never load a GL driver (see the next test)."""
    lighting["facs"]["octahedral"].save(tmp_path / "fac")
    script = ("import sys, numpy as np, homofac as hf\n"
              "from homofac.gl.window import show\n"
              "img = show(hf.load(sys.argv[1]), size=64, backend='headless', frames=2, exposure=1.0)\n"
              "np.save(sys.argv[2], img)\n")
    r = subprocess.run([sys.executable, "-c", script, str(tmp_path / "fac"), str(tmp_path / "img.npy")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    img = np.load(tmp_path / "img.npy")
    assert img.shape == (64, 64, 3)
    covered = (img != 32).any(axis=-1)
    assert 0.2 < covered.mean() < 0.9 and len(np.unique(img[covered], axis=0)) > 50


def test_headless_renders_never_load_a_gl_driver_into_the_fitting_process(lighting, tmp_path):
    """render / evaluate / preview run in the GL device process: after them, the process that computes with
    XLA (the preview's exact panel and the CPU evaluate compile XLA programs in it, as a fit does) has neither
    moderngl nor a Mesa driver or its LLVM mapped, and the device answers again after it died (a driver crash
    costs one call, not the session). The factorization is the module's, loaded: a fit in the child would add
    its compiles (about 6 s of CPU) and nothing this test checks."""
    lighting["facs"]["octahedral"].save(tmp_path / "fac")
    script = """
import os, signal, sys, numpy as np, homofac as hf
from homofac.errors import HomofacError
from homofac.gl import device
env = hf.light.load_environment("forest", resolution=8)
t = hf.light.lighting_target(hf.brdf.ggx(roughness=0.4), env)
fac = hf.load(sys.argv[1])
img = hf.gl.preview(fac, t, size=32)
n = np.array([[0.0, 0.0, 1.0]]); v = np.array([[0.0, 0.6, 0.8]])
gpu = hf.gl.evaluate(fac, n, v)
assert np.allclose(gpu, np.asarray(fac.evaluate(n, v)), rtol=1e-4, atol=1e-6)
maps = open("/proc/self/maps").read()
loaded = sorted({w for line in maps.splitlines() for w in line.split()[-1:] if "LLVM" in w or "dri" in w.split("/")[-1] or "gallium" in w})
assert "moderngl" not in sys.modules and not loaded, (sorted(m for m in sys.modules if "moderngl" in m), loaded)
os.kill(device._child["proc"].pid, signal.SIGKILL)
device._child["proc"].wait()
try:
    hf.gl.evaluate(fac, n, v)
except HomofacError as e:
    print("died:", e)
assert np.allclose(hf.gl.evaluate(fac, n, v), gpu)
print("ok", img.shape)
"""
    r = subprocess.run([sys.executable, "-c", script, str(tmp_path / "fac")], capture_output=True, text=True, timeout=600,
                       cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "ok (" in r.stdout
