"""GLSL generated from the mapper and parametrization data the solver uses (one place, tested).

The GPU must compute exactly what :meth:`homofac.fit.factorization.Factorization.evaluate` computes:
``correction * prod_j bilinear(t_k(j), mapper(pi_j(a, b)))``. This module is the single GLSL twin of
that math. It holds

* :data:`SPHERE_GLSL`: the helpers of :mod:`homofac.sphere` (normalize with the zero guard, tangent
  t(n) with its fallback, frame, half vector, Gram-Schmidt difference vector);
* :data:`MAPPER_GLSL`: per registered mapper (:data:`homofac.param.mappers.MAPPERS`) a function
  ``void hf_map_<name>(vec3 d, out int face, out float u, out float v)``, the twin of
  ``Mapper.to_face_uv``; the cube table is generated from the very arrays the Python mapper uses;
* :data:`PROJECTION_GLSL`: per registered projection (:data:`homofac.param.parametrizations.PROJECTIONS`)
  a function ``vec3 hf_proj_<name>(vec3 a, vec3 b)`` (context: ``uniform vec3 u_dominant``);

and :func:`evaluation_glsl` generates, from a :class:`~homofac.param.parametrizations.Parametrization`
(its factors and textures) and a mapper, the function ``vec3 hf_value(vec3 a, vec3 b)``: per factor the
projection, the mapper, the bilinear footprint of :func:`homofac.param.mappers.bilinear` (clamp to the
face, corners outside ``valid_mask`` dropped and the weights renormalised, reads redirected to the
nearest valid texel, all through ``texelFetch`` on an integer table of nearest valid texels), and the
product with the correction colour. No hardware filtering is used anywhere: GL equals CPU.

``tests/test_gl.py`` checks every registered mapper and projection (and the whole evaluation) against
the Python functions on the GPU; a mapper or projection registered without GLSL is a clear
:class:`~homofac.errors.HomofacError` when a shader for it is generated. Add GLSL for a new one with
:func:`register_mapper_glsl` / :func:`register_projection_glsl`.
"""

from __future__ import annotations

import numpy as np

from ..errors import HomofacError
from ..param import mappers
from ..param import parametrizations as pz

GLSL_VERSION = "#version 330 core"


def _f(x: float) -> str:
    """A float literal GLSL reads back to the same float32."""
    return repr(float(np.float32(x))) if np.isfinite(x) else "0.0"


# --------------------------------------------------------------------------------------------------
# homofac.sphere

SPHERE_GLSL = f"""
const float HF_TINY = {_f(1e-12)};
vec3 hf_normalize(vec3 a) {{  // sphere.normalize: a zero vector stays zero
    float n2 = dot(a, a);
    return n2 > HF_TINY * HF_TINY ? a / sqrt(n2) : vec3(0.0);
}}
vec3 hf_half(vec3 a, vec3 b) {{ return hf_normalize(a + b); }}  // sphere.half_vector
vec3 hf_reflect(vec3 v, vec3 n) {{ return 2.0 * dot(n, v) * n - v; }}  // sphere.reflect, r = 2 (n.v) n - v
vec3 hf_tangent(vec3 n) {{  // sphere.tangent, Latta-Kolb eq. 6, fallback +y at n = +-x
    vec3 t = vec3(1.0, 0.0, 0.0) - n.x * n;
    vec3 fallback = vec3(0.0, 1.0, 0.0);
    return dot(t, t) > {_f(1e-14)} ? hf_normalize(t) : fallback - dot(fallback, n) * n;
}}
vec3 hf_to_local(vec3 d, vec3 t, vec3 b, vec3 n) {{ return vec3(dot(d, t), dot(d, b), dot(d, n)); }}
vec3 hf_local(vec3 d, vec3 n) {{  // d in the frame (t(n), n x t(n), n) of sphere.frame
    vec3 t = hf_tangent(n);
    return hf_to_local(d, t, cross(n, t), n);
}}
vec3 hf_tangent_against(vec3 t, vec3 h) {{  // sphere.tangent_against
    vec3 tp = t - dot(t, h) * h;
    return dot(tp, tp) > {_f(1e-14)} ? hf_normalize(tp) : hf_tangent(h);
}}
vec3 hf_gram_schmidt(vec3 a, vec3 h, vec3 t) {{  // sphere.gram_schmidt_difference
    vec3 tp = hf_tangent_against(t, h);
    return hf_to_local(a, tp, cross(h, tp), h);
}}
"""


# --------------------------------------------------------------------------------------------------
# Mappers: twins of Mapper.to_face_uv (DESIGN.md table, pinned).

MAPPER_GLSL: dict[str, str] = {}


def register_mapper_glsl(name: str, source: str) -> None:
    """GLSL of ``hf_map_<name>(vec3 d, out int face, out float u, out float v)`` for a registered mapper."""
    MAPPER_GLSL[name] = source


def _vec3_table(name: str, rows: np.ndarray) -> str:
    items = ", ".join(f"vec3({', '.join(_f(x) for x in r)})" for r in rows)
    return f"const vec3 {name}[{len(rows)}] = vec3[{len(rows)}]({items});"


