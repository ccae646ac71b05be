"""Shader source of a factorization in GLSL, GLSL ES, HLSL, MSL or WGSL, generated from the records.

Every formula is traced from the Python records (:mod:`homofac.shader.symbolic`): each mapper's
``to_face_uv`` becomes ``hf_map_<mapper>``, each projection ``hf_proj_<name>``, and the model's sum of
products becomes ``homofac_value(a, b)``; only the texture read itself (``hf_sample_<texture>``) and the
function syntax are written per language (:mod:`homofac.shader.languages`). The pinned interface
(docs/shaders.md):

* lighting models: ``vec3 homofac_radiance(vec3 n, vec3 v)`` in homofac's world frame (+z up), 0 where
  n.v <= 0; BRDF models: ``vec3 homofac_brdf(vec3 wi, vec3 wo)`` in the local frame (z = normal), 0
  below either horizon; both call ``homofac_value(a, b)``;
* one texture per model texture named ``hf_<texture name>``, bound to the data of ``<name>.exr``
  (float RGB, or the 8-bit ``<name>.png`` for the quantized variant), sampled with linear filtering,
  clamp to edge, no mipmaps, rows in file order (row 0 = first row = texture coordinate v = 0);
* ``HOMOFAC_Y_UP`` (a define in GLSL, HLSL, MSL; a constant in WGSL) maps a right-handed y-up engine
  frame (three.js, Godot, glTF) to homofac's: ``(x, y, z) -> (x, -z, y)``;
* ``HOMOFAC_FLIP_V`` (same forms) reads ``1 - v`` for engines that store an image's first row at
  ``v = 1`` (Unity's texture importer);
* per term: ``homofac_term(int k, a, b)`` (term k of ``homofac_value``, 0 outside 0 .. HOMOFAC_TERMS - 1)
  and ``homofac_radiance_term`` / ``homofac_brdf_term(int k, ...)``, the entry point's twin.

The texture coordinate of a lookup is the pinned continuous coordinate clamped to the face (thesis
eq. 33-34, :func:`homofac.param.mappers.bilinear`) plus half a texel, so the hardware's bilinear filter
reads the four texels the CPU reads (every in-domain footprint is valid, and invalid texels are
dilated with their nearest valid neighbour, :func:`homofac.fit.precision.normalize`).
"""

from __future__ import annotations

import numpy as np

from .. import sphere
from .._version import __version__
from ..errors import HomofacError
from ..factorization import Factorization, Quantized, check_identifier, check_texture_name
from ..param import mappers
from ..param import projections as pj
from . import languages as L
from .symbolic import NS, Expr, _call, float_input, vec3_input

#: Function names of the interface, per model kind.
ENTRY = {"lighting": ("homofac_radiance", "n", "v"), "brdf": ("homofac_brdf", "wi", "wo")}


def mapper_function(lang: L.Language, name: str) -> tuple[str, dict]:
    """``vec3 hf_map_<name>(vec3 d)`` (or ``(float x)``) returning (face, u, v): the record's math."""
    m = mappers.get(name)
    d = float_input("x") if m.scalar else vec3_input("d")
    face, u, v = m.to_face_uv(d)
    out = NS.stack([face, u, v])
    params = [("x", "float")] if m.scalar else [("d", "vec3")]
    return L.function(lang, f"hf_map_{name}", params, out, doc=m.doc), L.tables([out])


def projection_function(lang: L.Language, name: str, context: dict) -> tuple[str, dict]:
    """``hf_proj_<name>(vec3 a, vec3 b)`` (vec3 or float): the record's math, context baked in."""
    p = pj.get(name)
    a, b = vec3_input("a"), vec3_input("b")
    ctx = {k: _constant(context[k]) for k in p.context}
    out = pj.apply(name, a, b, ctx)
    if not isinstance(out, Expr):
        raise HomofacError(f"projection {name} did not trace to a shader expression")
    return L.function(lang, f"hf_proj_{name}", [("a", "vec3"), ("b", "vec3")], out, doc=p.doc), L.tables([out])


