"""The material-parametric bake: the glTF BRDF's integrals (furnace, exact material split), the bake's
accuracy where it must be exact, its directory, CLI, plan, and shaders (GPU equals CPU, glslang)."""

from __future__ import annotations

import json
import shutil
import subprocess
from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import homofac as hf
from homofac.bake import kernels as kn
from homofac.bake.plan import PRESETS, plan as make_plan
from homofac.bake import shader
from homofac.errors import HomofacError
from homofac.io.exr import read_exr
from homofac.io.ktx2 import read_ktx2
from homofac.light.integrals import integrals, material_radiance
from helpers import BAKE_SIZES, FOREST_BAKES, optimized_xla, visible_pairs as pairs

JS = Path(__file__).resolve().parents[1] / "js"

TINY = dict(layers=3, **BAKE_SIZES)


def as_schema_4(doc: dict, version: int = 4) -> dict:
    """A schema-5 bake.json written as schema ``version`` (<= 4) would hold it: every map in the first map's
    layout, given by the layers' x, y; no per-map blocks."""
    old = json.loads(json.dumps(doc))
    old["schema_version"] = version
    first = [t for t in old["textures"] if t["kind"] == "prefiltered"][0]["blocks"]
    for layer, block in zip(old["layers"], first):
        layer.update(x=block["x"], y=block["y"])
    for t in old["textures"]:
        t.pop("blocks", None)
    return old


def nrmse(a, e):
    return float(np.linalg.norm(np.asarray(a) - np.asarray(e)) / np.linalg.norm(np.asarray(e)))


@pytest.fixture
def forest_bake(forest_bakes):
    return forest_bakes("plain")  # the plain products (mixed: test_bake_mixed.py)


def test_white_furnace_integrals(x64):
    """Uniform radiance 1: I_A + I_B is the white metal's directional albedo, 0.96 I_d + 0.04 I_A + I_B the
    white dielectric's (the glTF BRDF's albedo by quadrature, :func:`homofac.brdf.albedo`)."""
    env = hf.light.uniform(1.0, 16)
    n, v = pairs(6, seed=1)
    rough = np.array([0.5, 0.6, 0.7, 0.9, 0.8, 1.0])
    parts = np.asarray(integrals(env, jnp.asarray(n), jnp.asarray(v), jnp.asarray(rough)))
    wo = np.asarray(hf.sphere.local(jnp.asarray(v), jnp.asarray(n)))
    for i in range(len(n)):
        metal = hf.brdf.gltf(base_color=1.0, metallic=1.0, roughness=float(rough[i]))
        dielectric = hf.brdf.gltf(base_color=1.0, metallic=0.0, roughness=float(rough[i]))
        a_metal = float(hf.brdf.albedo(metal, jnp.asarray(wo[i]), n=96)[0])
        a_diel = float(hf.brdf.albedo(dielectric, jnp.asarray(wo[i]), n=96)[0])
        np.testing.assert_allclose(parts[i, 1, 0] + parts[i, 2, 0], a_metal, rtol=3e-3)
        np.testing.assert_allclose(0.96 * parts[i, 0, 0] + 0.04 * parts[i, 1, 0] + parts[i, 2, 0], a_diel, rtol=3e-3)


def test_three_integrals_give_the_lighting_of_any_material(x64):
    """L(n, v; c, m, rho) from I_d, I_A, I_B equals the pinned lighting of the full glTF BRDF."""
    env = hf.light.load_environment("forest", 8)
    env = jax.tree_util.tree_map(lambda a: a.astype(jnp.float64) if getattr(a, "dtype", None) == jnp.float32 else a, env)
    n, v = pairs(5, seed=2)
    rng = np.random.default_rng(3)
    rough = rng.uniform(0.1, 1.0, len(n))
    parts = integrals(env, jnp.asarray(n), jnp.asarray(v), jnp.asarray(rough))
    for i in range(len(n)):
        c, m = rng.uniform(0, 1, 3), float(rng.uniform())
        brdf = hf.brdf.gltf(base_color=c, metallic=m, roughness=float(rough[i]))
        direct = np.asarray(hf.light.lighting(brdf, env, jnp.asarray(n[i:i + 1]), jnp.asarray(v[i:i + 1])))
        np.testing.assert_allclose(np.asarray(material_radiance(parts[i:i + 1], c, m)), direct, rtol=1e-10, atol=1e-14)