register_mapper_glsl("parabolic", """
void hf_map_parabolic(vec3 d, out int face, out float u, out float v) {
    float den = max(1.0 + d.z, HF_TINY);
    face = 0; u = (d.x / den + 1.0) / 2.0; v = (d.y / den + 1.0) / 2.0;
}""")

register_mapper_glsl("dual_paraboloid", """
void hf_map_dual_paraboloid(vec3 d, out int face, out float u, out float v) {
    float den = 1.0 + abs(d.z);
    face = d.z < 0.0 ? 1 : 0; u = (d.x / den + 1.0) / 2.0; v = (d.y / den + 1.0) / 2.0;
}""")

# The cube tables are the arrays of homofac.param.mappers (major axis, sc axis, tc axis per face).
register_mapper_glsl("cube", "\n".join([
    "",
    _vec3_table("HF_CUBE_N", mappers._CUBE_N),
    _vec3_table("HF_CUBE_SC", mappers._CUBE_SC),
    _vec3_table("HF_CUBE_TC", mappers._CUBE_TC),
    """void hf_map_cube(vec3 d, out int face, out float u, out float v) {
    vec3 a = abs(d);  // ties in the major axis go to x, then y, then z
    bool is_x = a.x >= a.y && a.x >= a.z;
    bool is_y = !is_x && a.y >= a.z;
    face = is_x ? (d.x >= 0.0 ? 0 : 1) : (is_y ? (d.y >= 0.0 ? 2 : 3) : (d.z >= 0.0 ? 4 : 5));
    float ma = max(dot(HF_CUBE_N[face], d), HF_TINY);
    u = (dot(HF_CUBE_SC[face], d) / ma + 1.0) / 2.0;
    v = (dot(HF_CUBE_TC[face], d) / ma + 1.0) / 2.0;
}"""]))

register_mapper_glsl("octahedral", """
float hf_sign(float a) { return a >= 0.0 ? 1.0 : -1.0; }  // sign(0) = +1 (pinned)
void hf_map_octahedral(vec3 d, out int face, out float u, out float v) {
    float l1 = max(abs(d.x) + abs(d.y) + abs(d.z), HF_TINY);
    float px = d.x / l1, py = d.y / l1;
    bool lower = d.z < 0.0;
    float qx = lower ? (1.0 - abs(py)) * hf_sign(px) : px;
    float qy = lower ? (1.0 - abs(px)) * hf_sign(py) : py;
    face = 0; u = (qx + 1.0) / 2.0; v = (qy + 1.0) / 2.0;
}""")

register_mapper_glsl("hemispherical", """
void hf_map_hemispherical(vec3 d, out int face, out float u, out float v) {
    face = 0; u = (d.x + 1.0) / 2.0; v = (d.y + 1.0) / 2.0;
}""")

register_mapper_glsl("spherical", """
void hf_map_spherical(vec3 d, out int face, out float u, out float v) {
    float m = 2.0 * sqrt(max(d.x * d.x + d.y * d.y + (d.z + 1.0) * (d.z + 1.0), HF_TINY * HF_TINY));
    bool pole = d.x * d.x + d.y * d.y < HF_TINY * HF_TINY && d.z < 0.0;  // exactly -z: the rim point
    face = 0; u = pole ? 1.0 : d.x / m + 0.5; v = pole ? 0.5 : d.y / m + 0.5;
}""")


# --------------------------------------------------------------------------------------------------
# Projections: twins of the functions in homofac.param.parametrizations.

PROJECTION_GLSL: dict[str, str] = {}


def register_projection_glsl(name: str, source: str) -> None:
    """GLSL of ``vec3 hf_proj_<name>(vec3 a, vec3 b)`` for a registered projection."""
    PROJECTION_GLSL[name] = source


for _name, _body in {
    "wi": "return a;",
    "wo": "return b;",
    "h": "return hf_half(a, b);",
    "d": "return hf_gram_schmidt(a, hf_half(a, b), vec3(1.0, 0.0, 0.0));",  # local tangent = +x
    "n": "return a;",
    "v": "return b;",
    "r": "return hf_reflect(b, a);",
    "h_dom": "return hf_local(hf_half(u_dominant, b), a);",  # eq. 67-68
    "d_dom": "return hf_gram_schmidt(u_dominant, hf_half(u_dominant, b), hf_tangent(a));",  # eq. 69
}.items():
    register_projection_glsl(_name, f"vec3 hf_proj_{_name}(vec3 a, vec3 b) {{ {_body} }}")


def _need(table: dict, name: str, what: str) -> str:
    if name not in table:
        raise HomofacError(f"no GLSL for {what} {name!r}; add it with homofac.gl.glsl.register_{what}_glsl()")
    return table[name]


def mapper_glsl(name: str) -> str:
    """The GLSL mapper function of a registered mapper (HomofacError when there is none)."""
    mappers.get(name)
    return _need(MAPPER_GLSL, name, "mapper")


