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
from .atlas import assemble, down
from .model import TANGENT_FLOOR, Bake
from .sources import SPREAD

LANGUAGES = ("glsl", "glsl_es", "hlsl", "msl", "wgsl")


def _f(x: float) -> str:
    return L.float_literal(float(x))


def source(bake: Bake, language: str = "glsl", *, y_up: bool = False, flip_v: bool = False) -> str:
    """The source of ``bake``'s two pinned functions in ``language`` (GLSL 330 and GLSL ES 3.00 without a
    ``#version`` line, HLSL, MSL, WGSL)."""
    if language not in LANGUAGES:
        raise HomofacError(f"bake shaders are generated for {', '.join(LANGUAGES)}, not {language!r}")
    if language in ("msl", "wgsl"):
        return _metal_or_wgsl(bake, language, y_up=y_up, flip_v=flip_v)
    lang = L.get("glsl" if language == "hlsl" else language)
    pl = bake.plan
    atlases = bake.atlases
    K, D, layers, X = pl.terms, pl.diffuse, pl.layers, pl.nv_size
    se = pl.diffuse_size
    cube_src, tables = generate.mapper_function(L.get(language), "cube")
    prec = "highp " if language == "glsl_es" else ""
    mixed = bool(pl.mixed and pl.harmonic_layers())
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
    harm = bool(pl.harmonic)
    for k in range(pl.maps):
        what = f" ({', '.join(specular_channels(bake)[k])})" if harm else ""
        lines.append(f"uniform {prec}sampler2D hf_P{k};  // P{k}.exr: {layers} layers in a {atlases[k].width} x {atlases[k].height} atlas{what}")
    sh9 = pl.diffuse_basis == "sh9"
    for d in range(D if not sh9 else 0):
        lines.append(f"uniform {prec}sampler2D hf_E{d};  // E{d}.exr: cube {se}")
    for t in range(pl.tables):
        lines.append(f"uniform {prec}sampler2D hf_W{t};  // W{t}.exr: {layers} x {X} weight table")
    lines += [
        f"const int HF_LAYERS = {layers};",
        *([f"const int HF_H0 = {min(pl.harmonic_layers())};  // the first layer storing the harmonic (mixed)"] if mixed else []),
        f"const float HF_RHO0 = {_f(bake.roughness[0])};",
        f"const float HF_RHO1 = {_f(bake.roughness[-1])};",
        *(line for i, a in enumerate(atlases) for line in (
            f"const vec2 HF_ATLAS{i} = vec2({_f(a.width)}, {_f(a.height)});  // P{i}'s atlas",
            f"const vec4 HF_LAYER{i}[{layers}] = vec4[{layers}]({_layer_rows(a, bake.shift, 'vec4', _f)});  // x0, y0, face size, axis shift")),
        "#ifdef HOMOFAC_FLIP_V",
        "float hf_flip_v(float v) { return 1.0 - v; }",
        "#else",
        "float hf_flip_v(float v) { return v; }",
        "#endif",
        cube_src,
        "vec3 hf_layer(sampler2D t, vec4 layer, vec2 atlas, vec3 d) {  // layer (x0, y0, S, shift) of an atlas at direction d",
        "    vec3 fuv = hf_map_cube(d);",
        "    float s = layer.z;",
        "    float cu = clamp(fuv.y * s - 0.5, 0.0, s - 1.0);",
        "    float cv = clamp(fuv.z * s - 0.5, 0.0, s - 1.0);",
        "    vec2 uv = vec2(layer.x + floor(fuv.x + 0.5) * s + cu + 0.5, layer.y + cv + 0.5) / atlas;",
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
    if harm:
        lines += _harmonic_functions(language)
    if sh9:
        lines += [_sh9_function(d, np.asarray(bake.sh)[d]) for d in range(D)]
    if bake.sources:
        lines += _source_function(language)
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
        "    vec4 l0 = HF_LAYER0[j];",
        "    vec4 l1 = HF_LAYER0[j + 1];",
        "    vec3 a0 = normalize(mix(r, n, l0.w));",
        "    vec3 a1 = normalize(mix(r, n, l1.w));",
        f"    vec2 wuv = vec2((clamp(x * {_f(X)} - 0.5, 0.0, {_f(X - 1)}) + 0.5) / {_f(X)}, (u + 0.5) / {_f(layers)});",
        "    wuv.y = hf_flip_v(wuv.y);",
    ]
    chans = []
    for t in range(pl.tables):
        body.append(f"    vec3 w{t} = textureLod(hf_W{t}, wuv, 0.0).rgb;")
        chans += [f"w{t}.{c}" for c in "rgb"]
    for i in range(pl.maps):  # each map at both layers (P_k's RGB, or the tensor's face-gauge channels)
        body.append(f"    vec3 q0_{i} = hf_layer(hf_P{i}, HF_LAYER{i}[j], HF_ATLAS{i}, a0);")
        body.append(f"    vec3 q1_{i} = hf_layer(hf_P{i}, HF_LAYER{i}[j + 1], HF_ATLAS{i}, a1);")
    if mixed:  # hg0, hg1: whether each layer stores the harmonic (then its channels after K - 1 products are M's)
        body.append("    float hg0 = j >= HF_H0 ? 1.0 : 0.0;")
        body.append("    float hg1 = j + 1 >= HF_H0 ? 1.0 : 0.0;")
    g = K - 1 if mixed else K  # the map holding the tensor
    for k in range(K):
        if mixed and k == K - 1:  # each layer's own meaning: P_K below the harmonic layers, 0 in them
            body.append(f"    vec3 p{k} = mix((1.0 - hg0) * q0_{k}, (1.0 - hg1) * q1_{k}, t);")
        else:
            body.append(f"    vec3 p{k} = mix(q0_{k}, q1_{k}, t);")
        body.append(f"    I_A += p{k} * {chans[2 * k]};")
        body.append(f"    I_B += p{k} * {chans[2 * k + 1]};")
    if harm:
        gs = ("hg0 * ", "hg1 * ") if mixed else ("", "")
        body.append(f"    float hh = mix({gs[0]}hf_gauge(q0_{g}, a0, hf_tangent(n, a0)), "
                    f"{gs[1]}hf_gauge(q1_{g}, a1, hf_tangent(n, a1)), t);")
        if pl.shared_gain:  # one gain, h_A's, scales I_A and I_B
            body.append(f"    float ga = hf_gain(I_A, hh * {chans[pl.harmonic_channel]});")
            body.append("    I_A *= ga;")
            body.append("    I_B *= ga;")
        else:
            body.append(f"    I_A = hf_harmonic(I_A, hh * {chans[pl.harmonic_channel]});")
            body.append(f"    I_B = hf_harmonic(I_B, hh * {chans[pl.harmonic_channel + 1]});")
    for d in range(D):
        read = f"hf_sh9_{d}(n)" if sh9 else f"hf_cube(hf_E{d}, {_f(se)}, n)"
        body.append(f"    I_d += {read} * {chans[2 * K + d]};")
    body += ["    " + b for b in _source_lines(bake, language, ("I_d", "I_A", "I_B"))]
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