def helper_functions(lang: L.Language) -> list[str]:
    """``hf_normalize(d)`` and ``hf_local(d, n)`` (d in the frame (t(n), n x t(n), n) of Latta-Kolb eq. 6),
    traced from :mod:`homofac.sphere`: what a renderer needs to turn world vectors into a BRDF's local frame."""
    d, n = vec3_input("d"), vec3_input("n")
    return [
        L.function(lang, "hf_normalize", [("d", "vec3")], sphere.normalize(d), doc="d / |d|; zero stays zero"),
        L.function(lang, "hf_local", [("d", "vec3"), ("n", "vec3")], sphere.local(d, n),
                   doc="d in the local frame (t(n), n x t(n), n), t(n) of Latta-Kolb eq. 6"),
    ]


def _constant(value):
    """A context value baked into shader code: a float (r_off's shift) or a 3-vector (NRHD's dominant light)."""
    a = np.asarray(value, np.float64)
    return float(a) if a.ndim == 0 else a.reshape(3)


def _term_graphs(model: Factorization, quantized: Quantized | None) -> list[Expr]:
    """The traced terms of ``homofac_value(a, b)``: per term its correction times its texture reads."""
    a, b = vec3_input("a"), vec3_input("b")
    proj_type = {name: ("float" if pj.get(name).scalar else "vec3") for term in model.terms for name in
                 (f.projection for f in term.factors)}
    projected = {name: _call(f"hf_proj_{name}", a, b, type=t) for name, t in proj_type.items()}
    reads = {tex.name: (k, tex) for k, tex in enumerate(model.textures)}
    out = []
    for t_index, term in enumerate(model.terms):
        corr = quantized.corrections[t_index] if quantized is not None else term.correction
        value = Expr.const(_constant(corr), "vec3")
        for f in term.factors:
            k, tex = reads[f.texture]
            value = value * _fetch(tex, projected[f.projection], quantized, k)
        out.append(value)
    return out


def _value_graph(model: Factorization, quantized: Quantized | None) -> Expr:
    """The traced ``homofac_value(a, b)``: the sum of the terms' products of texture reads."""
    total = None
    for value in _term_graphs(model, quantized):
        total = value if total is None else total + value
    return total


def _fetch(tex, d: Expr, quantized: Quantized | None, k: int) -> Expr:
    """Texture ``tex`` read at direction (or scalar) ``d``: pinned clamped coordinate + half a texel."""
    m = mappers.get(tex.mapper)
    S = tex.size
    H, W = m.rows(S), m.faces * S
    fuv = _call(f"hf_map_{m.name}", d, type="vec3")
    face, u, v = fuv[..., 0], fuv[..., 1], fuv[..., 2]
    cu = NS.clip(u * float(S) - 0.5, 0.0, float(S - 1))
    cv = NS.clip(v * float(H) - 0.5, 0.0, float(H - 1)) if H > 1 else None
    tu = (NS.floor(face + 0.5) * float(S) + cu + 0.5) / float(W)
    tv = (cv + 0.5) / float(H) if H > 1 else Expr.const(0.5, "float")
    rgb = _call(f"hf_sample_{tex.name}", tu, tv, type="vec3")
    if quantized is None:
        return rgb
    if quantized.alpha[k]:
        rgb = rgb * _call(f"hf_sample_alpha_{tex.name}", tu, tv, type="float")
    offset, scale = _constant(quantized.offset[k]), _constant(quantized.scale[k])
    value = rgb if np.all(scale == 1.0) else Expr.const(scale, "vec3") * rgb
    return value if np.all(offset == 0.0) else Expr.const(offset, "vec3") + value


# --------------------------------------------------------------------------------------------------
# Per-language texture declarations and reads (the only hand-written part)