def test_kernel_mass_is_the_directional_albedo():
    """An azimuth-averaged kernel integrates to its lobe's directional albedo (furnace of the bake's filters)."""
    x = np.array([0.2, 0.6, 0.95])
    k = kn.specular_kernels(0.5, x)
    b = hf.brdf.gltf(base_color=1.0, metallic=1.0, roughness=0.5)
    wo = jnp.asarray(np.stack([np.sqrt(1 - x * x), 0 * x, x], -1))
    np.testing.assert_allclose(kn.mass(k).sum(0), np.asarray(hf.brdf.albedo(b, wo, n=96))[:, 0], rtol=2e-3)


def test_bake_under_uniform_light_is_the_albedo(uniform_bake):
    """Under constant radiance 1 the integrals are the lobes' directional albedos (the white furnace) and the
    bake must give them within its tables' n.v interpolation, at every layer including the sharpest (whose
    lobe is far narrower than a light texel here)."""
    b = uniform_bake  # hf.bake(hf.light.uniform(1.0, 8), preset="fast", **TINY)
    n, v = pairs(300, seed=4)
    x = np.sum(n * v, 1)
    xc = kn.nv_centres(TINY["nv_size"])
    line = lambda values: np.interp(x, xc, values)  # noqa: E731 - the tables' n.v interpolation
    diffuse = line(kn.mass(kn.diffuse_kernels(xc)))
    for rho in b.roughness:
        a, bb = kn.albedos(rho, xc)
        ref = np.stack([diffuse, line(a), line(bb)])
        got = np.asarray(b.terms(n, v, rho))
        for i in range(3):
            assert nrmse(got[:, i, 0], ref[i]) < 0.01, (rho, i)


def test_evaluate_interface(forest_bake):
    """The pinned evaluate: (N, 3) out, linear in base colour and metallic exactly; 0 for n.v <= 0; lookups."""
    b = forest_bake
    n, v = pairs(200, seed=5)
    rng = np.random.default_rng(6)
    c, m, r = rng.uniform(size=(200, 3)), rng.uniform(size=200), rng.uniform(0.05, 1, 200)
    out = np.asarray(b.evaluate(n, v, c, m, r))
    assert out.shape == (200, 3) and np.all(np.isfinite(out))
    t = np.asarray(b.terms(n, v, r))
    f0 = (1 - m[:, None]) * 0.04 + m[:, None] * c
    np.testing.assert_allclose(out, (1 - m[:, None]) * 0.96 * c * t[:, 0] + f0 * t[:, 1] + t[:, 2], rtol=1e-5, atol=1e-7)
    assert np.all(np.asarray(b.evaluate(n, -v, c, m, r)) == 0)
    assert b.lookups == make_plan("balanced", harmonic=0.0, diffuse_basis="texture").lookups == 7
    with pytest.raises(HomofacError, match="evaluate"):
        b.evaluate(n[:, :2], v, c, m, r)


@pytest.mark.slow
def test_bake_is_closer_to_the_integrals_than_split_sum_at_its_layers():
    """At a layer's roughness, the fitted P W is never worse than split-sum (exact prefilter, exact DFG) on I_A
    (Eckart-Young on the azimuth-averaged data; measured on random pairs against the exact integrals)."""
    env = hf.light.load_environment("forest", 8)
    with optimized_xla():  # helpers.optimized_xla: a bake runs long at -O0
        b = hf.bake(env, preset="fast", layers=4, nv_size=16, samples=256, data_resolution=8, max_size=16, diffuse_size=8)
    n, v = pairs(400, seed=7)
    x = np.sum(n * v, 1)
    r = 2 * x[:, None] * n - v
    rho = b.roughness[2]  # 0.356: its own block (the sharp layers share one, read at the block's detail)
    assert b.blocks[2] == 2
    ref = np.asarray(integrals(env, jnp.asarray(n, jnp.float32), jnp.asarray(v, jnp.float32), rho))
    got = np.asarray(b.terms(n, v, rho))
    q = kn.q_grid()
    ch = np.sqrt(1 - q * q)
    a2 = rho ** 4
    d = a2 / (np.pi * (ch * ch * (a2 - 1) + 1) ** 2) * np.maximum(1 - 2 * q * q, 0)
    from homofac.bake.filter import prefilter
    num, den = prefilter(d[None], r, env)
    p = num[:, 0] / den[:, :1]  # Karis' prefilter at n = v = r
    xs = kn.nv_centres(128)
    a = np.interp(x, xs, kn.mass(kn.specular_kernels(rho, xs))[0])
    assert nrmse(got[:, 1], ref[:, 1]) <= nrmse(p * a[:, None], ref[:, 1])