def _layer_rows(atlas, shift, vec4: str, f) -> str:
    """The constants (x0, y0, face size, axis shift) of every layer's block in one map's atlas."""
    return ", ".join(f"{vec4}({f(x)}, {f(y)}, {f(s)}, {f(sh)})" for (x, y), s, sh in zip(atlas.offsets, atlas.sizes, shift))


def _harmonic_functions(language: str) -> list[str]:
    """``hf_tangent(n, a)`` (the unit tangent from the axis a towards n), ``hf_gauge(m, a, t)`` (t^T M t from the
    face-gauge channels m = (M'_uu, M'_vv, M'_uv), (u, v) the minor axes of a's cube face) and ``hf_harmonic(i0,
    h)`` (i0 max(0, 1 + h / Y(i0)): the harmonic's luminance coloured as the isotropic part), ``hf_gain(i0, h)``
    (its factor, for the plan's ``shared_gain``): :func:`homofac.bake.gauge.gauge_read`,
    :func:`homofac.bake.model.harmonic_colour`, :func:`homofac.bake.model.harmonic_gain`."""
    msl, wgsl = language == "msl", language == "wgsl"
    v3, ft = ("float3", "float") if msl else (("vec3<f32>", "f32") if wgsl else ("vec3", "float"))
    f = (lambda x: L.float_literal(float(x), "f")) if msl else _f

    def head(name, params, ret):
        if wgsl:
            return f"fn {name}({', '.join(f'{a}: {t}' for a, t in params)}) -> {ret} {{"
        return f"{ret} {name}({', '.join(f'{t} {a}' for a, t in params)}) {{"

    def let(name, t, e):
        return f"let {name}: {t} = {e};" if wgsl else f"{t} {name} = {e};"

    lum = f"{v3}({f(0.2126)}, {f(0.7152)}, {f(0.0722)})"
    return [
        head("hf_tangent", [("n", v3), ("a", v3)], v3) + "  // unit tangent from the axis a towards n",
        "    " + let("g", v3, "n - dot(n, a) * a"),
        f"    return g / max(sqrt(dot(g, g)), {f(TANGENT_FLOOR)});",
        "}",
        head("hf_gauge", [("m", v3), ("a", v3), ("t", v3)], ft) + "  // t^T M t from the face gauge (M'_uu, M'_vv, M'_uv)",
        "    " + let("b", v3, "abs(a)"),
        "    " + let("fx", "bool", "b.x >= b.y && b.x >= b.z"),
        "    " + let("fy", "bool", "!fx && b.y >= b.z"),
        "    " + let("tu", ft, "select(t.x, t.y, fx)" if wgsl else "fx ? t.y : t.x"),
        "    " + let("tv", ft, "select(t.y, t.z, fx || fy)" if wgsl else "(fx || fy) ? t.z : t.y"),
        f"    return tu * tu * m.x + tv * tv * m.y + {f(2.0)} * tu * tv * m.z;",
        "}",
        head("hf_harmonic", [("i0", v3), ("h", ft)], v3) + "  // i0 max(0, 1 + h / Y(i0))",
        "    " + let("y", ft, f"dot(i0, {lum})"),
        f"    if (y <= {f(1e-20)}) {{ return i0; }}",
        f"    return i0 * max({f(0.0)}, {f(1.0)} + h / y);",
        "}",
        head("hf_gain", [("i0", v3), ("h", ft)], ft) + "  // max(0, 1 + h / Y(i0)), 1 where Y(i0) <= 0",
        "    " + let("y", ft, f"dot(i0, {lum})"),
        f"    if (y <= {f(1e-20)}) {{ return {f(1.0)}; }}",
        f"    return max({f(0.0)}, {f(1.0)} + h / y);",
        "}",
    ]