def _resources(lang: L.Language, model: Factorization, quantized: bool) -> tuple[list[str], list[str]]:
    """(file-scope declarations, sample functions) of the model's textures in ``lang``."""
    decl, fns = [], []
    v3 = lang.type("vec3")
    for k, tex in enumerate(model.textures):
        n = f"hf_{tex.name}"
        if lang.name in ("glsl", "glsl_es"):
            # highp: GLSL ES fragment shaders default to lowp samplers (8-bit results on some mobile GPUs)
            prec = "highp " if lang.name == "glsl_es" else ""
            decl.append(f"uniform {prec}sampler2D {n};  // {tex.name}: {tex.mapper} {tex.size}, linear, clamp to edge, "
                        "no mipmaps")
            fns.append(f"vec3 hf_sample_{tex.name}(float u, float v) {{ return textureLod({n}, vec2(u, hf_flip_v(v)), 0.0).rgb; }}")
            if quantized:
                fns.append(f"float hf_sample_alpha_{tex.name}(float u, float v) {{ return textureLod({n}, vec2(u, hf_flip_v(v)), 0.0).a; }}")
        elif lang.name == "hlsl":
            decl.append(f"Texture2D<float4> {n};  // {tex.name}: {tex.mapper} {tex.size}")
            # sampler_<texture>: Unity's convention (the texture's own filter and wrap settings)
            decl.append(f"SamplerState sampler_{n};  // linear, clamp to edge, no mipmaps")
            fns.append(f"float3 hf_sample_{tex.name}(float u, float v) {{ "
                       f"return {n}.SampleLevel(sampler_{n}, float2(u, hf_flip_v(v)), 0).rgb; }}")
            if quantized:
                fns.append(f"float hf_sample_alpha_{tex.name}(float u, float v) {{ "
                           f"return {n}.SampleLevel(sampler_{n}, float2(u, hf_flip_v(v)), 0).a; }}")
        elif lang.name == "msl":
            fns.append(f"float3 hf_sample_{tex.name}(thread const HomofacTextures& hf, float u, float v) "
                       f"{{ return hf.{n}.sample(hf_sampler, float2(u, hf_flip_v(v)), level(0.0f)).rgb; }}")
            if quantized:
                fns.append(f"float hf_sample_alpha_{tex.name}(thread const HomofacTextures& hf, float u, float v) "
                           f"{{ return hf.{n}.sample(hf_sampler, float2(u, hf_flip_v(v)), level(0.0f)).a; }}")
        elif lang.name == "wgsl":
            decl.append(f"@group(0) @binding({2 * k}) var {n}: texture_2d<f32>;  // {tex.name}: {tex.mapper} {tex.size}")
            decl.append(f"@group(0) @binding({2 * k + 1}) var {n}_sampler: sampler;  // linear, clamp to edge")
            fns.append(f"fn hf_sample_{tex.name}(u: f32, v: f32) -> {v3} {{ "
                       f"return textureSampleLevel({n}, {n}_sampler, vec2<f32>(u, hf_flip_v(v)), 0.0).rgb; }}")
            if quantized:
                fns.append(f"fn hf_sample_alpha_{tex.name}(u: f32, v: f32) -> f32 {{ "
                           f"return textureSampleLevel({n}, {n}_sampler, vec2<f32>(u, hf_flip_v(v)), 0.0).a; }}")
    if lang.name == "wgsl":
        fns.insert(0, "fn hf_flip_v(v: f32) -> f32 { return select(v, 1.0 - v, HOMOFAC_FLIP_V); }")
    else:
        one = lang.literal(1.0, "float")
        fns.insert(0, "#ifdef HOMOFAC_FLIP_V  // the engine stores the file's first row at v = 1 (Unity ...)\n"
                   f"float hf_flip_v(float v) {{ return {one} - v; }}\n#else\nfloat hf_flip_v(float v) {{ return v; }}\n#endif")
    if lang.name == "msl":
        members = "\n".join(f"    texture2d<float> hf_{t.name} [[id({k})]];" for k, t in enumerate(model.textures))
        decl.append("struct HomofacTextures {  // an argument buffer, or fill it from the entry point's arguments\n"
                    + members + "\n};")
        decl.append("constexpr sampler hf_sampler(coord::normalized, filter::linear, mip_filter::none, "
                    "address::clamp_to_edge);")
    return decl, fns