def projection_glsl(name: str) -> str:
    """The GLSL projection function of a registered projection (HomofacError when there is none)."""
    if name not in pz.PROJECTIONS:
        raise HomofacError(f"unknown projection {name!r}; known: {', '.join(pz.PROJECTIONS)}")
    return _need(PROJECTION_GLSL, name, "projection")


def library_glsl(mapper: str | None = None, projections=()) -> str:
    """Declarations every generated shader shares: ``u_dominant``, sphere helpers, a mapper, projections."""
    parts = ["uniform vec3 u_dominant;", SPHERE_GLSL]
    if mapper is not None:
        parts.append(mapper_glsl(mapper))
    for name in dict.fromkeys(projections):
        parts.append(projection_glsl(name))
    return "\n".join(parts)


def lookup_glsl(mapper: str, S: int) -> str:
    """``vec3 hf_lookup(sampler2D tex, vec3 d)``: :func:`homofac.param.mappers.lookup` with texelFetch.

    Needs ``uniform isampler2D u_nearest`` (flat index of the nearest valid texel, the identity on
    valid texels: ``mappers._nearest_valid``), so a corner is valid exactly when it maps to itself.
    """
    m = mappers.get(mapper)
    W = m.faces * S
    return f"""
uniform isampler2D u_nearest;
const int HF_S = {S};
const int HF_W = {W};
int hf_nearest(int i) {{ return texelFetch(u_nearest, ivec2(i % HF_W, i / HF_W), 0).r; }}
vec3 hf_texel(sampler2D tex, int i) {{ return texelFetch(tex, ivec2(i % HF_W, i / HF_W), 0).rgb; }}
vec3 hf_lookup(sampler2D tex, vec3 d) {{  // mappers.bilinear, thesis eq. 33-34
    int face; float u, v;
    hf_map_{mapper}(d, face, u, v);
    float cu = clamp(u * float(HF_S) - 0.5, 0.0, float(HF_S) - 1.0);
    float cv = clamp(v * float(HF_S) - 0.5, 0.0, float(HF_S) - 1.0);
    float j0 = clamp(floor(cu), 0.0, float(HF_S) - 2.0);
    float i0 = clamp(floor(cv), 0.0, float(HF_S) - 2.0);
    float au = cu - j0, av = cv - i0;
    float bu = 1.0 - au, bv = 1.0 - av;
    int base = int(i0) * HF_W + face * HF_S + int(j0);
    int idx[4] = int[4](base, base + 1, base + HF_W, base + HF_W + 1);
    float w[4] = float[4](bu * bv, au * bv, bu * av, au * av);
    int near[4];
    float wv[4];
    float total = 0.0;
    for (int k = 0; k < 4; k++) {{
        near[k] = hf_nearest(idx[k]);
        wv[k] = near[k] == idx[k] ? w[k] : 0.0;
        total += wv[k];
    }}
    vec3 sum = vec3(0.0);
    for (int k = 0; k < 4; k++) {{
        float wk = total > 0.0 ? wv[k] / total : w[k];
        sum += wk * hf_texel(tex, near[k]);
    }}
    return sum;
}}
"""


def evaluation_glsl(parametrization: str, mapper: str, S: int) -> str:
    """GLSL of ``vec3 hf_value(vec3 a, vec3 b)``, the factorization of eq. 45, generated from the data.

    Uniforms: ``u_tex0 .. u_tex{T-1}`` (RGB32F linear textures), ``u_nearest``, ``u_correction``,
    ``u_dominant``. One line per factor ``j``: ``value *= hf_lookup(u_tex<k(j)>, hf_proj_<pi_j>(a, b))``.
    """
    p = pz.get(parametrization)
    lines = [library_glsl(mapper, [f.projection for f in p.factors]), lookup_glsl(mapper, S)]
    lines += [f"uniform sampler2D u_tex{k};  // texture {name!r}" for k, name in enumerate(p.textures)]
    lines.append("uniform vec3 u_correction;")
    body = [f"    value *= hf_lookup(u_tex{f.texture}, hf_proj_{f.projection}(a, b));" for f in p.factors]
    lines.append(
        f"vec3 hf_value(vec3 a, vec3 b) {{  // {p.name}: {p.doc}\n    vec3 value = u_correction;\n"
        + "\n".join(body)
        + "\n    return value;\n}"
    )
    return "\n".join(lines)


def nearest_table(mapper: str, S: int) -> np.ndarray:
    """The int32 ``(H, W)`` table behind ``u_nearest`` (nearest valid texel; identity where valid)."""
    m = mappers.get(mapper)
    return np.asarray(mappers._nearest_valid(m.name, S), np.int32).reshape(S, m.faces * S)


__all__ = [
    "GLSL_VERSION", "MAPPER_GLSL", "PROJECTION_GLSL", "SPHERE_GLSL", "evaluation_glsl", "library_glsl",
    "lookup_glsl", "mapper_glsl", "nearest_table", "projection_glsl", "register_mapper_glsl",
    "register_projection_glsl",
]
