"""Shader source of a bake: ``homofac_ibl`` and ``homofac_ibl_terms`` (pinned, docs/format.md), GLSL, GLSL ES, HLSL.

The cube mapper's formula is the record's (``hf_map_cube`` traced by :func:`homofac.shader.generate.
mapper_function`); the rest is the model of :mod:`.model` written once for the GLSL family:

* ``hf_P<k>``: layer atlases (:mod:`.atlas`); a layer's texel is read at the cube mapper's per-face clamped
  coordinate plus the layer's offset, so the hardware's bilinear filter reads the four texels the CPU reads;
  the two layers around u(rho) are read and blended by hand (2 lookups per P_k);
* ``hf_E<d>``: cube-layout diffuse maps (1 lookup each), or with the plan's ``diffuse_basis`` ``sh9`` their 9
  SH coefficients as constants, ``hf_sh9_<d>(n)`` (no lookup); ``hf_W<t>``: weight tables, rows = layers, columns
  = n.v, read bilinearly at (n.v, u) (1 lookup each, 3 channels);
* every texture linear, clamp to edge, no mipmaps, rows in file order (``HOMOFAC_FLIP_V`` as for
  ``homofac_radiance``); ``HOMOFAC_Y_UP`` maps a y-up engine frame (x, y, z) -> (x, -z, y).
"""

from __future__ import annotations

import numpy as np

from .._version import __version__
from ..errors import HomofacError
from ..light.sh import SH9_NORM
from ..shader import generate
from ..shader import languages as L
from .atlas import assemble
from .model import Bake

LANGUAGES = ("glsl", "glsl_es", "hlsl")


def _f(x: float) -> str:
    return L.float_literal(float(x))