def test_save_load_round_trip(forest_bake, tmp_path):
    b = forest_bake
    out = b.save(tmp_path / "bk")
    doc = json.loads((out / "bake.json").read_text())
    assert doc["format"] == "homofac.bake" and doc["lookups"] == 7
    assert sorted(p.name for p in out.iterdir()) == ["E0.exr", "P0.exr", "P1.exr", "W0.exr", "W1.exr", "bake.json",
                                                     "sh.txt", "sh9.json", "shader.glsl", "shader.hlsl", "shader.metal", "shader.wgsl",
                                                     "shader_es.glsl"]
    sh = json.loads((out / "sh9.json").read_text())["irradiance"]  # pinned: 9 RGB coefficients
    assert np.shape(sh) == (9, 3) and np.all(np.isfinite(sh)) and sh[0][0] > 0
    assert (out / "shader.glsl").read_text() == shader.source(b, "glsl")
    back = hf.load(out)
    n, v = pairs(100, seed=8)
    r = np.linspace(0.04, 1, 100)
    np.testing.assert_allclose(np.asarray(back.terms(n, v, r)), np.asarray(b.terms(n, v, r)), rtol=3e-3, atol=1e-4)
    (out / "W1.exr").unlink()
    with pytest.raises(HomofacError, match="W1.exr"):
        hf.load(out)