def _msl_thread_textures(src: str, model: Factorization) -> str:
    """MSL has no global textures: thread the ``HomofacTextures`` argument through the functions that read them."""
    for fn in ("homofac_value", "homofac_term", *(f"homofac_term_{k}" for k in range(len(model.terms)))):
        for params in ("float3 a, float3 b", "int k, float3 a, float3 b"):
            src = src.replace(f"{fn}({params})", f"{fn}({params}, thread const HomofacTextures& hf)")
    for tex in model.textures:
        src = src.replace(f"hf_sample_{tex.name}(", f"hf_sample_{tex.name}(hf, ")
        src = src.replace(f"hf_sample_alpha_{tex.name}(", f"hf_sample_alpha_{tex.name}(hf, ")
    return src


def _dispatch(lang: L.Language, model: Factorization) -> str:
    """``homofac_term(int k, a, b)``: term ``k`` of ``homofac_value`` (0 for k outside 0 .. terms-1)."""
    v3, i = lang.type("vec3"), lang.type("int")
    zero = lang.literal((0.0, 0.0, 0.0), "vec3")
    hf = ", hf" if lang.name == "msl" else ""
    body = "".join(f"    if (k == {k}) {{ return homofac_term_{k}(a, b{hf}); }}\n" for k in range(len(model.terms)))
    doc = "  // term k of homofac_value (their sum); 0 outside 0 .. HOMOFAC_TERMS - 1"
    return (lang.signature("homofac_term", [("k", i), ("a", v3), ("b", v3)], v3) + " {" + doc + "\n"
            + body + f"    return {zero};\n}}")


def _entry(lang: L.Language, model: Factorization, term: bool = False) -> str:
    """The pinned entry point (``homofac_radiance`` / ``homofac_brdf``): the engine frame (``HOMOFAC_Y_UP``)
    and the validity test around ``homofac_value``; with ``term`` its per-term twin ``<entry>_term(k, a, b)``."""
    name, a, b = ENTRY[model.kind]
    v3 = lang.type("vec3")
    z = lang.literal(0.0, "float")
    valid = f"dot({a}, {b}) > {z}" if model.kind == "lighting" else f"{a}.z > {z} && {b}.z > {z}"
    msl = lang.name == "msl"
    extra = ", thread const HomofacTextures& hf" if msl else ""
    k_arg = "k, " if term else ""
    call = f"{'homofac_term' if term else 'homofac_value'}({k_arg}{a}, {b}{', hf' if msl else ''})"
    zero = lang.literal((0.0, 0.0, 0.0), "vec3")
    fname = f"{name}_term" if term else name
    if lang.name == "wgsl":
        k_param = "k: i32, " if term else ""
        swz = (f"    var {a}w = {a}_in;\n    var {b}w = {b}_in;\n"
               f"    if (HOMOFAC_Y_UP) {{ {a}w = vec3<f32>({a}_in.x, -{a}_in.z, {a}_in.y); "
               f"{b}w = vec3<f32>({b}_in.x, -{b}_in.z, {b}_in.y); }}\n") if model.kind == "lighting" else (
               f"    let {a}w = {a}_in;\n    let {b}w = {b}_in;\n")
        return (f"fn {fname}({k_param}{a}_in: {v3}, {b}_in: {v3}) -> {v3} {{\n{swz}"
                f"    let {a} = {a}w;\n    let {b} = {b}w;\n"
                f"    return select({zero}, {call}, {valid});\n}}")
    swz = ""
    if model.kind == "lighting":
        swz = (f"#ifdef HOMOFAC_Y_UP\n    {a} = {v3}({a}.x, -{a}.z, {a}.y);\n    {b} = {v3}({b}.x, -{b}.z, {b}.y);\n"
               "#endif\n")
    k_param = "int k, " if term else ""
    return (f"{v3} {fname}({k_param}{v3} {a}, {v3} {b}{extra}) {{\n{swz}"
            f"    return ({valid}) ? {call} : {zero};\n}}")