def source(bake: Bake, language: str = "glsl", *, y_up: bool = False, flip_v: bool = False) -> str:
    """The GLSL (330) or GLSL ES (3.00) source of ``bake``'s two pinned functions; no ``#version`` line."""
    if language not in LANGUAGES:
        raise HomofacError(f"bake shaders are generated for {', '.join(LANGUAGES)}; {language!r} is not supported yet")
    lang = L.get("glsl" if language == "hlsl" else language)
    pl = bake.plan
    atlas = bake.atlas
    K, D, layers, X = pl.terms, pl.diffuse, pl.layers, pl.nv_size
    se = pl.diffuse_size
    cube_src, tables = generate.mapper_function(L.get(language), "cube")
    prec = "highp " if language == "glsl_es" else ""
    lines = [
        f"// homofac {__version__}: material-parametric bake ({pl.preset}), {bake.lookups} texture lookups per pixel.",
        f"// {L.get(language).title}. Generated from the bake's records; the interface is pinned (docs/format.md).",
        "// Frame: homofac world, +z up; n, v point away from the surface (v towards the viewer).",
    ]
    if language != "hlsl":
        lines += ["#ifdef GL_ES", "precision highp float;", "precision highp int;", "#endif"]
    if y_up:
        lines.append("#define HOMOFAC_Y_UP")
    if flip_v:
        lines.append("#define HOMOFAC_FLIP_V")
    lines += [L.table_source(L.get(language), n, v) for n, v in tables.items()]
    for k in range(K):
        lines.append(f"uniform {prec}sampler2D hf_P{k};  // P{k}.exr: {layers} layers in a {atlas.width} x {atlas.height} atlas")
    sh9 = pl.diffuse_basis == "sh9"
    for d in range(D if not sh9 else 0):
        lines.append(f"uniform {prec}sampler2D hf_E{d};  // E{d}.exr: cube {se}")
    for t in range(pl.tables):
        lines.append(f"uniform {prec}sampler2D hf_W{t};  // W{t}.exr: {layers} x {X} weight table")
    rows = ", ".join(f"vec4({_f(x)}, {_f(y)}, {_f(s)}, {_f(sh)})"
                     for (x, y), s, sh in zip(atlas.offsets, atlas.sizes, bake.shift))
    lines += [
        f"const int HF_LAYERS = {layers};",
        f"const float HF_RHO0 = {_f(bake.roughness[0])};",
        f"const float HF_RHO1 = {_f(bake.roughness[-1])};",
        f"const vec2 HF_ATLAS = vec2({_f(atlas.width)}, {_f(atlas.height)});",
        f"const vec4 HF_LAYER[{layers}] = vec4[{layers}]({rows});  // x0, y0, face size, axis shift",
        "#ifdef HOMOFAC_FLIP_V",
        "float hf_flip_v(float v) { return 1.0 - v; }",
        "#else",
        "float hf_flip_v(float v) { return v; }",
        "#endif",
        cube_src,
        "vec3 hf_layer(sampler2D t, vec4 layer, vec3 d) {  // layer (x0, y0, S, shift) of an atlas at direction d",
        "    vec3 fuv = hf_map_cube(d);",
        "    float s = layer.z;",
        "    float cu = clamp(fuv.y * s - 0.5, 0.0, s - 1.0);",
        "    float cv = clamp(fuv.z * s - 0.5, 0.0, s - 1.0);",
        "    vec2 uv = vec2(layer.x + floor(fuv.x + 0.5) * s + cu + 0.5, layer.y + cv + 0.5) / HF_ATLAS;",
        "    return textureLod(t, vec2(uv.x, hf_flip_v(uv.y)), 0.0).rgb;",
        "}",
        "vec3 hf_cube(sampler2D t, float s, vec3 d) {  // a cube-layout texture of face size s at direction d",
        "    vec3 fuv = hf_map_cube(d);",
        "    float cu = clamp(fuv.y * s - 0.5, 0.0, s - 1.0);",
        "    float cv = clamp(fuv.z * s - 0.5, 0.0, s - 1.0);",
        "    vec2 uv = vec2((floor(fuv.x + 0.5) * s + cu + 0.5) / (6.0 * s), (cv + 0.5) / s);",
        "    return textureLod(t, vec2(uv.x, hf_flip_v(uv.y)), 0.0).rgb;",
        "}",
    ]
    if sh9:
        lines += [_sh9_function(d, np.asarray(bake.sh)[d]) for d in range(D)]
    body = [
        "void homofac_ibl_terms(vec3 n, vec3 v, float roughness, out vec3 I_d, out vec3 I_A, out vec3 I_B) {",
        "#ifdef HOMOFAC_Y_UP",
        "    n = vec3(n.x, -n.z, n.y);",
        "    v = vec3(v.x, -v.z, v.y);",
        "#endif",
        "    I_d = vec3(0.0); I_A = vec3(0.0); I_B = vec3(0.0);",
        "    float x = dot(n, v);",
        "    if (x <= 0.0) { return; }",
        "    vec3 r = 2.0 * x * n - v;",
        "    float rho = clamp(roughness, HF_RHO0, HF_RHO1);",
        "    float u = clamp(float(HF_LAYERS - 1) * log(rho / HF_RHO0) / log(HF_RHO1 / HF_RHO0), 0.0, float(HF_LAYERS - 1));",
        "    int j = min(int(floor(u)), HF_LAYERS - 2);",
        "    float t = u - float(j);",
        "    vec4 l0 = HF_LAYER[j];",
        "    vec4 l1 = HF_LAYER[j + 1];",
        "    vec3 a0 = normalize(mix(r, n, l0.w));",
        "    vec3 a1 = normalize(mix(r, n, l1.w));",
        f"    vec2 wuv = vec2((clamp(x * {_f(X)} - 0.5, 0.0, {_f(X - 1)}) + 0.5) / {_f(X)}, (u + 0.5) / {_f(layers)});",
        "    wuv.y = hf_flip_v(wuv.y);",
    ]
    chans = []
    for t in range(pl.tables):
        body.append(f"    vec3 w{t} = textureLod(hf_W{t}, wuv, 0.0).rgb;")
        chans += [f"w{t}.{c}" for c in "rgb"]
    for k in range(K):
        body.append(f"    vec3 p{k} = mix(hf_layer(hf_P{k}, l0, a0), hf_layer(hf_P{k}, l1, a1), t);")
        body.append(f"    I_A += p{k} * {chans[2 * k]};")
        body.append(f"    I_B += p{k} * {chans[2 * k + 1]};")
    for d in range(D):
        read = f"hf_sh9_{d}(n)" if sh9 else f"hf_cube(hf_E{d}, {_f(se)}, n)"
        body.append(f"    I_d += {read} * {chans[2 * K + d]};")
    body.append("}")
    entry = [
        "vec3 homofac_ibl(vec3 n, vec3 v, vec3 base_color, float metallic, float roughness) {",
        "    vec3 I_d, I_A, I_B;",
        "    homofac_ibl_terms(n, v, roughness, I_d, I_A, I_B);",
        "    vec3 f0 = mix(vec3(0.04), base_color, metallic);  // (1 - m) 0.04 + m c",
        "    return (1.0 - metallic) * 0.96 * base_color * I_d + f0 * I_A + I_B;",
        "}",
    ]
    text = "\n".join(lines + body + entry) + "\n"
    return _to_hlsl(text, bake) if language == "hlsl" else text