def test_cli_writes_a_bake_and_refuses_bad_input(tmp_path, capsys):
    from homofac.app import bake_cli
    cfg = tmp_path / "bake.yaml"
    cfg.write_text("preset: fast\nlayers: 3\nmax_size: 8\nnv_size: 8\nsamples: 64\ndata_resolution: 4\ndiffuse_size: 8\n")
    assert bake_cli.main(["forest", "--out", str(tmp_path / "out"), "--config", str(cfg)]) == 0
    assert hf.load(tmp_path / "out").lookups == 4
    cfg.write_text("preset: fast\nlayer: 3\n")
    assert bake_cli.main(["forest", "--out", str(tmp_path / "o2"), "--config", str(cfg)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("homofac: error:") and "layer" in err[0]
    assert bake_cli.main(["forest", "--out", str(tmp_path / "o3"), "--max-size", "12"]) == 2
    assert "power of two" in capsys.readouterr().err
    assert bake_cli.main(["no_such_map.exr", "--out", str(tmp_path / "o4"), "--layers", "3"]) == 2
    assert "no such file" in capsys.readouterr().err
    assert not (tmp_path / "o2").exists() and not (tmp_path / "o3").exists() and not (tmp_path / "o4").exists()


def test_presets_are_one_printable_plan():
    assert [make_plan(p).lookups for p in PRESETS] == [4, 8, 16]
    assert "lookups per pixel" in make_plan("best").describe()


# The shaders of each layout: glslang (GLSL 330, GLSL ES 3.00, HLSL to SPIR-V), the MSL against the Metal stand-in,
# the WGSL on wgpu against the CPU; the plain bake's both ways up. Tolerances: the harmonic's layouts divide by
# Y(I_0), which amplifies float32 rounding where it is small (the GLSL's own comparisons: each layout's file).
SHADER_CHECKS = {"plain": ((False, True), 500, (1e-4, 2e-3)), "shared": ((False,), 400, (1e-3, 3e-3)),
                 "mixed": ((False,), 400, (1e-3, 3e-3)), "harmonic": ((False,), 400, (1e-3, 3e-3))}


@pytest.mark.parametrize("layout", list(FOREST_BAKES))
def test_each_layouts_shaders_compile_and_the_wgsl_equals_cpu(forest_bakes, layout, tmp_path):
    """Every shader language of the layout's bake: GLSL 330 and GLSL ES 3.00 through glslangValidator, HLSL through
    its HLSL front end to SPIR-V (validated), the MSL as C++17 against the Metal stand-in, the WGSL run on wgpu
    (lavapipe) and equal to ``Bake.terms`` / ``evaluate``. A check whose tool is missing is skipped after the others ran."""
    b = forest_bakes(layout)
    y_ups, count, tol = SHADER_CHECKS[layout]
    checks = [partial(check_glslang, b, language, tmp_path, y_ups=y_ups) for language in ("glsl", "glsl_es", "hlsl")]
    skipped = []
    for check in checks + [partial(check_msl, b, tmp_path, y_ups=y_ups), partial(check_wgsl, b, count, tol)]:
        try:
            check()
        except pytest.skip.Exception as e:
            skipped.append(str(e))
    with pytest.raises(HomofacError, match="cg"):
        shader.source(b, "cg")
    if skipped:
        pytest.skip("; ".join(skipped))


def check_glslang(bake, language: str, tmp_path, y_ups=(False, True)):
    """``bake``'s shader in ``language`` (glsl, glsl_es, hlsl) compiles with glslangValidator in a caller of
    ``homofac_ibl`` (HLSL to SPIR-V, validated by spirv-val where installed)."""
    exe = shutil.which("glslangValidator")
    if exe is None:
        pytest.skip("glslangValidator is not installed (Debian glslang-tools)")
    for y_up in y_ups:
        src = shader.source(bake, language, y_up=y_up)
        if language == "hlsl":
            f = tmp_path / "bake.hlsl"
            f.write_text(src + "\nfloat4 ps_main(float4 pos : SV_Position) : SV_Target {\n"
                         "    return float4(homofac_ibl(normalize(pos.xyz), float3(0, 0, 1), float3(0.5, 0.5, 0.5), 0.5, 0.3), 1.0);\n}\n")
            cmd = [exe, "-D", "-e", "ps_main", "-S", "frag", "-V", "-o", str(tmp_path / "bake.spv"), str(f)]
        else:
            head = "#version 330 core\n" if language == "glsl" else "#version 300 es\nprecision highp float;\n"
            f = tmp_path / "bake.frag"
            f.write_text(head + src + "uniform vec3 n_in; uniform vec3 v_in; out vec4 color;\n"
                         "void main() { color = vec4(homofac_ibl(n_in, v_in, vec3(0.5), 0.5, 0.3), 1.0); }\n")
            cmd = [exe, "-S", "frag", str(f)]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stdout[-3000:]
        if language == "hlsl" and shutil.which("spirv-val"):
            r = subprocess.run(["spirv-val", str(tmp_path / "bake.spv")], capture_output=True, text=True, timeout=120)
            assert r.returncode == 0, r.stdout + r.stderr


def test_gpu_equals_cpu(forest_bake):
    pytest.importorskip("moderngl")
    from homofac.gl.engine import run_glsl
    b = forest_bake
    n, v = pairs(2000, seed=9)
    decl = check_glsl_terms(b, n, v, (0.03, 0.2, 0.7), 1e-4)
    c, m = (0.9, 0.5, 0.2), 0.3
    gpu = run_glsl(decl, "homofac_ibl(a, b, c, m, rho)", n, v, textures=shader.texture_arrays(b),
                   uniforms={"rho": 0.4, "c": c, "m": m})
    cpu = np.asarray(b.evaluate(n, v, np.broadcast_to(c, (len(n), 3)), m, 0.4))
    assert np.abs(gpu - cpu).max() <= 1e-4 * np.abs(cpu).max()


def check_glsl_terms(bake, n, v, roughness, tol: float) -> str:
    """``homofac_ibl_terms`` of ``bake``'s GLSL (moderngl) equals ``bake.terms`` at each roughness, every term
    within ``tol`` of its largest value. Returns the shader declarations (uniforms rho, c, m and ``hf_part``)."""
    from homofac.gl.engine import run_glsl
    decl = shader.source(bake) + ("uniform float rho; uniform vec3 c; uniform float m;\n"
                                  "vec3 hf_part(vec3 n, vec3 v, int i) { vec3 d, a, s; homofac_ibl_terms(n, v, rho, d, a, s);"
                                  " return i == 0 ? d : (i == 1 ? a : s); }\n")
    for rho in roughness:
        cpu = np.asarray(bake.terms(n, v, rho))
        for i in range(3):
            gpu = run_glsl(decl, f"hf_part(a, b, {i})", n, v, textures=shader.texture_arrays(bake), uniforms={"rho": rho})
            assert np.abs(gpu - cpu[:, i]).max() <= tol * np.abs(cpu[:, i]).max(), (rho, i)
    return decl


def test_ktx2_textures_hold_the_exr_data(forest_bake, tmp_path):
    """``ktx2=True`` writes every texture also as <name>.ktx2 (RGBA half), listed in bake.json, equal to the EXR."""
    out = forest_bake.save(tmp_path / "k", ktx2=True)
    doc = json.loads((out / "bake.json").read_text())
    for t in doc["textures"]:
        k = read_ktx2(out / t["ktx2"])
        exr = read_exr(out / t["file"])
        np.testing.assert_array_equal(np.asarray(k.levels[0])[..., :3], exr)
        assert json.loads(k.text("homofac"))["texture"] == t["name"]
    assert np.asarray(hf.load(out).W).shape == np.asarray(forest_bake.W).shape


def test_ktx2_files_read_by_ktx_parse_name_their_layout(forest_bake, tmp_path):
    """A bake saved with ``ktx2`` (``--ktx2``, ``ktx2: true``): every texture is a KTX2 file that ktx-parse reads
    as a 2D RGBA half-float image of bake.json's size, and its ``homofac`` key names the layout without bake.json:
    the P atlas' layer blocks (roughness, size, x, y), the E maps' cube layout, the W tables' rows and columns."""
    node = shutil.which("node")
    if node is None or not (JS / "node_modules" / "ktx-parse").is_dir():
        pytest.skip("node or js/node_modules/ktx-parse is missing (make js-packages)")
    out = forest_bake.save(tmp_path / "bake", ktx2=True)
    doc = json.loads((out / "bake.json").read_text())
    files = [out / t["ktx2"] for t in doc["textures"]]
    infos = json.loads(subprocess.run([node, str(JS / "ktx2-info.mjs"), *map(str, files)], check=True,
                                      capture_output=True, text=True, timeout=60).stdout)
    assert {t["kind"] for t in doc["textures"]} == {"prefiltered", "diffuse", "weights"}
    for t, info in zip(doc["textures"], infos):
        assert (info["vkFormat"], info["pixelWidth"], info["pixelHeight"]) == (97, t["width"], t["height"])
        assert (info["pixelDepth"], info["layerCount"], info["faceCount"], info["levelCount"]) == (0, 0, 1, 1)
        assert info["levelBytes"] == [t["width"] * t["height"] * 4 * 2]
        key = json.loads(info["keyValue"]["homofac"])
        assert key["texture"] == t["name"] and key["kind"] == t["kind"] and key["channels"] == t["channels"]
        assert key["ktx2"] == {"kind": "2d", "format": "half", "levels": 1, "mip_filter": None}
        assert key["frame"] == "homofac world, +z up" and key["rows"].startswith("file order")
        if t["kind"] == "prefiltered":
            # this map's own blocks (bake.json schema 5), with the layers' roughness and shift
            assert key["mapper"] == "cube" and len(key["layers"]) == len(doc["layers"]) == len(t["blocks"])
            assert key["layers"] == [{**layer, **block} for layer, block in zip(doc["layers"], t["blocks"])]
            # every block lies inside the image the key describes
            assert all(b["x"] + 6 * b["size"] <= key["width"] and b["y"] + b["size"] <= key["height"] for b in key["layers"])
        elif t["kind"] == "diffuse":
            assert key["mapper"] == "cube" and 6 * key["size"] == key["width"] and key["size"] == key["height"]
        else:
            assert key["layers"] == key["height"] == len(doc["layers"]) and key["nv_size"] == key["width"]
        np.testing.assert_array_equal(read_ktx2(out / t["ktx2"]).levels[0][..., :3], read_exr(out / t["file"]))


@pytest.mark.parametrize("path, value", [
    (("plan", "preset"), "fast\n    return vec3(1e9);\n//"),
    (("textures", 0, "name"), "normalize"),
    (("textures", 0, "file"), "../P0.exr"),
    (("textures", 0, "ktx2"), "/etc/passwd"),
    (("shaders", "glsl_es"), "evil.glsl"),
    (("layers", 0, "roughness"), 1e400),
    (("plan", "terms"), 10**9),
    (("plan", "harmonic"), 5.0),
    (("plan", "harmonic"), 0.3),  # the lookups and textures no longer match the plan
])
def test_a_crafted_bake_json_is_refused_in_one_line(forest_bake, tmp_path, path, value):
    """bake.json is input like factorization.json: what reaches generated code, file names or sizes is validated."""
    out = forest_bake.save(tmp_path / "bk")
    doc = json.loads((out / "bake.json").read_text())
    node = doc
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    (out / "bake.json").write_text(json.dumps(doc).replace("Infinity", "1e400"))
    with pytest.raises(HomofacError) as e:
        hf.load(out)
    assert "\n" not in str(e.value)


#: What the bake's MSL uses beyond the factorization's shim (tests/test_shaders.METAL_SHIM), with Metal's signatures.
BAKE_SHIM = r"""
namespace metal {
inline float log(float a) { return std::log(a); }
inline float exp(float a) { return std::exp(a); }
inline int min(int a, int b) { return a < b ? a : b; }
inline float3 normalize(float3 a) { return a / std::sqrt(dot(a, a)); }
inline float3 mix(float3 a, float3 b, float3 t) { return a + (b - a) * t; }
inline float2 operator/(float2 a, float2 b) { return float2(a.x / b.x, a.y / b.y); }
}  // namespace metal
"""


def check_msl(bake, tmp_path, y_ups=(False, True)):
    """``bake``'s MSL compiles (clang, C++17, the Metal stand-in) with a caller of both pinned functions."""
    from test_shaders import CLANG_FLAGS, METAL_SHIM, run, tool
    exe = tool("clang++")
    shim = tmp_path / "shim"
    shim.mkdir()
    (shim / "metal_stdlib").write_text(METAL_SHIM.replace("}  // namespace metal\n", "}  // namespace metal\n" + BAKE_SHIM, 1))
    for y_up in y_ups:
        src = tmp_path / "bake.metal"
        src.write_text(shader.source(bake, "msl", y_up=y_up) +
                       "float3 caller(float3 n, float3 v, thread const HomofacBakeTextures& hf) {\n"
                       "    float3 d, a, s; homofac_ibl_terms(n, v, 0.3f, d, a, s, hf);\n"
                       "    return homofac_ibl(n, v, float3(0.5f), 0.5f, 0.3f, hf) + d + a + s;\n}\n")
        run([exe, *CLANG_FLAGS, "-fsyntax-only", "-I", shim, "-x", "c++", src])


def check_wgsl(bake, count: int, tol: tuple[float, float]):
    """A compute pass over ``bake``'s WGSL on wgpu (lavapipe) equals ``bake.terms`` and ``bake.evaluate`` on
    ``count`` random pairs over the roughness range, within ``tol`` (float32 textures, half-float textures)
    of the largest value. RGB textures are uploaded as RGBA with alpha 1, RGBA ones as they are."""
    wgpu = pytest.importorskip("wgpu")
    import os
    os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp")
    try:
        adapter = wgpu.gpu.request_adapter_sync(power_preference="low-power")
    except Exception as e:  # noqa: BLE001
        pytest.skip(f"no WebGPU adapter: {e}")
    f32 = "float32-filterable" in adapter.features
    device = adapter.request_device_sync(required_features=["float32-filterable"] if f32 else [])
    b = bake
    n, v = pairs(count, seed=10)
    rho = np.linspace(0.03, 1.0, len(n))
    rng = np.random.default_rng(11)
    c, m = rng.uniform(size=(len(n), 3)), rng.uniform(size=len(n))
    main = """
@group(1) @binding(0) var<storage, read> hf_in: array<vec4<f32>>;
@group(1) @binding(1) var<storage, read_write> hf_out: array<vec4<f32>>;
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if (i >= arrayLength(&hf_out) / 4u) { return; }
    let n = hf_in[3u * i].xyz; let v = hf_in[3u * i + 1u].xyz; let c = hf_in[3u * i + 2u].xyz;
    let rho = hf_in[3u * i].w; let m = hf_in[3u * i + 1u].w;
    let o = homofac_ibl_terms(n, v, rho);
    hf_out[4u * i] = vec4<f32>(o.I_d, 0.0); hf_out[4u * i + 1u] = vec4<f32>(o.I_A, 0.0);
    hf_out[4u * i + 2u] = vec4<f32>(o.I_B, 0.0); hf_out[4u * i + 3u] = vec4<f32>(homofac_ibl(n, v, c, m, rho), 0.0);
}
"""
    module = device.create_shader_module(code=shader.source(b, "wgsl") + main)
    pipeline = device.create_compute_pipeline(layout="auto", compute={"module": module, "entry_point": "main"})
    sampler = device.create_sampler(mag_filter="linear", min_filter="linear", address_mode_u="clamp-to-edge",
                                    address_mode_v="clamp-to-edge")
    entries = []
    for k, (_, data) in enumerate(shader.texture_arrays(b)):
        H, W = data.shape[:2]
        rgba = data if data.shape[-1] == 4 else np.concatenate([data, np.ones((H, W, 1), np.float32)], -1)
        rgba = np.asarray(rgba).astype(np.float32 if f32 else np.float16)
        tex = device.create_texture(size=(W, H, 1), format="rgba32float" if f32 else "rgba16float",
                                    usage=wgpu.TextureUsage.TEXTURE_BINDING | wgpu.TextureUsage.COPY_DST)
        device.queue.write_texture({"texture": tex}, np.ascontiguousarray(rgba).tobytes(),
                                   {"bytes_per_row": W * rgba.itemsize * 4, "rows_per_image": H}, (W, H, 1))
        entries += [{"binding": 2 * k, "resource": tex.create_view()}, {"binding": 2 * k + 1, "resource": sampler}]
    inp = np.zeros((len(n), 3, 4), np.float32)
    inp[:, 0, :3], inp[:, 1, :3], inp[:, 2, :3], inp[:, 0, 3], inp[:, 1, 3] = n, v, c, rho, m
    buf_in = device.create_buffer_with_data(data=inp.tobytes(), usage=wgpu.BufferUsage.STORAGE)
    buf_out = device.create_buffer(size=len(n) * 64, usage=wgpu.BufferUsage.STORAGE | wgpu.BufferUsage.COPY_SRC)
    groups = [device.create_bind_group(layout=pipeline.get_bind_group_layout(0), entries=entries),
              device.create_bind_group(layout=pipeline.get_bind_group_layout(1), entries=[
                  {"binding": 0, "resource": {"buffer": buf_in}}, {"binding": 1, "resource": {"buffer": buf_out}}])]
    enc = device.create_command_encoder()
    cp = enc.begin_compute_pass()
    cp.set_pipeline(pipeline)
    for i, g in enumerate(groups):
        cp.set_bind_group(i, g)
    cp.dispatch_workgroups(-(-len(n) // 64))
    cp.end()
    device.queue.submit([enc.finish()])
    gpu = np.frombuffer(device.queue.read_buffer(buf_out), np.float32).reshape(len(n), 4, 4)[..., :3]
    cpu = np.concatenate([np.asarray(b.terms(n, v, rho)), np.asarray(b.evaluate(n, v, c, m, rho))[:, None]], axis=1)
    assert np.abs(gpu - cpu).max() <= (tol[0] if f32 else tol[1]) * np.abs(cpu).max()


def test_sharp_layers_share_one_block_and_round_trip(forest_bake):
    """Layers whose lobe is at most half a texel of the largest block share it (packed once, one offset in
    bake.json); the offsets read back give the same sharing; a layer may share only an earlier block of its size."""
    from homofac.bake.atlas import blocks_of, pack
    from homofac.bake.build import layer_size, sharp
    b = forest_bake
    assert b.blocks == tuple(0 if sharp(r, 8) else j for j, r in enumerate(b.roughness)) == (0, 0, 2)
    a = b.atlas
    assert a.offsets[0] == a.offsets[1] != a.offsets[2] and a.width * a.height == 2 * 6 * 8 * 8
    assert blocks_of(a.offsets, a.sizes) == b.blocks
    assert [layer_size(r, 64) for r in (0.045, 0.25, 0.5, 1.0)] == [64, 64, 16, 8]
    with pytest.raises(ValueError):
        pack([16, 8], [0, 0])  # different sizes
    with pytest.raises(ValueError):
        pack([8, 8, 8], [0, 2, 2])  # a later block
