"""The exported shaders (issue 14): every language compiled by a real compiler, and run where one can be.

What each check proves (docs/shaders.md, "How the shaders are checked"):

* GLSL 330 core and GLSL ES 3.00: ``glslangValidator`` (Khronos' reference front end) compiles the
  library behind ``#version 330 core`` / ``#version 300 es`` and a fragment ``main`` calling the
  pinned entry point; both are also *run* (headless OpenGL, moderngl over EGL) and equal
  ``fac.evaluate`` at random pairs;
* HLSL: glslang's HLSL front end compiles it (``-D -e ps_main -S frag -V``) to SPIR-V, which
  ``spirv-val`` validates; ``spirv-cross`` turns that SPIR-V into reference MSL and into GLSL 330,
  and the latter is run on the GPU and equals ``fac.evaluate`` -- so the HLSL's *meaning* is checked
  through SPIR-V (glslang is not Microsoft's DXC/FXC, which are not available here);
* MSL: no Metal compiler exists off Apple platforms. homofac's own MSL is compiled by ``clang++``
  (C++17, ``-Werror -Wconversion -Wdouble-promotion``) against :data:`METAL_SHIM`, a stand-in for
  ``<metal_stdlib>`` that declares only the Metal API the source uses, with strict constructors, and
  then *executed* on the CPU (the shim's sampler filters bilinearly with clamp to edge): it equals
  ``fac.evaluate``. This proves the source is well-formed C++ of the Metal API subset with the right
  numbers, not that Apple's compiler accepts every attribute; the MSL that spirv-cross derives from
  the HLSL is the cross-check;
* WGSL: wgpu-py (naga, on Mesa's lavapipe Vulkan CPU driver) validates the module and a compute
  pipeline using it, and runs it: it equals ``fac.evaluate``.

Missing tools skip with the package to install outside CI (``make test`` installs them first); in CI
(``CI`` set) a missing tool fails.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import homofac as hf
from homofac.app import view as viewer
from homofac.errors import HomofacError
from homofac.factorization import (Factor, Factorization, Term, Texture, check_identifier, check_label, check_texture_name,
                                   decode_texels)
from homofac.fit import structures
from homofac.fit.result import Result
from homofac.gl import device, engine
from homofac.output import shader_files
from homofac.param import mappers
from homofac.param import parametrizations as pz
from homofac.param import projections as pj
from homofac.shader import LANGUAGES, generate
from homofac.shader.languages import comment
from helpers import smooth_texture

RNG = np.random.default_rng(14)

#: Debian package of each external tool (the Makefile's SYSTEM_PACKAGES installs them).
PACKAGES = {"glslangValidator": "glslang-tools", "spirv-val": "spirv-tools", "spirv-cross": "spirv-cross",
            "clang++": "clang"}


def tool(name: str) -> str:
    path = shutil.which(name)
    if path is None:
        msg = f"{name} is not installed (Debian package {PACKAGES[name]}; `make system-packages` installs it)"
        if os.environ.get("CI"):
            pytest.fail(msg)
        pytest.skip(msg)
    return path


def run(cmd, **kw) -> subprocess.CompletedProcess:
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, timeout=120, **kw)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))}\n{r.stdout[-4000:]}\n{r.stderr[-4000:]}"
    return r


_BATCHES: dict[str, bool] = {}


@pytest.fixture(scope="module")
def batch_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("batch")


def batch_compiles(group: str, cmd: list, source, suffix: str, root: Path) -> bool:
    """Whether one run of ``cmd`` over ``source(name, quantized, y_up)`` of every case (one file each)
    succeeds, run once per ``group``.

    The compilers take several files per run and compile each separately, so one process replaces one per
    shader; a test whose batch fails compiles its own shaders alone, so the failure names the culprit."""
    if group not in _BATCHES:
        d = root / group
        d.mkdir()
        files = []
        for n in sorted(CASES):
            for q in (False, True):
                for y in (False, True):
                    files.append(d / f"{n}-{int(q)}{int(y)}{suffix}")
                    files[-1].write_text(source(n, q, y))
        r = subprocess.run([str(c) for c in (*cmd, *files)], capture_output=True, text=True, timeout=600)
        _BATCHES[group] = r.returncode == 0
    return _BATCHES[group]


# --------------------------------------------------------------------------------------------------
# Models: every mapper, one term and several terms (with every projection of the model's kind)

LIGHTING_MAPPERS = [m for m, r in mappers.MAPPERS.items() if r.covers_sphere]
BRDF_MAPPERS = [m for m, r in mappers.MAPPERS.items() if not r.covers_sphere and not r.scalar]


def model(mapper: str, terms: int) -> Result:
    """A hand-built model on ``mapper``: smooth positive and signed textures, a 1D ``line`` texture in
    the several-term case; ``mapper == "line"``: one term W(n.v)."""
    S = 8
    kind = "brdf" if mapper in BRDF_MAPPERS else "lighting"
    W = Texture("W", "line", 16, jnp.asarray(smooth_texture("line", 16, 3)))
    if mapper == "line":
        term = Term((Factor("nv", "W"),), jnp.asarray([0.5, 0.6, 0.7]))
        return Result(Factorization("lighting", "lighting", (W,), (term,), {}, "line"))
    A = Texture("A", mapper, S, jnp.asarray(smooth_texture(mapper, S, 1)))
    B = Texture("B", mapper, S, jnp.asarray(smooth_texture(mapper, S, 2, signed=True)))
    if kind == "brdf":
        all_terms = [Term((Factor("wi", "A"), Factor("h", "B"), Factor("wo", "A")), jnp.asarray([0.9, 0.8, 0.7])),
                     Term((Factor("d", "B"), Factor("cos_i", "W"), Factor("cos_o", "W")), jnp.asarray([0.3, 0.2, 0.1]))]
        ctx = {}
    else:
        all_terms = [Term((Factor("n", "A"), Factor("h_dom", "B")), jnp.asarray([0.9, 0.8, 0.7])),
                     Term((Factor("r", "B"), Factor("nv", "W"), Factor("v", "A")), jnp.asarray([0.3, 0.2, 0.1]), "prefiltered"),
                     Term((Factor("d_dom", "A"), Factor("r_off", "B"), Factor("nh_dom", "W"), Factor("nh_dom1", "W"),
                           Factor("nh_dom2", "W"), Factor("vh_dom", "W"), Factor("vh_dom1", "W"), Factor("vh_dom2", "W"),
                           Factor("ni_dom", "W"), Factor("ni_dom1", "W"), Factor("ni_dom2", "W"),
                           Factor("ninv_dom", "A"), Factor("ninv_dom1", "B"), Factor("ninv_dom2", "A"),
                           Factor("nhs_dom", "W"), Factor("nhs_dom1", "W"), Factor("nhs_dom2", "W")),
                          jnp.asarray([0.1, 0.2, 0.3]))]
        ctx = {k: jnp.asarray(v, jnp.float32) if np.ndim(v) else v for k, v in pj.example_context().items()}
    chosen = tuple(all_terms[:terms])
    used = {f.texture for t in chosen for f in t.factors}
    textures = tuple(t for t in (A, B, W) if t.name in used)
    return Result(Factorization(kind, kind, textures, chosen, ctx, f"{mapper}-{terms}"))


CASES = {f"{m}-{k}": (m, k) for m in [*LIGHTING_MAPPERS, *BRDF_MAPPERS] for k in (1, 3 if m in LIGHTING_MAPPERS else 2)}
CASES["line-1"] = ("line", 1)
_MODELS: dict = {}


def case(name: str) -> Result:
    if name not in _MODELS:
        _MODELS[name] = model(*CASES[name])
    return _MODELS[name]


def test_cases_cover_every_mapper_and_projection():
    used_m = {t.mapper for n in CASES for t in case(n).model.textures}
    used_p = {f.projection for n in CASES for term in case(n).model.terms for f in term.factors}
    assert used_m == set(mappers.MAPPERS)
    assert used_p == set(pj.PROJECTIONS)


def pairs(kind: str, n: int, rng=RNG):
    """Random valid pairs: (n, v) with n.v > 0 (lighting) or (wi, wo) above the horizon (BRDF)."""
    a = rng.normal(size=(n, 3))
    b = rng.normal(size=(n, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    if kind == "brdf":
        a[:, 2], b[:, 2] = np.abs(a[:, 2]), np.abs(b[:, 2])
    else:
        b = np.where(np.sum(a * b, axis=1, keepdims=True) < 0, -b, b)
    return a.astype(np.float32), b.astype(np.float32)


def entry(fac) -> str:
    return generate.ENTRY[fac.kind][0]


# --------------------------------------------------------------------------------------------------
# Minimal entry points per language (what a renderer adds around the library)

GLSL_MAIN = """
in vec3 hf_in_a;
in vec3 hf_in_b;
out vec4 hf_color;
void main() {{ hf_color = vec4({entry}(normalize(hf_in_a), normalize(hf_in_b)), 1.0); }}
"""
HLSL_MAIN = """
float4 ps_main(float3 a : TEXCOORD0, float3 b : TEXCOORD1) : SV_Target {{
    return float4({entry}(normalize(a), normalize(b)), 1.0);
}}
"""
WGSL_MAIN = """
@group(1) @binding(0) var<storage, read> hf_pairs: array<vec4<f32>>;
@group(1) @binding(1) var<storage, read_write> hf_result: array<vec4<f32>>;
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {{
    let i = id.x;
    if (i >= arrayLength(&hf_result)) {{ return; }}
    hf_result[i] = vec4<f32>({entry}(hf_pairs[2u * i].xyz, hf_pairs[2u * i + 1u].xyz), 1.0);
}}
"""


def wrapped(fac, language: str, quantized: bool = False, y_up: bool = False) -> str:
    src = fac.shader(language, quantized=quantized, y_up=y_up)
    e = entry(fac)
    if language == "glsl":
        return "#version 330 core\n" + src + GLSL_MAIN.format(entry=e)
    if language == "glsl_es":
        return "#version 300 es\nprecision highp float;\n" + src + GLSL_MAIN.format(entry=e)
    if language == "hlsl":
        return src + HLSL_MAIN.format(entry=e)
    if language == "wgsl":
        return src + WGSL_MAIN.format(entry=e)
    return src


# --------------------------------------------------------------------------------------------------
# Compilation


@pytest.mark.parametrize("quantized", [False, True], ids=["float", "8bit"])
@pytest.mark.parametrize("name", sorted(CASES))
@pytest.mark.parametrize("language", ["glsl", "glsl_es"])
def test_glsl_compiles_with_glslang(language, name, quantized, batch_dir, tmp_path):
    """glslangValidator accepts the library + a fragment main, as GLSL 330 core and as GLSL ES 3.00."""
    exe = tool("glslangValidator")
    if batch_compiles(language, [exe, "-S", "frag"], lambda n, q, y: wrapped(case(n), language, q, y_up=y),
                      ".frag", batch_dir):
        return
    for y_up in (False, True):  # the batch failed: compile this test's shaders alone, naming the culprit
        src = tmp_path / "shader.frag"
        src.write_text(wrapped(case(name), language, quantized, y_up=y_up))
        run([exe, "-S", "frag", src])


def hlsl_spirv(fac, quantized: bool, tmp_path: Path, y_up: bool = False) -> Path:
    exe = tool("glslangValidator")
    src = tmp_path / "shader.hlsl"
    src.write_text(wrapped(fac, "hlsl", quantized, y_up=y_up))
    spv = tmp_path / "shader.spv"
    run([exe, "-D", "-e", "ps_main", "-S", "frag", "-V", "-o", spv, src])
    run([tool("spirv-val"), spv])
    return spv


@pytest.mark.parametrize("quantized", [False, True], ids=["float", "8bit"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_hlsl_compiles_to_spirv_and_msl(name, quantized, tmp_path):
    """HLSL -> SPIR-V (glslang's HLSL front end) -> spirv-val -> spirv-cross MSL (the reference MSL)."""
    fac = case(name)
    spv = hlsl_spirv(fac, quantized, tmp_path)
    msl = run([tool("spirv-cross"), spv, "--msl", "--msl-version", "20000"]).stdout
    assert "fragment ps_main_out ps_main(" in msl
    for t in fac.model.textures:
        assert f"texture2d<float> hf_{t.name} [[texture(" in msl
    hlsl_spirv(fac, quantized, tmp_path, y_up=True)


#: A stand-in for Metal's <metal_stdlib>: the subset of the Metal API homofac's MSL uses, with Metal's
#: semantics for it (scalar-to-vector only explicitly, bilinear clamp-to-edge sampling of RGBA float
#: texels, row 0 at v = 0). Address spaces are erased; attributes such as [[id(k)]] are ignored.
METAL_SHIM = r"""
#pragma once
#include <cmath>
#define thread
#define device
#define constant const
namespace metal {
struct float2 {
    float x, y;
    float2(float a, float b) : x(a), y(b) {}
};
struct float3 {
    float x, y, z;
    float3() : x(0), y(0), z(0) {}
    explicit float3(float s) : x(s), y(s), z(s) {}
    float3(float a, float b, float c) : x(a), y(b), z(c) {}
};
inline float3 operator-(float3 a) { return float3(-a.x, -a.y, -a.z); }
#define HF_OP(OP) \
    inline float3 operator OP(float3 a, float3 b) { return float3(a.x OP b.x, a.y OP b.y, a.z OP b.z); } \
    inline float3 operator OP(float3 a, float s) { return float3(a.x OP s, a.y OP s, a.z OP s); } \
    inline float3 operator OP(float s, float3 a) { return float3(s OP a.x, s OP a.y, s OP a.z); }
HF_OP(+) HF_OP(-) HF_OP(*) HF_OP(/)
#undef HF_OP
struct float4 {
    float x, y, z, w;
    float3 rgb, xyz;
    float r, g, b, a;
    float4(float x_, float y_, float z_, float w_)
        : x(x_), y(y_), z(z_), w(w_), rgb(x_, y_, z_), xyz(x_, y_, z_), r(x_), g(y_), b(z_), a(w_) {}
};
inline float abs(float a) { return std::fabs(a); }
inline float sqrt(float a) { return std::sqrt(a); }
inline float floor(float a) { return std::floor(a); }
inline float max(float a, float b) { return std::fmax(a, b); }
inline float min(float a, float b) { return std::fmin(a, b); }
inline float clamp(float x, float lo, float hi) { return std::fmin(std::fmax(x, lo), hi); }
inline float atan2(float y, float x) { return std::atan2(y, x); }
inline float3 abs(float3 a) { return float3(abs(a.x), abs(a.y), abs(a.z)); }
inline float3 max(float3 a, float3 b) { return float3(max(a.x, b.x), max(a.y, b.y), max(a.z, b.z)); }
inline float3 min(float3 a, float3 b) { return float3(min(a.x, b.x), min(a.y, b.y), min(a.z, b.z)); }
inline float3 clamp(float3 x, float3 lo, float3 hi) {
    return float3(clamp(x.x, lo.x, hi.x), clamp(x.y, lo.y, hi.y), clamp(x.z, lo.z, hi.z));
}
inline float dot(float3 a, float3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline float3 cross(float3 a, float3 b) {
    return float3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
namespace coord { enum mode { normalized, pixel }; }
namespace filter { enum mode { nearest, linear }; }
namespace mip_filter { enum mode { none, nearest, linear }; }
namespace address { enum mode { clamp_to_edge, clamp_to_zero, repeat, mirrored_repeat }; }
struct sampler {
    constexpr sampler(coord::mode, filter::mode, mip_filter::mode, address::mode) {}
};
struct level {
    explicit level(float l) : lod(l) {}
    float lod;
};
template <typename T> struct texture2d {
    const float* data;  // RGBA, rows top to bottom (row 0 at v = 0)
    int width, height;
    float4 texel(int i, int j) const {
        i = i < 0 ? 0 : (i >= width ? width - 1 : i);
        j = j < 0 ? 0 : (j >= height ? height - 1 : j);
        const float* p = data + 4 * (j * width + i);
        return float4(p[0], p[1], p[2], p[3]);
    }
    float4 sample(sampler, float2 uv, level) const {
        float x = uv.x * (float)width - 0.5f, y = uv.y * (float)height - 0.5f;
        float x0 = std::floor(x), y0 = std::floor(y);
        float fx = x - x0, fy = y - y0;
        int i = (int)x0, j = (int)y0;
        float4 t[4] = {texel(i, j), texel(i + 1, j), texel(i, j + 1), texel(i + 1, j + 1)};
        float o[4];
        for (int k = 0; k < 4; ++k) {
            const float* c[4] = {&t[0].x, &t[1].x, &t[2].x, &t[3].x};
            o[k] = (c[0][k] * (1 - fx) + c[1][k] * fx) * (1 - fy) + (c[2][k] * (1 - fx) + c[3][k] * fx) * fy;
        }
        return float4(o[0], o[1], o[2], o[3]);
    }
};
}  // namespace metal
"""

CLANG_FLAGS = ["-std=c++17", "-Wall", "-Wextra", "-Werror", "-Wconversion", "-Wdouble-promotion",
               "-Wno-unknown-attributes", "-Wno-unused-function", "-Wno-unused-const-variable",
               "-Wno-unused-parameter"]


def metal_shim(tmp_path: Path) -> Path:
    """A directory holding the shim as ``metal_stdlib``; written once (a precompiled header built from it stays valid)."""
    d = tmp_path / "shim"
    d.mkdir(exist_ok=True)
    if not (d / "metal_stdlib").exists():
        (d / "metal_stdlib").write_text(METAL_SHIM)
    return d


def shim_pch(exe: str, shim: Path) -> Path:
    """The shim precompiled (once per directory): each shader's own parse of <cmath> was most of its clang CPU."""
    pch = shim / "metal_stdlib.pch"
    if not pch.exists():
        run([exe, *CLANG_FLAGS, "-x", "c++-header", shim / "metal_stdlib", "-o", pch])
    return pch


@pytest.mark.parametrize("quantized", [False, True], ids=["float", "8bit"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_msl_compiles_against_the_metal_shim(name, quantized, batch_dir, tmp_path):
    exe = tool("clang++")
    shim = metal_shim(batch_dir)
    assert "#include <metal_stdlib>" in case(name).shader("msl", quantized=quantized)  # the batch's -include-pch adds it
    if batch_compiles("msl", [exe, *CLANG_FLAGS, "-fsyntax-only", "-I", shim, "-include-pch", shim_pch(exe, shim),
                              "-x", "c++"],
                      lambda n, q, y: case(n).shader("msl", quantized=q, y_up=y), ".metal", batch_dir):
        return
    for y_up in (False, True):  # the batch failed: compile this test's shaders alone, naming the culprit
        src = tmp_path / "shader.metal"
        src.write_text(case(name).shader("msl", quantized=quantized, y_up=y_up))
        run([exe, *CLANG_FLAGS, "-fsyntax-only", "-I", shim, "-x", "c++", src])


def test_the_metal_shim_rejects_what_metal_rejects(tmp_path):
    """The shim is strict where C++ would be lax: an implicit float3 from a scalar and doubles fail."""
    exe = tool("clang++")
    shim = metal_shim(tmp_path)
    for bad in ("float3 f(float a) { float3 x = a; return x; }",
                "float f(float a) { return max(a, 1.0e-12); }"):
        src = tmp_path / "bad.metal"
        src.write_text("#include <metal_stdlib>\nusing namespace metal;\n" + bad + "\n")
        r = subprocess.run([exe, *CLANG_FLAGS, "-fsyntax-only", "-I", str(shim), "-x", "c++", str(src)],
                           capture_output=True, text=True, timeout=60)
        assert r.returncode != 0, bad


@pytest.fixture(scope="module")
def wgpu_device():
    try:
        import wgpu
    except ImportError:
        msg = "wgpu-py is not installed (pip install wgpu; the dev extra)"
        if os.environ.get("CI"):
            pytest.fail(msg)
        pytest.skip(msg)
    os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp")  # Mesa's Vulkan loader warns without it
    try:
        adapter = wgpu.gpu.request_adapter_sync(power_preference="low-power")
    except Exception as e:  # noqa: BLE001
        msg = f"no WebGPU adapter (Debian mesa-vulkan-drivers gives lavapipe): {e}"
        if os.environ.get("CI"):
            pytest.fail(msg)
        pytest.skip(msg)
    features = ["float32-filterable"] if "float32-filterable" in adapter.features else []
    return wgpu, adapter.request_device_sync(required_features=features), bool(features)


@pytest.mark.parametrize("quantized", [False, True], ids=["float", "8bit"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_wgsl_validates_with_naga(wgpu_device, name, quantized):
    """naga (inside wgpu) parses and validates the module, and a compute pipeline over it."""
    wgpu, device, _ = wgpu_device
    for y_up in (False, True):
        module = device.create_shader_module(code=wrapped(case(name), "wgsl", quantized, y_up=y_up))
        device.create_compute_pipeline(layout="auto", compute={"module": module, "entry_point": "main"})


def test_wgsl_rejects_a_broken_shader(wgpu_device):
    """The validation is real: a type error in WGSL raises."""
    wgpu, device, _ = wgpu_device
    with pytest.raises(Exception, match="(?i)valid"):
        device.create_shader_module(code="fn f() -> f32 { let a: i32 = 1.5; return 1.0; }")


# --------------------------------------------------------------------------------------------------
# Running: GPU (and the MSL on the CPU) equals fac.evaluate

#: case -> language -> {"float": relative RMS, "8bit": max |diff| / max |value| with RGBA8 textures,
#: "8bit_bound": that diff / the 1/255-per-texel bound, "8bit_exact": max |diff| / max |value| with the
#: 8-bit values in float textures}; printed by test_error_table.
ERRORS: dict = {}


def _record(name, language, what, value):
    ERRORS.setdefault(name, {}).setdefault(language, {})[what] = float(value)


def bound_8bit(fac) -> np.ndarray:
    """Per channel, the largest change of the 8-bit value when every filtered texel read is off by 1/255
    (in RGB and, with the alpha trick, in A): texture units may filter RGBA8 in 8-bit fixed point
    (Mesa's llvmpipe does: its results are rounded to 1/255), and the factors multiply those errors."""
    q = fac.encoded()
    model = fac.model
    decoded = decode_texels(q)
    top = [np.abs(d).reshape(-1, 3).max(axis=0) for d in decoded]
    one = [np.abs(np.asarray(s)) / 255 * (2 if alpha else 1) for s, alpha in zip(q.scale, q.alpha)]
    index = {t.name: k for k, t in enumerate(model.textures)}
    total = np.zeros(3)
    for c, term in zip(q.corrections, model.terms):
        ks = [index[f.texture] for f in term.factors]
        for i, k in enumerate(ks):
            prod = one[k].copy()
            for j, g in enumerate(ks):
                if j != i:
                    prod *= top[g] + one[g]
            total += np.abs(np.asarray(c)) * prod
    return total


def check(name: str, language: str, fac, a, b, gpu, quantized: bool, rgba8: bool = True):
    """Float textures: relative RMS <= 1e-3. 8-bit: with the 8-bit values in float textures (exact
    filtering) max |diff| <= 1/255 of the value range; with RGBA8 textures (``rgba8``) every channel
    within :func:`bound_8bit` (1/255 per filtered texel)."""
    cpu = np.asarray(fac.evaluate(a, b, quantized=quantized), np.float64)
    diff = np.asarray(gpu, np.float64) - cpu
    if quantized and rgba8:
        bound = bound_8bit(fac)
        worst = np.abs(diff).max(axis=0)
        _record(name, language, "8bit", worst.max() / np.abs(cpu).max())
        _record(name, language, "8bit_bound", (worst / bound).max())
        assert np.all(worst <= bound), (name, language, worst, bound)
    elif quantized:
        err = np.abs(diff).max() / np.abs(cpu).max()
        _record(name, language, "8bit_exact", err)
        assert err <= 1 / 255, (name, language, err)
    else:
        err = np.linalg.norm(diff) / np.linalg.norm(cpu)
        _record(name, language, "float", err)
        assert err <= 1e-3, (name, language, err)


VERTEX_QUAD = """#version 330 core
in vec2 hf_in_pos;
void main() { gl_Position = vec4(hf_in_pos, 0.0, 1.0); }
"""

#: The fragment main of the GPU check: one pair per pixel from two RGBA32F textures.
FRAGMENT_PAIRS = """
uniform sampler2D hf_pairs_a;
uniform sampler2D hf_pairs_b;
layout(location = 0) out vec4 hf_color;
void main() {{
    ivec2 p = ivec2(gl_FragCoord.xy);
    hf_color = vec4({entry}(texelFetch(hf_pairs_a, p, 0).xyz, texelFetch(hf_pairs_b, p, 0).xyz), 1.0);
}}
"""
HLSL_PAIRS = """
Texture2D<float4> hf_pairs_a;
Texture2D<float4> hf_pairs_b;
float4 ps_main(float4 pos : SV_Position) : SV_Target {{
    int3 p = int3(int(pos.x), int(pos.y), 0);
    return float4({entry}(hf_pairs_a.Load(p).xyz, hf_pairs_b.Load(p).xyz), 1.0);
}}
"""
WIDTH = 64


def render_pairs(fragment: str, fac, a, b, quantized: bool, names: dict | None = None, rgba8: bool = True) -> np.ndarray:
    """Render a quad with ``fragment`` (one pair per pixel) in the GL device process; ``names``: uniform
    of each sampler (default ``hf_<texture>``, ``hf_pairs_a``, ``hf_pairs_b``); ``rgba8=False`` uploads
    the 8-bit textures' values (RGBA / 255) as float textures. Returns (N, 3) float32."""
    n = len(a)
    H = -(-n // WIDTH)
    names = names or {}

    def pairs_texture(x):
        d = np.zeros((H * WIDTH, 4), np.float32)
        d[:n, :3] = x
        return d.reshape(H, WIDTH, 4)

    if quantized and not rgba8:
        arrays = gpu_textures(fac, True)
    else:
        arrays = engine.texture_arrays(fac.model, fac.encoded() if quantized else None)
    textures = engine.texture_specs([(names.get(f"hf_{t.name}", f"hf_{t.name}"), arr)
                                     for t, arr in zip(fac.model.textures, arrays)])
    textures += [(names.get(k, k), pairs_texture(x), "f4", "nearest") for k, x in (("hf_pairs_a", a), ("hf_pairs_b", b))]
    (px,) = device.call("draw", vertex=VERTEX_QUAD, fragment=fragment,
                        attributes=np.asarray([[-1, -1], [3, -1], [-1, 3]], np.float32), layout="2f",
                        names=["hf_in_pos"], textures=textures, size=(WIDTH, H))
    return px.reshape(-1, 4)[:n, :3].copy()


N_PAIRS = 4096


@pytest.mark.parametrize("quantized", [False, True], ids=["float", "8bit"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_glsl_es_is_the_glsl_code_with_highp_samplers(name, quantized):
    """The GLSL ES 3.00 library is the GLSL 330 one but for its first comment line and ``highp`` on its
    samplers, so test_glsl_render_equals_cpu's renders of the GLSL give its values too (glslang compiles it as
    ES in test_glsl_compiles_with_glslang; three.js runs it in test_threejs)."""
    fac = case(name)
    glsl = fac.shader("glsl", quantized=quantized).splitlines()
    es = fac.shader("glsl_es", quantized=quantized).splitlines()
    assert sum(line.startswith("// GLSL 330 core.") for line in glsl) == 1
    assert es == [line.replace("// GLSL 330 core.", "// GLSL ES 3.00.", 1).replace("uniform sampler2D ", "uniform highp sampler2D ")
                  for line in glsl]


@pytest.mark.parametrize("quantized", [False, True], ids=["float", "8bit"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_glsl_render_equals_cpu(name, quantized):
    """The exported GLSL, rendered headless with moderngl over random pairs, equals fac.evaluate (the GLSL ES
    library is the same code: test_glsl_es_is_the_glsl_code_with_highp_samplers)."""
    fac = case(name)
    a, b = pairs(fac.kind, N_PAIRS)
    src = fac.shader("glsl", quantized=quantized)
    frag = "#version 330 core\n" + src + FRAGMENT_PAIRS.format(entry=entry(fac))
    check(name, "glsl", fac, a, b, render_pairs(frag, fac, a, b, quantized), quantized)
    if quantized:  # the same 8-bit values, filtered exactly: the decode rule and constants to float rounding
        check(name, "glsl", fac, a, b, render_pairs(frag, fac, a, b, True, rgba8=False), True, rgba8=False)


@pytest.mark.parametrize("quantized", [False, True], ids=["float", "8bit"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_hlsl_through_spirv_equals_cpu(name, quantized, tmp_path):
    """HLSL -> SPIR-V (glslang) -> GLSL 330 (spirv-cross) rendered on the GPU equals fac.evaluate."""
    fac = case(name)
    src = tmp_path / "shader.hlsl"
    src.write_text(fac.shader("hlsl", quantized=quantized) + HLSL_PAIRS.format(entry=entry(fac)))
    spv = tmp_path / "shader.spv"
    run([tool("glslangValidator"), "-D", "-e", "ps_main", "-S", "frag", "-V", "-o", spv, src])
    glsl = run([tool("spirv-cross"), spv, "--version", "330", "--no-es"]).stdout
    names = {}
    for t in [*(f"hf_{t.name}" for t in fac.model.textures), "hf_pairs_a", "hf_pairs_b"]:
        found = re.findall(rf"uniform sampler2D (SPIRV_Cross_Combined{t}(?:sampler_{t}|SPIRV_Cross_DummySampler));", glsl)
        assert len(found) == 1, (t, glsl[:1500])
        names[t] = found[0]
    a, b = pairs(fac.kind, N_PAIRS)
    check(name, "hlsl", fac, a, b, render_pairs(glsl, fac, a, b, quantized, names), quantized)


MSL_DRIVER = """
#include <cstdio>
#include <vector>
#include "shader.metal"
int main(int argc, char** argv) {{
    FILE* f = std::fopen(argv[1], "rb");
    int header[2];  // textures, pairs
    if (std::fread(header, sizeof(int), 2, f) != 2) return 2;
    std::vector<std::vector<float>> data(header[0]);
    std::vector<int> w(header[0]), h(header[0]);
    for (int t = 0; t < header[0]; ++t) {{
        int shape[2];
        if (std::fread(shape, sizeof(int), 2, f) != 2) return 2;
        h[t] = shape[0]; w[t] = shape[1];
        data[t].resize(4 * (size_t)(w[t] * h[t]));
        if (std::fread(data[t].data(), sizeof(float), data[t].size(), f) != data[t].size()) return 2;
    }}
    std::vector<float> p(6 * (size_t)header[1]);
    if (std::fread(p.data(), sizeof(float), p.size(), f) != p.size()) return 2;
    std::fclose(f);
    HomofacTextures hf = {{ {init} }};
    FILE* o = std::fopen(argv[2], "wb");
    for (int i = 0; i < header[1]; ++i) {{
        const float* q = &p[6 * (size_t)i];
        float3 r = {entry}(float3(q[0], q[1], q[2]), float3(q[3], q[4], q[5]), hf);
        float out[3] = {{r.x, r.y, r.z}};
        std::fwrite(out, sizeof(float), 3, o);
    }}
    std::fclose(o);
    return 0;
}}
"""


def gpu_textures(fac, quantized: bool) -> list[np.ndarray]:
    """The textures as a GPU holds them: RGBA float32 (float RGB + alpha 1) or the 8-bit RGBA / 255."""
    if quantized:
        return [np.asarray(r, np.float32) / np.float32(255) for r in fac.encoded().rgba]
    out = []
    for t in fac.model.textures:
        d = np.asarray(t.data, np.float32)[..., :3]
        out.append(np.concatenate([d, np.ones(d.shape[:2] + (1,), np.float32)], axis=-1))
    return out


MSL_RUN_CASES = ["cube-3", "dual_paraboloid-1", "octahedral-3", "parabolic-2", "spherical-3", "hemispherical-1", "line-1"]


#: clang++'s flags for the executed MSL: the checks' own, optimized.
RUN_FLAGS = [*CLANG_FLAGS, "-Wno-sign-conversion", "-O1"]


def driver_pch(exe: str, shim: Path) -> Path:
    """The driver's headers and the shim precompiled with :data:`RUN_FLAGS` (once per directory): parsing
    <vector> and <cmath> was a third of each run's clang CPU. The shader still includes <metal_stdlib> itself
    (test_msl_compiles_against_the_metal_shim asserts it)."""
    pch = shim / "driver.pch"
    if not pch.exists():
        (shim / "driver.h").write_text("#include <cstdio>\n#include <vector>\n#include <metal_stdlib>\n")
        run([exe, *RUN_FLAGS, "-I", shim, "-x", "c++-header", shim / "driver.h", "-o", pch])
    return pch


@pytest.mark.parametrize("quantized", [False, True], ids=["float", "8bit"])
@pytest.mark.parametrize("name", MSL_RUN_CASES)
def test_msl_runs_on_the_cpu_and_equals_cpu(name, quantized, batch_dir, tmp_path):
    """homofac's MSL, compiled by clang++ against the shim and executed, equals fac.evaluate."""
    exe = tool("clang++")
    fac = case(name)
    shim = metal_shim(batch_dir)
    (tmp_path / "shader.metal").write_text(fac.shader("msl", quantized=quantized))
    init = ", ".join(f"{{data[{k}].data(), w[{k}], h[{k}]}}" for k in range(len(fac.model.textures)))
    (tmp_path / "main.cpp").write_text(MSL_DRIVER.format(init=init, entry=entry(fac)))
    binary = tmp_path / "run"
    run([exe, *RUN_FLAGS, "-I", shim, "-include-pch", driver_pch(exe, shim), "-I", tmp_path, tmp_path / "main.cpp",
         "-o", binary])
    a, b = pairs(fac.kind, N_PAIRS)
    texs = gpu_textures(fac, quantized)
    with open(tmp_path / "in.bin", "wb") as f:
        f.write(np.asarray([len(texs), len(a)], np.int32).tobytes())
        for t in texs:
            f.write(np.asarray(t.shape[:2], np.int32).tobytes())
            f.write(np.ascontiguousarray(t, np.float32).tobytes())
        f.write(np.concatenate([a, b], axis=1).astype(np.float32).tobytes())
    run([binary, tmp_path / "in.bin", tmp_path / "out.bin"])
    out = np.fromfile(tmp_path / "out.bin", np.float32).reshape(-1, 3)
    check(name, "msl", fac, a, b, out, quantized, rgba8=False)  # the shim filters exactly


def run_wgsl(wgpu_device, fac, a, b, quantized: bool, source: str | None = None) -> np.ndarray:
    """The WGSL compute main over the pairs on the wgpu device (lavapipe): (N, 3)."""
    wgpu, device, f32_filterable = wgpu_device
    module = device.create_shader_module(code=source or wrapped(fac, "wgsl", quantized))
    pipeline = device.create_compute_pipeline(layout="auto", compute={"module": module, "entry_point": "main"})
    sampler = device.create_sampler(mag_filter="linear", min_filter="linear", mipmap_filter="nearest",
                                    address_mode_u="clamp-to-edge", address_mode_v="clamp-to-edge")
    entries = []
    for k, data in enumerate(gpu_textures(fac, quantized)):
        H, W = data.shape[:2]
        if quantized:
            fmt, raw, row = "rgba8unorm", np.asarray(fac.encoded().rgba[k], np.uint8), 4 * W
        else:
            fmt = "rgba32float" if f32_filterable else "rgba16float"
            raw = data.astype(np.float32 if f32_filterable else np.float16)
            row = W * raw.itemsize * 4
        tex = device.create_texture(size=(W, H, 1), format=fmt,
                                    usage=wgpu.TextureUsage.TEXTURE_BINDING | wgpu.TextureUsage.COPY_DST)
        device.queue.write_texture({"texture": tex}, np.ascontiguousarray(raw).tobytes(),
                                   {"bytes_per_row": row, "rows_per_image": H}, (W, H, 1))
        entries += [{"binding": 2 * k, "resource": tex.create_view()}, {"binding": 2 * k + 1, "resource": sampler}]
    n = len(a)
    inp = np.zeros((n, 2, 4), np.float32)
    inp[:, 0, :3], inp[:, 1, :3] = a, b
    buf_in = device.create_buffer_with_data(data=inp.tobytes(), usage=wgpu.BufferUsage.STORAGE)
    buf_out = device.create_buffer(size=n * 16, usage=wgpu.BufferUsage.STORAGE | wgpu.BufferUsage.COPY_SRC)
    groups = [device.create_bind_group(layout=pipeline.get_bind_group_layout(0), entries=entries),
              device.create_bind_group(layout=pipeline.get_bind_group_layout(1), entries=[
                  {"binding": 0, "resource": {"buffer": buf_in}}, {"binding": 1, "resource": {"buffer": buf_out}}])]
    enc = device.create_command_encoder()
    cp = enc.begin_compute_pass()
    cp.set_pipeline(pipeline)
    for i, g in enumerate(groups):
        cp.set_bind_group(i, g)
    cp.dispatch_workgroups(-(-n // 64))
    cp.end()
    device.queue.submit([enc.finish()])
    return np.frombuffer(device.queue.read_buffer(buf_out), np.float32).reshape(n, 4)[:, :3].copy()


@pytest.mark.parametrize("quantized", [False, True], ids=["float", "8bit"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_wgsl_runs_on_wgpu_and_equals_cpu(wgpu_device, name, quantized):
    fac = case(name)
    a, b = pairs(fac.kind, N_PAIRS)
    check(name, "wgsl", fac, a, b, run_wgsl(wgpu_device, fac, a, b, quantized), quantized)


def test_error_table():
    """Prints the measured errors (pytest -s / -rA shows them): relative RMS (float), max/range (8-bit)."""
    if not ERRORS:
        pytest.skip("no GPU-vs-CPU test ran in this process")
    langs = ["glsl", "hlsl", "msl", "wgsl"]
    cols = ["float", "8bit", "8bit_bound", "8bit_exact"]
    lines = ["float: relative RMS; 8bit: max |diff| / max |value| (RGBA8 textures), 8bit_bound: the same diff / "
             "the 1/255-per-texel bound; 8bit_exact: 8-bit values in float textures",
             f"{'case':20s} {'language':8s} " + " ".join(f"{c:>11s}" for c in cols)]
    for name in sorted(ERRORS):
        for lang in langs:
            e = ERRORS[name].get(lang)
            if e:
                lines.append(f"{name:20s} {lang:8s} " + " ".join(
                    f"{e[c]:11.2e}" if c in e else f"{'-':>11s}" for c in cols))
    print("\n" + "\n".join(lines), file=sys.stderr)


# --------------------------------------------------------------------------------------------------
# The interface: per-term functions, the y-up define, the files written


def test_per_term_functions_sum_to_the_value():
    """homofac_term(k, a, b) is term k of the model (Factorization.term_values); k out of range is 0;
    <entry>_term applies the entry point's validity test."""
    fac = case("cube-3")
    a, b = pairs("lighting", 2000)
    lib = generate.source(fac.model, "glsl")
    per = [engine.run_glsl(lib, f"homofac_term({k}, a, b)", a, b, textures=_bound(fac)) for k in range(4)]
    cpu = np.asarray(fac.model.term_values(a, b))
    for k in range(3):
        np.testing.assert_allclose(per[k], cpu[k], rtol=1e-5, atol=1e-6)
    assert not per[3].any()
    assert "const int HOMOFAC_TERMS = 3;" in lib
    b_bad = -a  # n.v < 0: invalid, 0
    for k in range(3):
        assert not engine.run_glsl(lib, f"homofac_radiance_term({k}, a, b)", a, b_bad, textures=_bound(fac)).any()


def _bound(fac, quantized=False):
    arrays = engine.texture_arrays(fac.model, fac.encoded() if quantized else None)
    return [(f"hf_{t.name}", arr) for t, arr in zip(fac.model.textures, arrays)]


def test_y_up_define_swizzles_into_homofacs_frame():
    """With HOMOFAC_Y_UP, homofac_radiance(n', v') of the y-up vectors (x, z, -y) is homofac's value at (n, v)."""
    fac = case("octahedral-3")
    a, b = pairs("lighting", 2000)
    up = lambda d: np.stack([d[:, 0], d[:, 2], -d[:, 1]], axis=1)  # noqa: E731 - homofac (x, y, z) in y-up
    lib = fac.shader("glsl", y_up=True)
    assert "#define HOMOFAC_Y_UP" in lib and "#define HOMOFAC_Y_UP" not in fac.shader("glsl")
    gpu = engine.run_glsl(lib, "homofac_radiance(a, b)", up(a), up(b), textures=_bound(fac))
    np.testing.assert_allclose(gpu, np.asarray(fac.evaluate(a, b)), rtol=1e-5, atol=1e-6)
    assert "const HOMOFAC_Y_UP: bool = true;" in fac.shader("wgsl", y_up=True)


@pytest.mark.parametrize("language", ["glsl", "wgsl"])
def test_flip_v_reads_textures_stored_bottom_up(language, wgpu_device):
    """HOMOFAC_FLIP_V: the textures uploaded with their rows reversed (as Unity stores them) give the same value."""
    fac = case("cube-3")
    a, b = pairs("lighting", 2000)
    flipped = Result(fac.model.replace_data([np.asarray(t.data)[::-1] for t in fac.model.textures]))
    if language == "glsl":
        lib = generate.source(fac.model, "glsl", flip_v=True)
        assert "#define HOMOFAC_FLIP_V" in lib
        gpu = engine.run_glsl(lib, "homofac_radiance(a, b)", a, b, textures=_bound(flipped))
    else:
        src = generate.source(fac.model, "wgsl", flip_v=True) + WGSL_MAIN.format(entry="homofac_radiance")
        assert "const HOMOFAC_FLIP_V: bool = true;" in src
        fake = Result(fac.model.replace_data([np.asarray(t.data)[::-1] for t in fac.model.textures]))
        gpu = run_wgsl(wgpu_device, fake, a, b, False, source=src)
    np.testing.assert_allclose(gpu, np.asarray(fac.evaluate(a, b)), rtol=1e-5, atol=1e-6)


def test_save_writes_every_shader_beside_the_textures(tmp_path):
    fac = case("dual_paraboloid-3")
    out = fac.save(tmp_path / "out", shaders=list(LANGUAGES), png=True)
    names = sorted(p.name for p in Path(out).iterdir() if p.name.startswith("shader"))
    assert names == sorted(shader_files(list(LANGUAGES), True)) == sorted(
        ["shader.glsl", "shader_es.glsl", "shader.hlsl", "shader.metal", "shader.wgsl", "shader_8bit.glsl",
         "shader_es_8bit.glsl", "shader_8bit.hlsl", "shader_8bit.metal", "shader_8bit.wgsl"])
    loaded = hf.output.load(out)
    # what was written is what the loaded directory generates (decode rules and corrections baked in)
    assert (Path(out) / "shader.glsl").read_text() == loaded.shader("glsl")
    assert (Path(out) / "shader_8bit.metal").read_text() == loaded.shader("msl", quantized=True)
    for t in fac.model.textures:
        assert f"uniform highp sampler2D hf_{t.name};" in (Path(out) / "shader_es.glsl").read_text()


# --------------------------------------------------------------------------------------------------
# The engine recipes (docs/recipes/): their code, extracted from the pages, compiles and runs

RECIPES = Path(__file__).resolve().parents[1] / "docs" / "recipes"


def recipe(page: str, name: str) -> str:
    """The fenced code block after ``<!-- recipe: name -->`` in ``docs/recipes/<page>``."""
    text = (RECIPES / page).read_text()
    m = re.search(rf"<!-- recipe: {re.escape(name)} -->\s*```[a-z]*\n(.*?)\n```", text, re.S)
    assert m, f"{page}: no code block marked {name}"
    return m.group(1)


#: What three.js (r15x-r17x) puts before a ShaderMaterial's code with glslVersion: THREE.GLSL3 and
#: defines {HOMOFAC_Y_UP: ""}: its built-in uniforms and attributes (an emulation; three.js is not run).
THREE_VERTEX_PREFIX = """#version 300 es
#define attribute in
#define varying out
#define texture2D texture
precision highp float;
precision highp int;
precision highp sampler2D;
#define HOMOFAC_Y_UP 
uniform mat4 modelMatrix;
uniform mat4 modelViewMatrix;
uniform mat4 projectionMatrix;
uniform mat4 viewMatrix;
uniform mat3 normalMatrix;
uniform vec3 cameraPosition;
uniform bool isOrthographic;
in vec3 position;
in vec3 normal;
in vec2 uv;
"""
THREE_FRAGMENT_PREFIX = """#version 300 es
#define varying in
layout(location = 0) out highp vec4 pc_fragColor;
#define gl_FragColor pc_fragColor
#define texture2D texture
precision highp float;
precision highp int;
precision highp sampler2D;
#define HOMOFAC_Y_UP 
uniform mat4 viewMatrix;
uniform vec3 cameraPosition;
uniform bool isOrthographic;
"""


def test_threejs_recipe_parses_and_its_shaders_compile(tmp_path):
    js = recipe("threejs.md", "threejs-js")
    node = shutil.which("node")
    if node is None:
        pytest.fail("node is not installed") if os.environ.get("CI") else pytest.skip("node is not installed")
    (tmp_path / "recipe.mjs").write_text(js)
    run([node, "--check", tmp_path / "recipe.mjs"])
    vertex = re.search(r"const VERTEX = `(.*?)`;", js, re.S).group(1)
    main = re.search(r"const FRAGMENT_MAIN = `(.*?)`;", js, re.S).group(1)
    main = "\n".join(line for line in main.splitlines() if not line.strip().startswith("#include <"))
    exe = tool("glslangValidator")
    (tmp_path / "v.vert").write_text(THREE_VERTEX_PREFIX + vertex)
    run([exe, "-S", "vert", tmp_path / "v.vert"])
    for name in ("dual_paraboloid-3", "cube-1"):
        for q in (False, True):
            (tmp_path / "f.frag").write_text(THREE_FRAGMENT_PREFIX + case(name).shader("glsl_es", quantized=q) + main)
            run([exe, "-S", "frag", tmp_path / "f.frag"])


UNITY_PS = """
#include "HomofacUnity.hlsl"
Texture2D<float4> hf_pairs_a;
Texture2D<float4> hf_pairs_b;
float4 ps_main(float4 pos : SV_Position) : SV_Target {
    int3 p = int3(int(pos.x), int(pos.y), 0);
    float3 radiance;
    HomofacRadiance_float(hf_pairs_a.Load(p).xyz, hf_pairs_b.Load(p).xyz, radiance);
    return float4(radiance, 1.0);
}
"""


@pytest.mark.parametrize("name", ["octahedral-3", "line-1"])
def test_unity_recipe_compiles_and_runs_through_spirv(name, tmp_path):
    """HomofacUnity.hlsl + shader.hlsl compile (glslang HLSL); run through SPIR-V -> GLSL with Unity's
    left-handed y-up vectors and textures stored bottom-up, it equals fac.evaluate."""
    fac = case(name)
    (tmp_path / "HomofacUnity.hlsl").write_text(recipe("unity.md", "unity-hlsl"))
    (tmp_path / "shader.hlsl").write_text(fac.shader("hlsl"))
    (tmp_path / "ps.hlsl").write_text(UNITY_PS)
    spv = tmp_path / "ps.spv"
    run([tool("glslangValidator"), "-D", "-e", "ps_main", "-S", "frag", "-V", "-I" + str(tmp_path), "-o", spv,
         tmp_path / "ps.hlsl"])
    run([tool("spirv-val"), spv])
    glsl = run([tool("spirv-cross"), spv, "--version", "330", "--no-es"]).stdout
    names = {}
    for t in [*(f"hf_{t.name}" for t in fac.model.textures), "hf_pairs_a", "hf_pairs_b"]:
        found = re.findall(rf"uniform sampler2D (SPIRV_Cross_Combined{t}(?:sampler_{t}|SPIRV_Cross_DummySampler));", glsl)
        assert len(found) == 1, (t, glsl[:1500])
        names[t] = found[0]
    a, b = pairs(fac.kind, N_PAIRS)
    unity = lambda d: d[:, [0, 2, 1]]  # noqa: E731 - homofac (x, y, z) is Unity's (x, z, y)
    stored = Result(fac.model.replace_data([np.asarray(t.data)[::-1] for t in fac.model.textures]))  # bottom-up
    gpu = render_pairs(glsl, stored, unity(a), unity(b), False, names)
    check(name, "unity", fac, a, b, gpu, False)


def test_opengl_recipe_program_renders_the_factorization(tmp_path):
    """docs/recipes/opengl.md's complete program, run on a saved output directory: its sphere.png equals
    fac.evaluate at the normals it ray-casts (within 2/255 after its gamma curve)."""
    fac = case("cube-3")
    out = fac.save(tmp_path / "out", shaders=["glsl"])
    (tmp_path / "render_sphere.py").write_text(recipe("opengl.md", "opengl-python"))
    size = 64
    r = run([sys.executable, tmp_path / "render_sphere.py", out, size, 1.0], cwd=tmp_path)
    assert "wrote sphere.png" in r.stdout
    from PIL import Image

    img = np.asarray(Image.open(tmp_path / "sphere.png").convert("RGB")).astype(int)
    c = (np.arange(size) + 0.5) / size * 2 - 1
    x, y = np.meshgrid(c, -c)  # rows top to bottom
    r2 = x * x + y * y
    inside = r2 < 0.97
    n = np.stack([np.sqrt(np.clip(1 - r2, 0, 1)), x, y], -1)[inside].astype(np.float32)
    v = np.tile(np.asarray([[1.0, 0.0, 0.0]], np.float32), (len(n), 1))
    want = np.round(np.clip(np.asarray(fac.evaluate(n, v)), 0, 1) ** (1 / 2.2) * 255)
    diff = np.abs(img[inside] - want).max()
    assert diff <= 2, diff
    assert (img[r2 > 1.03] == 0).all()


# --------------------------------------------------------------------------------------------------
# Names from a document never become code (issue 40): keywords compile, the generator's names are reserved

#: Texture names that are keywords, types or built-ins of some language (each becomes ``hf_<name>``).
KEYWORD_NAMES = ["float", "return", "texture", "main", "uniform", "discard", "float3", "SamplerState", "register",
                 "kernel", "device", "constant", "fn", "let", "var", "f32", "select", "Texture2D"]


def keyword_model() -> Result:
    """A two-term lighting model whose textures are named by :data:`KEYWORD_NAMES` (a line texture among them)."""
    names = KEYWORD_NAMES
    tex = [Texture(n, "line" if k == 0 else "dual_paraboloid", 4, jnp.asarray(
        smooth_texture("line" if k == 0 else "dual_paraboloid", 4, k))) for k, n in enumerate(names)]
    directions = ["n", "r", "v"]
    f1 = [Factor("nv", names[0])] + [Factor(directions[k % 3], n) for k, n in enumerate(names[1:9])]
    f2 = [Factor(directions[k % 3], n) for k, n in enumerate(names[9:])]
    terms = (Term(tuple(f1), jnp.asarray([0.5, 0.5, 0.5]), "fn"), Term(tuple(f2), jnp.asarray([0.1, 0.2, 0.3]), "float"))
    return Result(Factorization("lighting", "lighting", tuple(tex), terms, {}, "return x"))


def test_texture_names_that_are_keywords_compile_in_every_language(tmp_path, wgpu_device):
    """``hf_`` prefixes every texture identifier, so a keyword or built-in of any language is a valid name."""
    fac = keyword_model()
    glslang, clang, shim = tool("glslangValidator"), tool("clang++"), metal_shim(tmp_path)
    wgpu, device_, _ = wgpu_device
    for quantized in (False, True):
        for language in ("glsl", "glsl_es"):
            (tmp_path / "k.frag").write_text(wrapped(fac, language, quantized))
            run([glslang, "-S", "frag", tmp_path / "k.frag"])
        hlsl_spirv(fac, quantized, tmp_path)
        (tmp_path / "k.metal").write_text(fac.shader("msl", quantized=quantized))
        run([clang, *CLANG_FLAGS, "-fsyntax-only", "-I", shim, "-x", "c++", tmp_path / "k.metal"])
        module = device_.create_shader_module(code=wrapped(fac, "wgsl", quantized))
        device_.create_compute_pipeline(layout="auto", compute={"module": module, "entry_point": "main"})


def _own_identifiers(text: str, model) -> set[str]:
    """The ``hf_`` identifiers of ``text`` that are not the per-texture ones of ``model``'s textures."""
    per_texture = set()
    for t in model.textures:
        per_texture |= {f"hf_{t.name}", f"hf_sample_{t.name}", f"hf_sample_alpha_{t.name}", f"hf_{t.name}_sampler"}
    return set(re.findall(r"\bhf_\w+", text)) - per_texture


def test_the_generators_own_names_are_reserved_texture_names():
    """Every ``hf_`` identifier the generator (or a preview's main) writes that is not derived from a texture
    name is reserved: no texture name can produce it, so no texture collides with the generator's names."""
    own = _own_identifiers(engine.FRAGMENT_MAIN + viewer.SCRIPT, keyword_model().model)
    for name in sorted(CASES):
        fac = case(name)
        for language in LANGUAGES:
            for quantized in (False, True):
                own |= _own_identifiers(fac.shader(language, quantized=quantized), fac.model)
    assert {"hf_normalize", "hf_local", "hf_flip_v", "hf_sampler", "hf_srgb", "hf_viridis"} <= own
    assert any(n.startswith("hf_proj_") for n in own) and any(n.startswith("hf_map_") for n in own)
    for ident in own:
        with pytest.raises(HomofacError, match="reserved"):
            check_texture_name(ident[3:])
    for name in ("sample_E", "alpha_E", "E_sampler", "proj_n", "map_cube"):  # the per-texture forms
        with pytest.raises(HomofacError, match="reserved"):
            check_texture_name(name)


@pytest.mark.parametrize("bad", ["normalize", "proj_n", "sample_A", "local", "NR\n    return vec3(1e9);\n//",
                                 "a__b", "_x", "1x", "x" * 65, "é", "A-B", ""])
def test_a_model_refuses_texture_names_that_are_not_safe_in_code(bad):
    """A texture called ``normalize`` made ``hf_normalize`` twice (a shader that does not compile); a name with a
    newline put code into the shader. Both are refused when the model is built, whoever builds it."""
    W = Texture(bad, "line", 8, jnp.asarray(smooth_texture("line", 8, 3)))
    with pytest.raises(HomofacError) as e:
        Factorization("lighting", "lighting", (W,), (Term((Factor("nv", bad),), jnp.ones(3)),), {}, "line")
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("field", ["name", "kind"])
def test_a_model_refuses_names_and_kinds_that_are_not_safe_in_code(field):
    W = Texture("W", "line", 8, jnp.asarray(smooth_texture("line", 8, 3)))
    hostile = "NR\n    return vec3(1e9);\n//"
    name, kind = (hostile, "fitted") if field == "name" else ("line", hostile)
    with pytest.raises(HomofacError) as e:
        Factorization("lighting", "lighting", (W,), (Term((Factor("nv", "W"),), jnp.ones(3), kind),), {}, name)
    assert "\n" not in str(e.value)


def test_comments_cannot_be_broken_out_of():
    """:func:`homofac.shader.languages.comment`: whatever the text, one line of printable ASCII without a
    comment delimiter or a line continuation."""
    for text in ["a\nb", "x */ y", "/* z", "*//*/", "q\\", "\u2028\u2029\x85\r\x0b\x0c", "é ∑ 😀", "??/"]:
        c = comment(text)
        assert all(" " <= ch <= "~" for ch in c) and "*/" not in c and "/*" not in c and "\\" not in c, (text, c)
    assert comment("E'+NRW x2+R") == "E'+NRW x2+R"


def test_every_name_homofac_writes_follows_the_name_rules():
    """The pinned rules admit what homofac itself writes: the textures, kinds and labels of every registered
    parametrization and of every structure the chooser may fit (with tables, highlight lines, the split sum)."""
    seen = 0
    for kind in ("lighting", "brdf"):
        for p in pz.names(kind):
            check_label(p)
            for t in pz.get(p, kind).textures:
                check_texture_name(t)
        quantity = "lighting" if kind == "lighting" else "brdf"
        mapper = "dual_paraboloid" if kind == "lighting" else "parabolic"
        for table in (False, True):
            for s in structures.candidates(kind, 24, table=table) + structures.ladder(kind, 24, table=table):
                check_label(s.label())
                specs, terms = structures.skeleton(s, kind, quantity, mapper, 8)
                for spec in specs:
                    check_texture_name(spec.name)
                for term in terms:
                    check_identifier(term.kind, "kind")
                seen += 1
    assert seen > 100
    for name in ("split_sum", "kautz_mccool"):
        check_label(name)