def _check_names(model: Factorization) -> None:
    """Refuse names that would not be safe in code (docs/format.md, "Names"), whoever built the model: texture
    names become identifiers (``hf_<name>``), registered mappers and projections function names."""
    for t in model.textures:
        check_texture_name(t.name)
        mappers.get(t.mapper)
    for i, term in enumerate(model.terms):
        check_identifier(term.kind, f"term {i}: kind")
        for f in term.factors:
            pj.get(f.projection)


def source(model: Factorization, language: str = "glsl", *, quantized: Quantized | None = None,
           y_up: bool = False, flip_v: bool = False) -> str:
    """The complete shader source of ``model`` in ``language`` (see the module docstring).

    ``quantized``: generate the 8-bit variant, reading the PNG textures with their decode rule.
    ``y_up``: bake ``HOMOFAC_Y_UP`` in (a define / constant that is otherwise off).
    ``flip_v``: bake ``HOMOFAC_FLIP_V`` in: the textures are stored with the file's first row at v = 1
    (Unity's importer; image loaders that flip), so every read uses ``1 - v``.
    The source has no ``#version`` line and no entry point: include it after your own (the tests
    compile it that way with glslangValidator).
    """
    lang = L.get(language)
    _check_names(model)
    q = quantized is not None
    mapper_names = list(dict.fromkeys(t.mapper for t in model.textures))
    proj_names = list(dict.fromkeys(f.projection for term in model.terms for f in term.factors))
    fns, tables = [], {}
    for name in mapper_names:
        src, tb = mapper_function(lang, name)
        fns.append(src)
        tables.update(tb)
    for name in proj_names:
        src, tb = projection_function(lang, name, model.context)
        fns.append(src)
        tables.update(tb)
    decl, samplers = _resources(lang, model, q)
    vec3_ab = [("a", "vec3"), ("b", "vec3")]
    value = L.function(lang, "homofac_value", vec3_ab, _value_graph(model, quantized),
                       doc=f"{model.name}: {len(model.terms)} term(s), {model.lookups} lookups")
    terms = [L.function(lang, f"homofac_term_{k}", vec3_ab, g,
                        doc=f"term {k} ({model.terms[k].kind}): " + " * ".join(
                            ["correction"] + [f"{f.texture}({f.projection})" for f in model.terms[k].factors]))
             for k, g in enumerate(_term_graphs(model, quantized))]
    functions = "\n".join([value, *terms, _dispatch(lang, model)])
    if lang.name == "msl":
        functions = _msl_thread_textures(functions, model)
    lines = [
        f"// homofac {__version__}: {model.kind} factorization {L.comment(repr(model.name))}, {len(model.terms)} term(s), "
        f"{model.lookups} texture lookups, {'8-bit PNG' if q else 'float EXR'} textures.",
        f"// {lang.title}. Generated from homofac's records; the interface is pinned (docs/shaders.md).",
        "// Frame: homofac world, +z up (lighting: n, v point away from the surface; v towards the viewer).",
    ]
    if lang.name in ("glsl", "glsl_es"):
        lines += ["#ifdef GL_ES", "precision highp float;", "precision highp int;", "#endif"]
    if lang.header and lang.name in ("msl",):
        lines.append(lang.header)
    if y_up and lang.name != "wgsl":
        lines.append("#define HOMOFAC_Y_UP")
    if flip_v and lang.name != "wgsl":
        lines.append("#define HOMOFAC_FLIP_V")
    if lang.name == "wgsl":
        lines.append(f"const HOMOFAC_Y_UP: bool = {'true' if y_up else 'false'};  // true: (x, y, z)_engine -> (x, -z, y)")
        lines.append(f"const HOMOFAC_FLIP_V: bool = {'true' if flip_v else 'false'};  // true: textures stored bottom-up")
    lines.append(lang.constant(lang.type("int"), "HOMOFAC_TERMS", str(len(model.terms))) + "  // terms of homofac_value")
    lines += [L.table_source(lang, n, v) for n, v in tables.items()]
    lines += decl + samplers + helper_functions(lang) + fns + [functions, _entry(lang, model), _entry(lang, model, term=True)]
    return "\n".join(lines) + "\n"


__all__ = ["ENTRY", "mapper_function", "projection_function", "source"]