def _source_function(language: str) -> list[str]:
    """``hf_erfc``, ``hf_box`` and ``hf_source(n, v, x, roughness, l, s2, e1, w1, e2, w2, b1, b2)``: ((1 - s5)/pi,
    (1 - s5) S', s5 S') (n.l)+ of an analytic light at unit l (:func:`homofac.bake.sources.source_terms`; x = n.v >
    0), widened per axis of the plane of incidence (u = n x v across it): the core, read at the mirror direction,
    its covariance G = diag(w_1, w_2) + 4 alpha^2 (I - u u^T) in its unit axes e_i, a box of half-widths (b_1, b_2)
    along them blurred by a Gaussian of the rest of G, read in G's principal frame
    (:func:`homofac.bake.sources.box_blob`; b = 0: the Gaussian), weight w = S / (alpha^2 + S) with S = s2 / x; the
    tail, the anisotropic GGX of squared widths alpha^2 + s2 in the plane and alpha^2 + s2 / x^2 across it (h_y =
    h.u / |u|, h_x^2 = |n x h|^2 - h_y^2), weight 1 - w. Returned as a vector (d, A, B); the caller multiplies by
    the light's RGB power. ``hf_erfc`` is Abramowitz and Stegun's 7.1.26 (|error| <= 1.5e-7)."""
    msl, wgsl = language == "msl", language == "wgsl"
    v3, ft = ("float3", "float") if msl else (("vec3<f32>", "f32") if wgsl else ("vec3", "float"))
    f = (lambda x: L.float_literal(float(x), "f")) if msl else _f

    def let(name, t, e):
        return f"let {name}: {t} = {e};" if wgsl else f"{t} {name} = {e};"

    def sel(cond, a, b):
        return f"select({b}, {a}, {cond})" if wgsl else f"({cond} ? {a} : {b})"

    def head(name, params, ret):
        if wgsl:
            return f"fn {name}({', '.join(f'{a}: {t}' for a, t in params)}) -> {ret}"
        return f"{ret} {name}({', '.join(f'{t} {a}' for a, t in params)})"

    one, zero = f(1.0), f(0.0)
    erfc = [head("hf_erfc", [("x", ft)], ft) + " {  // erfc(x), Abramowitz and Stegun 7.1.26 (|error| <= 1.5e-7)",
            "    " + let("z", ft, "abs(x)"), "    " + let("t", ft, f"{one} / ({one} + {f(0.3275911)} * z)"),
            "    " + let("y", ft, f"t * ({f(0.254829592)} + t * ({f(-0.284496736)} + t * ({f(1.421413741)} "
                                  f"+ t * ({f(-1.453152027)} + t * {f(1.061405429)})))) * exp(-z * z)"),
            f"    return {sel(f'x >= {zero}', 'y', f'{f(2.0)} - y')};", "}"]
    box = [head("hf_box", [("s", ft), ("b", ft), ("g", ft)], ft)
           + " {  // a box of half-width b (unit integral) blurred by exp(-s^2 / g) / sqrt(pi g)",
           "    " + let("sg", ft, "sqrt(g)"), "    " + let("a", ft, "abs(s)"),
           f"    if (b < {f(1e-3)} * sg) {{ return exp(-s * s / g) / sqrt({f(np.pi)} * g); }}",
           f"    return (hf_erfc((a - b) / sg) - hf_erfc((a + b) / sg)) / ({f(4.0)} * b);", "}"]
    body = [let("nl", ft, "dot(n, l)"), f"if (nl <= {zero}) {{ return {v3}({zero}, {zero}, {zero}); }}",
            let("h", v3, "normalize(l + v)"), let("c", v3, "cross(n, h)"),
            let("nh", ft, f"max(dot(n, h), {zero})"), let("vh", ft, f"min(abs(dot(v, h)), {one})"),
            let("a2", ft, "roughness * roughness * roughness * roughness"),
            let("u", v3, "cross(n, v)"), let("hu", ft, "dot(h, u)"),
            let("hy2", ft, f"hu * hu / max(dot(u, u), {f(1e-12)})"), let("hx2", ft, f"max(dot(c, c) - hy2, {zero})"),
            let("sx", ft, "s2 / x"), let("wc", ft, sel(f"sx > {zero}", "sx / (a2 + sx)", zero)),
            let("ax", ft, "a2 + s2"), let("ay", ft, "a2 + s2 / (x * x)"),
            let("q", ft, "hx2 * ay + hy2 * ax + nh * nh * ax * ay"),
            let("dd", ft, f"ax * ay * sqrt(ax * ay) / ({f(np.pi)} * q * q)"),
            let("lv", ft, f"{f(0.5)} * (sqrt({one} + a2 * ({one} - x * x) / (x * x)) - {one})"),
            let("ll", ft, f"{f(0.5)} * (sqrt({one} + a2 * ({one} - nl * nl) / (nl * nl)) - {one})"),
            let("sv", ft, f"({one} - wc) * dd / (({one} + ll + lv) * {f(4.0)} * x)"),
            let("m", ft, f"{one} - vh"), let("s5", ft, "m * m * m * m * m"),
            let("e", v3, f"{f(2.0)} * x * n - v - l"), let("u1", ft, "dot(u, e1)"), let("u2", ft, "dot(u, e2)"),
            let("g11", ft, f"w1 + {f(4.0)} * a2 * ({one} - u1 * u1)"), let("g12", ft, f"{f(-4.0)} * a2 * u1 * u2"),
            let("g22", ft, f"w2 + {f(4.0)} * a2 * ({one} - u2 * u2)"),
            let("t1", ft, "dot(e, e1)"), let("t2", ft, "dot(e, e2)"), let("t3", ft, "dot(e, l)"),
            # G's principal frame: cos 2 theta = (g11 - g22) / dg, sin 2 theta = 2 g12 / dg
            let("dg", ft, f"sqrt((g11 - g22) * (g11 - g22) + {f(4.0)} * g12 * g12)"),
            let("big", "bool", f"dg > {f(1e-6)} * (g11 + g22)"),
            let("c2", ft, sel("big", f"(g11 - g22) / max(dg, {f(1e-30)})", one)),
            let("cos2", ft, f"{f(0.5)} * ({one} + c2)"), let("sin2", ft, f"{f(0.5)} * ({one} - c2)"),
            let("cs", ft, "sqrt(cos2)"), let("sn", ft, sel(f"g12 < {zero}", "-sqrt(sin2)", "sqrt(sin2)")),
            let("l1", ft, f"{f(0.5)} * (g11 + g22 + dg)"), let("l2", ft, f"{f(0.5)} * (g11 + g22 - dg)"),
            let("v1", ft, "b1 * b1 * cos2 + b2 * b2 * sin2"), let("v2", ft, "b1 * b1 * sin2 + b2 * b2 * cos2"),
            let("r1", ft, f"max(l1 - {f(2.0 / 3.0)} * v1, {f(1e-3)} * l1)"),
            let("r2", ft, f"max(l2 - {f(2.0 / 3.0)} * v2, {f(1e-3)} * l2)"),
            let("k", ft, "wc * hf_box(cs * t1 + sn * t2, sqrt(v1), r1) * hf_box(cs * t2 - sn * t1, sqrt(v2), r2) "
                         f"* exp(-t3 * t3 / min(g11, g22)) / ({one} + {f(2.0)} * lv)"),
            let("mx", ft, f"{one} - x"), let("m5", ft, "mx * mx * mx * mx * mx"),
            f"return {v3}(({one} - s5) / {f(np.pi)} * nl, ({one} - s5) * sv + ({one} - m5) * k, s5 * sv + m5 * k);"]
    params = [("n", v3), ("v", v3), ("x", ft), ("roughness", ft), ("l", v3), ("s2", ft), ("e1", v3), ("w1", ft),
              ("e2", v3), ("w2", ft), ("b1", ft), ("b2", ft)]
    return [*erfc, *box, head("hf_source", params, v3)
            + " {  // ((1 - s5)/pi, (1 - s5) S', s5 S') (n.l)+ of a source at l: box-and-Gaussian core + widened GGX tail",
            *("    " + b for b in body), "}"]