def _sh9_function(d: int, c) -> str:
    """``vec3 hf_sh9_<d>(vec3 n)``: sum_i c_i Y_i(n) with the constants folded into the coefficients (the
    polynomials 1, y, z, x, xy, yz, 3z^2 - 1, xz, x^2 - y^2 of :mod:`homofac.light.sh`, +z up)."""
    k = np.asarray(c, np.float64) * SH9_NORM[:, None]
    v = [f"vec3({_f(r)}, {_f(g)}, {_f(b)})" for r, g, b in k]
    return (f"vec3 hf_sh9_{d}(vec3 n) {{  // E{d}(n) from its 9 SH coefficients (no texture)\n"
            f"    return {v[0]} + {v[1]} * n.y + {v[2]} * n.z + {v[3]} * n.x\n"
            f"         + {v[4]} * (n.x * n.y) + {v[5]} * (n.y * n.z) + {v[6]} * (3.0 * n.z * n.z - 1.0)\n"
            f"         + {v[7]} * (n.x * n.z) + {v[8]} * (n.x * n.x - n.y * n.y);\n}}")


#: GLSL -> HLSL spellings of the few constructs the bake's code uses (the cube mapper comes traced in HLSL).
_HLSL = (("vec2", "float2"), ("vec3", "float3"), ("vec4", "float4"), ("mix(", "lerp("),
         ("int(floor(u))", "(int)floor(u)"), ("float(HF_LAYERS - 1)", "(float)(HF_LAYERS - 1)"), ("float(j)", "(float)j"))


def _to_hlsl(text: str, bake: Bake) -> str:
    """The GLSL source in HLSL (shader model 5): Texture2D + SamplerState per texture (Unity's
    ``sampler_<name>`` convention), ``SampleLevel``, static const tables."""
    out = []
    for line in text.split("\n"):
        if line.startswith("uniform ") and "sampler2D" in line:
            name = line.split()[-1].rstrip(";") if "//" not in line else line.split("//")[0].split()[-1].rstrip(";")
            out.append(f"Texture2D<float4> {name};  //" + line.split("//", 1)[1])
            out.append(f"SamplerState sampler_{name};  // linear, clamp to edge, no mipmaps")
            continue
        if line.startswith("const int ") or line.startswith("const float ") or line.startswith("const vec2 "):
            line = "static " + line
        if line.startswith("const vec4 HF_LAYER"):
            head, rest = line.split(" = ", 1)
            values, comment = rest.split(";", 1)
            values = values[values.index("(") + 1:values.rindex(")")]
            line = "static " + head + " = {" + values + "};" + comment
        if "sampler2D t" in line:
            line = line.replace("sampler2D t", "Texture2D<float4> t, SamplerState ts")
        line = line.replace("textureLod(t, vec2(uv.x, hf_flip_v(uv.y)), 0.0).rgb", "t.SampleLevel(ts, vec2(uv.x, hf_flip_v(uv.y)), 0).rgb")
        for k in range(bake.plan.terms):
            line = line.replace(f"hf_layer(hf_P{k}, ", f"hf_layer(hf_P{k}, sampler_hf_P{k}, ")
        for d in range(bake.plan.diffuse):
            line = line.replace(f"hf_cube(hf_E{d}, ", f"hf_cube(hf_E{d}, sampler_hf_E{d}, ")
        for t in range(bake.plan.tables):
            line = line.replace(f"textureLod(hf_W{t}, wuv, 0.0)", f"hf_W{t}.SampleLevel(sampler_hf_W{t}, wuv, 0)")
        line = line.replace("I_d = vec3(0.0); I_A = vec3(0.0); I_B = vec3(0.0);", "I_d = (vec3)0; I_A = (vec3)0; I_B = (vec3)0;")
        line = line.replace("vec3 f0 = mix(vec3(0.04), base_color, metallic);", "vec3 f0 = mix((vec3)0.04, base_color, metallic);")
        for a, b in _HLSL:
            line = line.replace(a, b)
        out.append(line)
    return "\n".join(out)


def texture_arrays(bake: Bake) -> list[tuple[str, object]]:
    """``(uniform name, (H, W, 3) float32 array)`` of every texture, as the files hold them."""
    pl = bake.plan
    out = [(f"hf_P{k}", assemble(bake.atlas, [np.asarray(p)[:, :, k] for p in bake.P], 3)) for k in range(pl.terms)]
    e = np.asarray(bake.E, np.float32) if pl.diffuse_basis == "texture" else None
    out += [(f"hf_E{d}", np.ascontiguousarray(e[:, :, d])) for d in range(pl.diffuse if pl.diffuse_basis == "texture" else 0)]
    w = np.asarray(bake.W, np.float32)
    w = np.concatenate([w, np.zeros(w.shape[:2] + (3 * pl.tables - w.shape[2],), np.float32)], axis=-1)
    out += [(f"hf_W{t}", np.ascontiguousarray(w[:, :, 3 * t:3 * t + 3])) for t in range(pl.tables)]
    return out


__all__ = ["LANGUAGES", "source", "texture_arrays"]