def _source_lines(bake: Bake, language: str, out: tuple[str, str, str]) -> list[str]:
    """The body lines adding each analytic source's lobes times its RGB power to I_d, I_A, I_B (constants)."""
    msl, wgsl = language == "msl", language == "wgsl"
    v3 = "float3" if msl else ("vec3<f32>" if wgsl else "vec3")
    f = (lambda x: L.float_literal(float(x), "f")) if msl else _f
    lines = []
    for i, src in enumerate(bake.sources):
        d = ", ".join(f(c) for c in src.direction)
        p = f"{v3}({', '.join(f(c) for c in src.power)})"
        axes, widths = src.core_frame()
        e1, e2 = (f"{v3}({', '.join(f(c) for c in a)})" for a in axes)
        g = (f"hf_source(n, v, x, roughness, {v3}({d}), {f((SPREAD * src.radius) ** 2 / 4)}, "
             f"{e1}, {f(widths[0])}, {e2}, {f(widths[1])}, {', '.join(f(b) for b in (src.box or (0.0, 0.0)))})")
        lines.append(f"let g{i}: {v3} = {g};" if wgsl else f"{v3} g{i} = {g};")
        lines += [f"{o} = {o} + g{i}.{c} * {p};" for o, c in zip(out, "xyz")]
    return lines


def _sh9_function(d: int, c, language: str = "glsl") -> str:
    """``hf_sh9_<d>(n)``: sum_i c_i Y_i(n) with the constants folded into the coefficients (the polynomials 1, y,
    z, x, xy, yz, 3z^2 - 1, xz, x^2 - y^2 of :mod:`homofac.light.sh`, +z up), in the GLSL family, MSL or WGSL."""
    msl, wgsl = language == "msl", language == "wgsl"
    v3 = "float3" if msl else ("vec3<f32>" if wgsl else "vec3")
    f = (lambda x: L.float_literal(float(x), "f")) if msl else _f
    k = np.asarray(c, np.float64) * SH9_NORM[:, None]
    v = [f"{v3}({f(r)}, {f(g)}, {f(b)})" for r, g, b in k]
    head = f"fn hf_sh9_{d}(n: {v3}) -> {v3} {{" if wgsl else f"{v3} hf_sh9_{d}({v3} n) {{"
    return (f"{head}  // E{d}(n) from its 9 SH coefficients (no texture)\n"
            f"    return {v[0]} + {v[1]} * n.y + {v[2]} * n.z + {v[3]} * n.x\n"
            f"         + {v[4]} * (n.x * n.y) + {v[5]} * (n.y * n.z) + {v[6]} * ({f(3.0)} * n.z * n.z - {f(1.0)})\n"
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
        line = line.replace("textureLod(t, vec2(uv.x, hf_flip_v(uv.y)), 0.0)", "t.SampleLevel(ts, vec2(uv.x, hf_flip_v(uv.y)), 0)")
        for k in range(bake.plan.maps):
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


def _names(bake: Bake) -> list[tuple[str, str]]:
    """``(texture name, comment)`` of every texture, in binding order (P<k>, E<d>, W<t>)."""
    pl, atlases = bake.plan, bake.atlases
    return ([(f"hf_P{k}", f"P{k}: {pl.layers} layers in a {a.width} x {a.height} atlas") for k, a in enumerate(atlases)]
            + [(f"hf_E{d}", f"E{d}: cube {pl.diffuse_size}") for d in range(pl.diffuse if pl.diffuse_basis == "texture" else 0)]
            + [(f"hf_W{t}", f"W{t}: {pl.layers} x {pl.nv_size} weight table") for t in range(pl.tables)])


def _metal_or_wgsl(bake: Bake, language: str, *, y_up: bool, flip_v: bool) -> str:
    """MSL (the textures in a ``HomofacBakeTextures`` struct passed by reference, out parameters as ``thread
    float3&``) or WGSL (module-scope ``texture_2d<f32>`` + sampler bindings, the terms returned as a
    ``HomofacIblTerms`` struct; ``HOMOFAC_Y_UP`` / ``HOMOFAC_FLIP_V`` constants): the same model as the GLSL."""
    msl = language == "msl"
    lang = L.get(language)
    pl, atlases = bake.plan, bake.atlases
    K, D, layers, X, se = pl.terms, pl.diffuse, pl.layers, pl.nv_size, pl.diffuse_size
    f = (lambda x: L.float_literal(float(x), "f")) if msl else _f
    v2, v3, v4 = ("float2", "float3", "float4") if msl else ("vec2<f32>", "vec3<f32>", "vec4<f32>")
    cube_src, tables = generate.mapper_function(lang, "cube")
    names = _names(bake)
    mixed = bool(pl.mixed and pl.harmonic_layers())
    h0 = min(pl.harmonic_layers()) if mixed else 0
    lines = [
        f"// homofac {__version__}: material-parametric bake ({pl.preset}), {bake.lookups} texture lookups per pixel.",
        f"// {lang.title}. Generated from the bake's records; the interface is pinned (docs/format.md).",
        "// Frame: homofac world, +z up; n, v point away from the surface (v towards the viewer).",
    ]
    if msl:
        lines.append(lang.header)
        lines += ["#define HOMOFAC_Y_UP"] if y_up else []
        lines += ["#define HOMOFAC_FLIP_V"] if flip_v else []
        lines += [L.table_source(lang, n, v) for n, v in tables.items()]
        lines.append("struct HomofacBakeTextures {  // an argument buffer, or fill it from the entry point's arguments")
        lines += [f"    texture2d<float> {n} [[id({i})]];  // {c}" for i, (n, c) in enumerate(names)]
        lines += ["};", "constexpr sampler hf_sampler(coord::normalized, filter::linear, mip_filter::none, address::clamp_to_edge);",
                  f"constant int HF_LAYERS = {layers};", *([f"constant int HF_H0 = {h0};  // the first layer storing the harmonic (mixed)"] if mixed else []),
                  f"constant float HF_RHO0 = {f(bake.roughness[0])};",
                  f"constant float HF_RHO1 = {f(bake.roughness[-1])};",
                  *(line for i, a in enumerate(atlases) for line in (
                      f"constant float2 HF_ATLAS{i} = float2({f(a.width)}, {f(a.height)});  // P{i}'s atlas",
                      f"constant float4 HF_LAYER{i}[{layers}] = {{{_layer_rows(a, bake.shift, v4, f)}}};  // x0, y0, face size, axis shift")),
                  "#ifdef HOMOFAC_FLIP_V", "float hf_flip_v(float v) { return 1.0f - v; }", "#else",
                  "float hf_flip_v(float v) { return v; }", "#endif", cube_src,
                  "float3 hf_read(texture2d<float> t, float2 uv) { return t.sample(hf_sampler, float2(uv.x, hf_flip_v(uv.y)), level(0.0f)).rgb; }"]
        tex = "texture2d<float> t, "
    else:
        lines += [f"const HOMOFAC_Y_UP: bool = {'true' if y_up else 'false'};  // true: (x, y, z)_engine -> (x, -z, y)",
                  f"const HOMOFAC_FLIP_V: bool = {'true' if flip_v else 'false'};  // true: textures stored bottom-up"]
        lines += [L.table_source(lang, n, v) for n, v in tables.items()]
        for i, (n, c) in enumerate(names):
            lines.append(f"@group(0) @binding({2 * i}) var {n}: texture_2d<f32>;  // {c}")
            lines.append(f"@group(0) @binding({2 * i + 1}) var {n}_sampler: sampler;  // linear, clamp to edge, no mipmaps")
        lines += [f"const HF_LAYERS: i32 = {layers};", *([f"const HF_H0: i32 = {h0};  // the first layer storing the harmonic (mixed)"] if mixed else []),
                  f"const HF_RHO0: f32 = {f(bake.roughness[0])};",
                  f"const HF_RHO1: f32 = {f(bake.roughness[-1])};",
                  *(line for i, a in enumerate(atlases) for line in (
                      f"const HF_ATLAS{i}: vec2<f32> = vec2<f32>({f(a.width)}, {f(a.height)});  // P{i}'s atlas",
                      f"var<private> HF_LAYER{i}: array<vec4<f32>, {layers}> = array<vec4<f32>, {layers}>({_layer_rows(a, bake.shift, v4, f)});"
                      "  // x0, y0, face size, axis shift")),
                  "fn hf_flip_v(v: f32) -> f32 { return select(v, 1.0 - v, HOMOFAC_FLIP_V); }", cube_src,
                  "struct HomofacIblTerms { I_d: vec3<f32>, I_A: vec3<f32>, I_B: vec3<f32> }"]
    one, half, zero = f(1.0), f(0.5), f(0.0)

    def fn(name, params, ret, body):
        if msl:
            head = f"{ret} {name}({', '.join(f'{t} {n}' for n, t in params)})"
        else:
            head = f"fn {name}({', '.join(f'{n}: {t}' for n, t in params)}) -> {ret}"
        return [head + " {", *("    " + b for b in body), "}"]

    def let(name, t, e):
        return f"{t} {name} = {e};" if msl else f"let {name}: {t} = {e};"

    def read(name, uv):
        return f"hf_read({name}, {uv})" if msl else f"textureSampleLevel({name}, {name}_sampler, vec2<f32>({uv}.x, hf_flip_v({uv}.y)), 0.0).rgb"

    coords = [let("fuv", v3, "hf_map_cube(d)"),
              let("cu", "float" if msl else "f32", f"clamp(fuv.y * s - {half}, {zero}, s - {one})"),
              let("cv", "float" if msl else "f32", f"clamp(fuv.z * s - {half}, {zero}, s - {one})")]
    ft = "float" if msl else "f32"
    # layer and cube reads: one helper each (the GLSL's), per texture in WGSL (textures are not function arguments there)
    def layer_body(tname):
        return ([let("s", ft, "layer.z")] + coords +
                [let("uv", v2, f"{v2}(layer.x + floor(fuv.x + {half}) * s + cu + {half}, layer.y + cv + {half}) / atlas"),
                 f"return {read(tname, 'uv')};"])

    def cube_body(tname):
        return coords + [let("uv", v2, f"{v2}((floor(fuv.x + {half}) * s + cu + {half}) / ({f(6.0)} * s), (cv + {half}) / s)"),
                         f"return {read(tname, 'uv')};"]

    harm = bool(pl.harmonic)

    if msl:
        lines += fn("hf_layer", [("t", "texture2d<float>"), ("layer", v4), ("atlas", v2), ("d", v3)], v3, layer_body("t"))
        lines += fn("hf_cube", [("t", "texture2d<float>"), ("s", ft), ("d", v3)], v3, cube_body("t"))
    else:
        for k in range(pl.maps):
            lines += fn(f"hf_layer_P{k}", [("layer", v4), ("atlas", v2), ("d", v3)], v3, layer_body(f"hf_P{k}"))
        for d in range(D if pl.diffuse_basis == "texture" else 0):
            lines += fn(f"hf_cube_E{d}", [("s", ft), ("d", v3)], v3, cube_body(f"hf_E{d}"))
    if pl.diffuse_basis == "sh9":
        lines += [_sh9_function(d, np.asarray(bake.sh)[d], language) for d in range(D)]
    if harm:
        lines += _harmonic_functions(language)
    if bake.sources:
        lines += _source_function(language)
    nv, vv = ("n", "v") if msl else ("n_in", "v_in")
    body = []
    if msl:
        body += ["#ifdef HOMOFAC_Y_UP", "n = float3(n.x, -n.z, n.y);", "v = float3(v.x, -v.z, v.y);", "#endif",
                 "I_d = float3(0.0f); I_A = float3(0.0f); I_B = float3(0.0f);"]
    else:
        body += ["var n = n_in;", "var v = v_in;",
                 "if (HOMOFAC_Y_UP) { n = vec3<f32>(n_in.x, -n_in.z, n_in.y); v = vec3<f32>(v_in.x, -v_in.z, v_in.y); }",
                 "var o = HomofacIblTerms(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));"]
    ret = "return;" if msl else "return o;"
    it = "int" if msl else "i32"
    bl = (lambda a: f"float3({a})") if msl else (lambda a: a)  # MSL's mix blends by a vector
    body += [let("x", ft, "dot(n, v)"), f"if (x <= {zero}) {{ {ret} }}", let("r", v3, f"{f(2.0)} * x * n - v"),
             let("rho", ft, "clamp(roughness, HF_RHO0, HF_RHO1)"),
             let("u", ft, f"clamp({ft}(HF_LAYERS - 1) * log(rho / HF_RHO0) / log(HF_RHO1 / HF_RHO0), {zero}, {ft}(HF_LAYERS - 1))"),
             let("j", it, f"min({it}(floor(u)), HF_LAYERS - 2)"), let("t", ft, f"u - {ft}(j)"),
             let("l0", v4, "HF_LAYER0[j]"), let("l1", v4, "HF_LAYER0[j + 1]"),
             let("a0", v3, f"normalize(mix(r, n, {bl('l0.w')}))"), let("a1", v3, f"normalize(mix(r, n, {bl('l1.w')}))"),
             let("wuv", v2, f"{v2}((clamp(x * {f(X)} - {half}, {zero}, {f(X - 1)}) + {half}) / {f(X)}, (u + {half}) / {f(layers)})")]
    chans = []
    for t in range(pl.tables):
        body.append(let(f"w{t}", v3, read(f"hf.hf_W{t}" if msl else f"hf_W{t}", "wuv")))
        chans += [f"w{t}.{c}" for c in "xyz"]
    out = ("I_d", "I_A", "I_B") if msl else ("o.I_d", "o.I_A", "o.I_B")
    for i in range(pl.maps):  # each map at both layers (P_k's RGB, or the tensor's face-gauge channels)
        for jj, a in (("j", "a0"), ("j + 1", "a1")):
            args = f"HF_LAYER{i}[{jj}], HF_ATLAS{i}, {a}"
            body.append(let(f"q{a[1]}_{i}", v3, f"hf_layer(hf.hf_P{i}, {args})" if msl else f"hf_layer_P{i}({args})"))
    if mixed:  # hg0, hg1: whether each layer stores the harmonic (then its channels after K - 1 products are M's)
        for g, jj in (("hg0", "j"), ("hg1", "j + 1")):
            body.append(let(g, ft, f"({jj} >= HF_H0 ? {one} : {zero})" if msl else f"select({zero}, {one}, {jj} >= HF_H0)"))
    g = K - 1 if mixed else K  # the map holding the tensor
    for k in range(K):
        if mixed and k == K - 1:  # each layer's own meaning: P_K below the harmonic layers, 0 in them
            body.append(let(f"p{k}", v3, f"mix(({one} - hg0) * q0_{k}, ({one} - hg1) * q1_{k}, {bl('t')})"))
        else:
            body.append(let(f"p{k}", v3, f"mix(q0_{k}, q1_{k}, {bl('t')})"))
        body.append(f"{out[1]} = {out[1]} + p{k} * {chans[2 * k]};")
        body.append(f"{out[2]} = {out[2]} + p{k} * {chans[2 * k + 1]};")
    if harm:
        gs = ("hg0 * ", "hg1 * ") if mixed else ("", "")
        body.append(let("h0", ft, f"{gs[0]}hf_gauge(q0_{g}, a0, hf_tangent(n, a0))"))
        body.append(let("h1", ft, f"{gs[1]}hf_gauge(q1_{g}, a1, hf_tangent(n, a1))"))
        body.append(let("hh", ft, "h0 + (h1 - h0) * t"))
        if pl.shared_gain:  # one gain, h_A's, scales I_A and I_B
            body.append(let("ga", ft, f"hf_gain({out[1]}, hh * {chans[pl.harmonic_channel]})"))
            body.append(f"{out[1]} = {out[1]} * ga;")
            body.append(f"{out[2]} = {out[2]} * ga;")
        else:
            body.append(f"{out[1]} = hf_harmonic({out[1]}, hh * {chans[pl.harmonic_channel]});")
            body.append(f"{out[2]} = hf_harmonic({out[2]}, hh * {chans[pl.harmonic_channel + 1]});")
    for d in range(D):
        e = (f"hf_sh9_{d}(n)" if pl.diffuse_basis == "sh9" else
             f"hf_cube(hf.hf_E{d}, {f(se)}, n)" if msl else f"hf_cube_E{d}({f(se)}, n)")
        body.append(f"{out[0]} = {out[0]} + {e} * {chans[2 * K + d]};")
    body += _source_lines(bake, language, out)
    if not msl:
        body.append("return o;")
    if msl:
        lines += fn("homofac_ibl_terms", [("n", v3), ("v", v3), ("roughness", ft), ("I_d", "thread float3&"),
                                          ("I_A", "thread float3&"), ("I_B", "thread float3&"),
                                          ("hf", "thread const HomofacBakeTextures&")], "void", body)
        lines += fn("homofac_ibl", [("n", v3), ("v", v3), ("base_color", v3), ("metallic", ft), ("roughness", ft),
                                    ("hf", "thread const HomofacBakeTextures&")], v3, [
            "float3 I_d, I_A, I_B;", "homofac_ibl_terms(n, v, roughness, I_d, I_A, I_B, hf);",
            "float3 f0 = mix(float3(0.04f), base_color, float3(metallic));  // (1 - m) 0.04 + m c",
            "return (1.0f - metallic) * 0.96f * base_color * I_d + f0 * I_A + I_B;"])
    else:
        lines += fn("homofac_ibl_terms", [("n_in", v3), ("v_in", v3), ("roughness", ft)], "HomofacIblTerms", body)
        lines += fn("homofac_ibl", [("n", v3), ("v", v3), ("base_color", v3), ("metallic", ft), ("roughness", ft)], v3, [
            "let o = homofac_ibl_terms(n, v, roughness);",
            "let f0 = mix(vec3<f32>(0.04), base_color, metallic);  // (1 - m) 0.04 + m c",
            "return (1.0 - metallic) * 0.96 * base_color * o.I_d + f0 * o.I_A + o.I_B;"])
    return "\n".join(x for x in lines if x != "") + "\n"


#: The tensor's channels in a specular map: the face gauge's (M'_uu, M'_vv, M'_uv) (:mod:`.gauge`).
TENSOR_CHANNELS = ("M.uu", "M.vv", "M.uv")


def specular_channels(bake: Bake) -> list[list[str]]:
    """The channels of each specular RGB map ``P<i>``: ``P<k>.r/g/b`` of the K products; with the plan's
    ``harmonic`` one more map, the tensor's face-gauge channels ``M.uu, M.vv, M.uv``; ``mixed``: the last
    product's map holds them in the harmonic layers (``P1.r/M.uu``, ...)."""
    pl = bake.plan
    maps = [[f"P{k}.{c}" for c in "rgb"] for k in range(pl.terms)]
    if pl.harmonic and pl.mixed:
        maps[-1] = [f"{p}/{m}" for p, m in zip(maps[-1], TENSOR_CHANNELS)]
    elif pl.harmonic:
        maps.append(list(TENSOR_CHANNELS))
    return maps


def _specular_layer(bake: Bake, j: int, i: int) -> np.ndarray:
    """Layer j's block (S, 6 S, 3) of specular map i (:func:`specular_channels`): P_i's RGB, or the tensor's
    channels (0 in a layer without the harmonic); mixed: the last map holds the tensor in the harmonic layers."""
    p = np.asarray(bake.P[j], np.float32)
    h = bake.H[j] if bake.H and bake.H[j] is not None else None
    pl = bake.plan
    if pl.harmonic and i == pl.terms - (1 if pl.mixed else 0) and (h is not None or not pl.mixed):
        return np.zeros(p.shape[:2] + (3,), np.float32) if h is None else np.asarray(h, np.float32)
    return p[:, :, i]


def texture_arrays(bake: Bake) -> list[tuple[str, object]]:
    """``(uniform name, (H, W, 3) float32 array)`` of every texture, as the files hold them."""
    pl = bake.plan
    out = [(f"hf_P{i}", assemble(a, [down(layer, layer.shape[0] // a.sizes[j]) for j, layer in
                                     enumerate(_specular_layer(bake, j, i) for j in range(pl.layers))], 3))
           for i, a in enumerate(bake.atlases)]  # each block at its size in its map (a smaller one box-averaged)
    e = np.asarray(bake.E, np.float32) if pl.diffuse_basis == "texture" else None
    out += [(f"hf_E{d}", np.ascontiguousarray(e[:, :, d])) for d in range(pl.diffuse if pl.diffuse_basis == "texture" else 0)]
    w = np.asarray(bake.W, np.float32)
    w = np.concatenate([w, np.zeros(w.shape[:2] + (3 * pl.tables - w.shape[2],), np.float32)], axis=-1)
    out += [(f"hf_W{t}", np.ascontiguousarray(w[:, :, 3 * t:3 * t + 3])) for t in range(pl.tables)]
    return out


__all__ = ["LANGUAGES", "source", "specular_channels", "texture_arrays"]
