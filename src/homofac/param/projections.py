"""Projections: functions pi(a, b) of a pair of directions that a factor looks a texture up at.

A projection is one record (:class:`Projection`): its math, written once against the namespace of
its inputs (:func:`homofac.sphere.namespace`, so the same function is NumPy, JAX and -- traced by
:mod:`homofac.shader` -- shader code), whether it gives a direction or a scalar, and its doc.

Names (pinned, docs/format.md):

* BRDF (a = wi, b = wo, local frame, z = normal): ``wi``, ``wo``, ``h`` (thesis eq. 21), ``d``
  (eq. 22, the Gram-Schmidt difference vector with the surface tangent t = local +x); scalars
  ``cos_i`` = wi.z and ``cos_o`` = wo.z, clamped to [0, 1].
* Lighting (a = n, b = v, world frame): ``n``, ``v``, ``r`` (eq. 40), ``h_dom`` (eq. 67-68) and
  ``d_dom`` (eq. 69), which use the dominant light direction ``i`` (eq. 66) from the context; the
  scalar ``nv`` = n.v clamped to [0, 1]; the scalar ``nh_dom`` = ``1 - (1 - n.h')^(1/4)`` of the dominant
  light's half vector h' (:func:`_nh_light`, the highlight of that light), and ``nh_dom1``, ``nh_dom2``
  the same for the second and third light (context ``dominant1``, ``dominant2``); ``nhs_dom``, ``nhs_dom1``,
  ``nhs_dom2`` the same at the point of the light's disc closest to ``r`` (context ``radius``, ``radius1``,
  ``radius2``: :func:`_nh_disc`); ``r_off``, the off-specular reflection direction
  ``normalize(r + beta (1 - n.v) n)`` with ``beta`` the context key ``shift`` (:func:`_r_off`).

Scalar projections are looked up with the ``line`` mapper; direction projections with any other. A
projection may carry its inverse for fixed ``a`` (``invert``): the grid design of the linear-space fits
(:func:`homofac.fit.sampling.grouped_grid`) puts ``n`` and the projected direction on texel centres
and needs the view that projects there.
"""

from __future__ import annotations

import functools
from typing import Callable, NamedTuple

import numpy as np

from .. import sphere
from ..errors import HomofacError


class Projection(NamedTuple):
    """A projection ``fn(a, b, context)`` of a direction pair: ``(..., 3)`` directions or ``(...)`` scalars."""

    name: str
    kind: str  # "brdf" or "lighting"
    fn: Callable
    hemisphere: bool  # directions: always z >= 0 for valid pairs
    doc: str
    scalar: bool = False  # True: a scalar in [0, 1] (looked up with the line mapper)
    context: tuple[str, ...] = ()  # context keys the function reads (e.g. "dominant")
    #: lighting directions: ``invert(n, p, context) -> (v, density)`` in NumPy: the view with
    #: ``fn(n, v) = p`` (n.v <= 0 where none exists), and d omega_v / d omega_p divided by its supremum
    #: (in [0, 1]: the acceptance of p-uniform pairs that makes v uniform)
    invert: Callable | None = None


PROJECTIONS: dict[str, Projection] = {}
KINDS = ("brdf", "lighting")


class ContextKey(NamedTuple):
    """A key of the projection context (``factorization.json``'s ``context``): its shape and bounds."""

    name: str
    shape: tuple[int, ...]
    doc: str
    example: tuple | float  # a valid value (tests and docs derive from it)
    bounds: tuple[float, float] | None = None


#: The context keys projections read; :func:`check_context` validates a value of each.
CONTEXT_KEYS: dict[str, ContextKey] = {k.name: k for k in (
    ContextKey("dominant", (3,), "the dominant light direction [x, y, z] (NRHD, thesis eq. 66)", (0.3, -0.5, 0.81)),
    ContextKey("dominant1", (3,), "the second-brightest light direction [x, y, z] (projection nh_dom1)",
               (-0.6, 0.1, 0.78)),
    ContextKey("dominant2", (3,), "the third-brightest light direction [x, y, z] (projection nh_dom2)",
               (0.85, 0.25, 0.45)),
    ContextKey("shift", (), "beta of the off-specular reflection r_off (NRO, RO), a number in [0, 0.9]", 0.3,
               (0.0, 0.9)),
    ContextKey("radius", (), "the sine of the angular radius of the dominant light's disc (projection nhs_dom), "
               "a number in [0, 0.5]", 0.02, (0.0, 0.5)),
    ContextKey("radius1", (), "the sine of the angular radius of the second light's disc (projection nhs_dom1), "
               "a number in [0, 0.5]", 0.03, (0.0, 0.5)),
    ContextKey("radius2", (), "the sine of the angular radius of the third light's disc (projection nhs_dom2), "
               "a number in [0, 0.5]", 0.01, (0.0, 0.5)),
)}

#: The highlight projections, brightest light first, and the context key each reads (``advanced.highlights.terms``).
HIGHLIGHTS = (("nh_dom", "dominant"), ("nh_dom1", "dominant1"), ("nh_dom2", "dominant2"))
#: The highlight projections of lights with a disc (``advanced.highlights.disc``), brightest first: the projection,
#: the light's direction key and its radius key (:func:`_nh_disc`).
HIGHLIGHT_DISCS = (("nhs_dom", "dominant", "radius"), ("nhs_dom1", "dominant1", "radius1"),
                   ("nhs_dom2", "dominant2", "radius2"))


def example_context() -> dict:
    """A valid value of every context key (vectors are directions, normalised): what tests trace every
    projection with."""
    out = {}
    for k in CONTEXT_KEYS.values():
        a = np.asarray(k.example, np.float64)
        out[k.name] = float(a) if k.shape == () else a / np.linalg.norm(a)
    return out


def check_context(name: str, value):
    """``value`` of context key ``name`` as float32 (a number for a scalar key), or a one-line refusal
    (also for values that are finite but not as float32, such as 1e39)."""
    key = CONTEXT_KEYS.get(name)
    if key is None:
        raise HomofacError(f"unknown context key {name!r}; known: {', '.join(CONTEXT_KEYS)}")
    try:
        a = np.asarray(value)
    except (TypeError, ValueError):  # ragged lists
        a = None
    if a is None or a.dtype.kind not in "iuf" or a.shape != key.shape or not np.all(np.isfinite(a)) or (
            not np.all(np.abs(a.astype(np.float64)) <= np.finfo(np.float32).max)) or (
            key.bounds is not None and not np.all((a >= key.bounds[0]) & (a <= key.bounds[1]))):
        raise HomofacError(f"context.{name} must be {key.doc}, got {value!r}")
    return float(a) if key.shape == () else a.astype(np.float32)


def register(p: Projection) -> Projection:
    """Add a projection to the registry."""
    if p.kind not in KINDS:
        raise HomofacError(f"projection {p.name}: kind must be one of {', '.join(KINDS)}, got {p.kind!r}")
    PROJECTIONS[p.name] = p
    return p


def get(name: str, kind: str | None = None) -> Projection:
    """The projection registered as ``name`` (optionally checking its target kind)."""
    p = PROJECTIONS.get(name) if isinstance(name, str) else None
    if p is None:
        raise HomofacError(f"unknown projection {name!r}; known: {', '.join(PROJECTIONS)}")
    if kind is not None and p.kind != kind:
        names = ", ".join(n for n, q in PROJECTIONS.items() if q.kind == kind)
        raise HomofacError(f"projection {name} is for {p.kind} targets, not {kind}; use one of: {names}")
    return p


def apply(name: str, a, b, context: dict | None = None):
    """``pi_name(a, b)`` with the given context (e.g. ``{"dominant": (3,)}``)."""
    p = get(name)
    ctx = context or {}
    for key in p.context:
        if key not in ctx:
            raise HomofacError(f"projection {name} needs context[{key!r}] ({CONTEXT_KEYS[key].doc})")
    return p.fn(a, b, ctx)


# --- BRDF projections (local frame) ------------------------------------------------------------


def _wi(a, b, ctx):
    return a


def _wo(a, b, ctx):
    return b


def _h(a, b, ctx):
    return sphere.half_vector(a, b)


def _d(a, b, ctx):
    """Thesis eq. 22 with the local tangent t = +x."""
    h = sphere.half_vector(a, b)
    return sphere.gram_schmidt_difference(a, h, sphere.constant([1.0, 0.0, 0.0], a))


def _clamp01(x):
    return sphere.namespace(x).clip(x, 0.0, 1.0)


def _cos_i(a, b, ctx):
    return _clamp01(a[..., 2])


def _cos_o(a, b, ctx):
    return _clamp01(b[..., 2])


# --- Lighting projections (world frame) --------------------------------------------------------


def _n(n, v, ctx):
    return n


def _v(n, v, ctx):
    return v


def _r(n, v, ctx):
    return sphere.reflect(v, n)


def _nv(n, v, ctx):
    return _clamp01(sphere.dot(n, v))


def _r_inverse(n, p, ctx):
    """The view reflecting to ``p`` about ``n``: ``v = 2 (n.p) n - p`` (an isometry: density 1)."""
    return 2.0 * np.sum(n * p, -1, keepdims=True) * n - p, np.ones(np.shape(p)[:-1])


def _r_off(n, v, ctx):
    """The off-specular reflection direction ``r' = normalize(r + beta (1 - n.v) n)``, beta = ``shift``.

    Where the view grazes, a glossy lobe around ``r`` is cut by the horizon of ``n`` and what is left
    of it peaks above the horizon, toward ``n`` (the off-specular peak; Lagarde & de Rousiers 2014 bend
    ``r`` toward ``n`` for the same reason). A texture read at ``r'`` holds that shift, which a product
    of a map of ``n`` and a map of ``r`` does not; at ``v = n`` (frontal) ``r' = r``. The elevation
    ``e`` of ``r`` above the horizon of ``n`` maps to ``tan e' = (beta + (1 - beta) sin e) / cos e``,
    monotone for ``beta`` in [0, 1): ``r'`` lies at least ``atan(beta)`` above the horizon (the context
    key accepts [0, 0.9]: at 1 the map flattens at the horizon and the grid design's density degenerates).
    """
    r = sphere.reflect(v, n)
    s = ctx["shift"] * (1.0 - _clamp01(sphere.dot(n, v)))
    return sphere.normalize(r + s[..., None] * n)


def _r_off_inverse(n, p, ctx):
    """Inverse of :func:`_r_off` for fixed ``n``. With ``d = n.p`` and ``c = n.r``,
    ``(beta + (1 - beta) c) sqrt(1 - d^2) = d sqrt(1 - c^2)``, a quadratic in ``c``; then
    ``r = c n + sqrt(1 - c^2) t`` with ``t`` the tangent of ``p`` about ``n``. Both maps keep the azimuth
    about ``n``, so d omega_r / d omega_p = dc / dd."""
    beta = float(ctx["shift"])
    n, p = np.asarray(n, np.float64), np.asarray(p, np.float64)
    d = np.clip(np.sum(n * p, -1), -1.0, 1.0)
    sd2 = 1.0 - d * d
    a1, b1 = 1.0 - beta, beta
    qa = a1 * a1 * sd2 + d * d
    qb = a1 * b1 * sd2
    disc = np.maximum(qb * qb - qa * (b1 * b1 * sd2 - d * d), 0.0)
    c = (-qb + np.sqrt(disc)) / np.where(qa > 0, qa, 1.0)
    ok = (d > 0) & (b1 * np.sqrt(sd2) < d)  # above the shifted horizon atan(beta)
    c = np.where(ok, np.clip(c, 0.0, 1.0), 0.0)
    t = p - d[..., None] * n
    tl = np.linalg.norm(t, axis=-1, keepdims=True)
    t = np.where(tl > 1e-12, t / np.where(tl > 1e-12, tl, 1.0), 0.0)
    r = c[..., None] * n + np.sqrt(np.maximum(1.0 - c * c, 0.0))[..., None] * t
    v = np.where(ok[..., None], 2.0 * c[..., None] * n - r, -n)

    def dd_dc(cc):  # d(c) = u / sqrt(u^2 + 1 - c^2), u = beta + (1 - beta) c
        u = b1 + a1 * cc
        q = u * u + 1.0 - cc * cc
        return a1 / np.sqrt(q) - u * (u * a1 - cc) / q ** 1.5

    sup = 1.0 / np.min(dd_dc(np.linspace(0.0, 1.0, 1025)))
    dens = np.where(ok, 1.0 / dd_dc(c) / sup, 0.0)
    return v, np.clip(dens, 0.0, 1.0)


def _h_dom(n, v, ctx):
    """Eq. 67-68: the half vector of the dominant light i and v, in the local frame of n."""
    i = sphere.constant(ctx["dominant"], n)
    return sphere.local(sphere.half_vector(i, v), n)


def _nh_light(n, v, ctx, key: str):
    """``1 - (1 - clamp(n.h', 0, 1))^(1/4)`` with ``h' = half(i, v)``, ``i`` the context's dominant light:
    the NDF argument of that light's highlight (eq. 67's half vector, read as one scalar). A microfacet
    BRDF's highlight of a light at ``i`` is ``D(n.h') F(v.h') G / (4 n.v)``, so a ``line`` texture of
    this scalar times w(n.v) holds its shape at every view, which a product of maps of n and r cannot
    (the lobe narrows and stretches with n.v). The fourth root spreads the peak: the half angle at
    ``1 - x`` is ``theta_h = sqrt 2 (1 - x)^2``, so a 32-texel line puts six texels inside the half
    maximum of a GGX lobe of alpha 0.1 (tan theta_h = 0.064) and still 15 over theta_h < 30 degrees.
    ``1 - n.h'`` is computed as ``|n - h'|^2 / 2`` (no cancellation near the peak, where the fourth root
    would magnify float32 rounding: GPU and CPU agree to 1e-6 there). Where the light is below the
    horizon of ``n`` (``n.i <= 0``) the coordinate is 0, the far tail of the line, where the fit puts no
    light: the highlight ends at the light's horizon as the lighting does (gold under the city sun at 16
    lookups: 0.157 -> 0.144 nrmse; unclamped, pairs whose sun had set carried 23 % of the squared error)."""
    return _nh_toward(n, v, sphere.constant(ctx[key], n))


def _nh_toward(n, v, i):
    """The coordinate of :func:`_nh_light` for the light direction(s) ``i``."""
    d = n - sphere.half_vector(i, v)
    xp = sphere.namespace(d)
    e = xp.clip(xp.sqrt(0.5 * sphere.dot(d, d)), 0.0, 1.0)  # (1 - n.h')^(1/2), n.h' clamped at 0
    return xp.where(sphere.dot(n, i) > 0.0, 1.0 - xp.sqrt(e), 0.0)


def _nh_disc(n, v, ctx, key: str, radius: str):
    """:func:`_nh_light` of a light with a disc: the coordinate of the disc's point closest to the
    reflected view ``r`` (the representative point of a sphere light: Karis 2013, "Real Shading in
    Unreal Engine 4", area lights: ``l = normalize(i + c clamp(R / |c|, 0, 1))`` with ``c = max(r.i, 0) r - i``
    and ``R`` the context key ``radius``, the sine of the disc's angular radius). ``R = 0`` is
    ``nh_dom``; where ``r`` lies on the disc, ``l = r`` and the coordinate is 1 (the peak).

    At grazing views the half vector of a point light is ill-conditioned: ``|v + i|`` is ``2 n.v`` at
    the mirror direction, so a light 0.8 degrees off ``r`` out of the plane of incidence puts ``n.h'`` at
    0.88 when ``n.v`` is 0.01. An extended light (the city sun: a disc of about 1.3 degrees radius at
    light resolution 64) still has part of its disc on the mirror direction there: gold under that sun
    read 7.6 against 106 on one such pair, which held 71 % of the squared error of 270 000 uniform
    pairs (docs/notes/sums-research.md, "The sun's disc at grazing views")."""
    i = sphere.constant(ctx[key], n)
    xp = sphere.namespace(n)
    r = sphere.reflect(v, n)
    c = xp.maximum(sphere.dot(r, i), 0.0)[..., None] * r - i  # to the closest point of the ray r (none behind)
    t = xp.clip(ctx[radius] / xp.sqrt(xp.maximum(sphere.dot(c, c), 1e-20)), 0.0, 1.0)
    return _nh_toward(n, v, sphere.normalize(i + t[..., None] * c))


def _vh_light(n, v, ctx, key: str):
    """``v.h'`` clamped to [0, 1], ``h' = half(i, v)`` with ``i`` the context's light ``key``: the Fresnel
    argument of that light's highlight ``D(n.h') F(v.h') G / (4 n.v)`` (a function of the view alone for a
    fixed light). At the peak (``h' = n``) it equals ``n.v``; off the peak of a broad lobe it does not, and
    a dielectric's F rises from F0 to 1 toward grazing ``v.h'``."""
    i = sphere.constant(ctx[key], n)
    return _clamp01(sphere.dot(v, sphere.half_vector(i, v)))


def _ni_light(n, v, ctx, key: str):
    """``n.i`` clamped to [0, 1] with ``i`` the context's light ``key``: the light's cosine, the argument of
    the shadowing term ``G1(n.i)`` in ``D(n.h') F(v.h') G1(n.v) G1(n.i) / (4 n.v)`` (the cosine factor of the
    rendering equation cancels the BRDF's ``1 / n.i``). It falls to 0 at the light's horizon, where a
    highlight of a light low over ``n`` fades; ``d(nh_dom) w(n.v)`` alone keeps the peak's height there."""
    i = sphere.constant(ctx[key], n)
    return _clamp01(sphere.dot(n, i))


#: Half-width of the square of the paraboloid disk that :func:`_table_light` fills: the corner lies at radius
#: 0.6 sqrt 2 = 0.85, so the four texels of every bilinear lookup are inside the disk (valid) from 32 texels up.
TABLE_SPAN = 0.6


def table_point(s, t):
    """The direction whose ``parabolic`` coordinates are ``TABLE_SPAN (2s - 1, 2t - 1)`` (reverse thesis eq. 46
    in closed form: ``(2p, 2q, 1 - p^2 - q^2) / (1 + p^2 + q^2)``): a point (s, t) of the unit square placed
    in a parabolic map, where ``((x/(1+z)+1)/2, (y/(1+z)+1)/2)`` reads it back exactly."""
    xp = sphere.namespace(s, t)
    p, q = TABLE_SPAN * (2.0 * s - 1.0), TABLE_SPAN * (2.0 * t - 1.0)
    k = 1.0 / (1.0 + p * p + q * q)
    return xp.stack([2.0 * p * k, 2.0 * q * k, (1.0 - p * p - q * q) * k], axis=-1)


def table_cosines(u, v):
    """Inverse of :func:`_table_light` on the texture square: ``(n.i, n.v)`` of ``parabolic`` coordinates
    (u, v) (clamped to the table's square); what a table texel centre stands for."""
    xp = sphere.namespace(u, v)
    s = xp.clip(((2.0 * u - 1.0) / TABLE_SPAN + 1.0) / 2.0, 0.0, 1.0)
    t = xp.clip(((2.0 * v - 1.0) / TABLE_SPAN + 1.0) / 2.0, 0.0, 1.0)
    return s * s, t * t


def _table_light(n, v, ctx, key: str):
    """``(sqrt(n.i), sqrt(n.v))`` of the context's light ``key`` placed in a parabolic map
    (:func:`table_point`): the coordinate of a 2D table T(n.i, n.v) in a highlight term
    ``d(nh_dom) f(v.h') T(n.i, n.v)`` (``advanced.highlights.table``). Near the mirror direction a light's highlight
    is ``D F n.h'^2 min(n.v, n.i) / (n.v (n.v + n.i))`` (the height-correlated shadowing over 4 n.v), and
    ``min(1, n.i / n.v)`` is no product of a function of n.i and one of n.v: c(n.i) w(n.v) holds it only on
    average, the table exactly. Square roots spread the grazing end, where the highlight climbs
    (``sqrt(max(x, 1e-12))``: finite gradients at 0)."""
    i = sphere.constant(ctx[key], n)
    xp = sphere.namespace(n)
    s = xp.sqrt(xp.maximum(_clamp01(sphere.dot(n, i)), 1e-12))
    t = xp.sqrt(xp.maximum(_clamp01(sphere.dot(n, v)), 1e-12))
    return table_point(s, t)


def _d_dom(n, v, ctx):
    """Eq. 69: i in the Gram-Schmidt frame of the half vector h' = half(i, v) and the tangent t(n)."""
    i = sphere.constant(ctx["dominant"], n)
    return sphere.gram_schmidt_difference(i, sphere.half_vector(i, v), sphere.tangent(n))


for _p in (
    Projection("wi", "brdf", _wi, True, "incident direction wi"),
    Projection("wo", "brdf", _wo, True, "outgoing (view) direction wo"),
    Projection("h", "brdf", _h, True, "half vector, thesis eq. 21"),
    Projection("d", "brdf", _d, True, "Gram-Schmidt difference vector, thesis eq. 22"),
    Projection("cos_i", "brdf", _cos_i, True, "cos theta_i = wi.z clamped to [0, 1]", scalar=True),
    Projection("cos_o", "brdf", _cos_o, True, "cos theta_o = wo.z clamped to [0, 1]", scalar=True),
    Projection("n", "lighting", _n, False, "surface normal n"),
    Projection("v", "lighting", _v, False, "view direction v"),
    Projection("r", "lighting", _r, False, "reflected view r = 2 (n.v) n - v, eq. 40", invert=_r_inverse),
    Projection("r_off", "lighting", _r_off, False,
               "off-specular reflection normalize(r + beta (1 - n.v) n), beta = context shift", context=("shift",),
               invert=_r_off_inverse),
    Projection("nv", "lighting", _nv, False, "n.v clamped to [0, 1]", scalar=True),
    Projection("h_dom", "lighting", _h_dom, False, "half vector to the dominant light, eq. 67-68",
               context=("dominant",)),
    Projection("d_dom", "lighting", _d_dom, False, "difference vector of the dominant light, eq. 69",
               context=("dominant",)),
):
    register(_p)

# the highlight coordinates, one record per light of HIGHLIGHTS (the same math, its own context key)
for _j, (_name, _key) in enumerate(HIGHLIGHTS):
    register(Projection(_name, "lighting", functools.partial(_nh_light, key=_key), False,
                        ("1 - (1 - n.h')^(1/4) with h' the half vector of the dominant light and v (eq. 67), clamped; "
                         "0 where n.i <= 0"
                         if _j == 0 else f"nh_dom of light {_j + 1} (brightest first), context {_key}"),
                        scalar=True, context=(_key,)))

# the same of a light with a disc (``advanced.highlights.disc``), one record per light of HIGHLIGHT_DISCS
for _j, (_name, _key, _radius) in enumerate(HIGHLIGHT_DISCS):
    register(Projection(_name, "lighting", functools.partial(_nh_disc, key=_key, radius=_radius), False,
                        f"nh_dom{_j or ''} at the point of light {_j + 1}'s disc (context {_key}, radius the sine of "
                        f"its angular radius {_radius}) closest to r (Karis 2013's representative point)",
                        scalar=True, context=(_key, _radius)))

#: The Fresnel coordinates of highlight terms, one per light of HIGHLIGHTS (projection, context key).
HIGHLIGHT_FRESNEL = (("vh_dom", "dominant"), ("vh_dom1", "dominant1"), ("vh_dom2", "dominant2"))
for _j, (_name, _key) in enumerate(HIGHLIGHT_FRESNEL):
    register(Projection(_name, "lighting", functools.partial(_vh_light, key=_key), False,
                        f"v.h' with h' the half vector of light {_j + 1} (brightest first, context {_key}) and v, "
                        f"clamped to [0, 1]", scalar=True, context=(_key,)))

#: The cosine coordinates of highlight terms (``advanced.highlights.cosine``), one per light of HIGHLIGHTS.
HIGHLIGHT_COSINE = (("ni_dom", "dominant"), ("ni_dom1", "dominant1"), ("ni_dom2", "dominant2"))
for _j, (_name, _key) in enumerate(HIGHLIGHT_COSINE):
    register(Projection(_name, "lighting", functools.partial(_ni_light, key=_key), False,
                        f"n.i with i light {_j + 1} (brightest first, context {_key}), clamped to [0, 1]",
                        scalar=True, context=(_key,)))

#: The table coordinates of highlight terms (``advanced.highlights.table``), one per light of HIGHLIGHTS: read with the
#: ``parabolic`` mapper.
HIGHLIGHT_TABLE = (("ninv_dom", "dominant"), ("ninv_dom1", "dominant1"), ("ninv_dom2", "dominant2"))
for _j, (_name, _key) in enumerate(HIGHLIGHT_TABLE):
    register(Projection(_name, "lighting", functools.partial(_table_light, key=_key), True,
                        f"(sqrt(n.i), sqrt(n.v)) with i light {_j + 1} (brightest first, context {_key}) as the "
                        f"parabolic-map direction of TABLE_SPAN (2s-1, 2t-1), a 2D table's coordinate",
                        context=(_key,)))

__all__ = ["CONTEXT_KEYS", "HIGHLIGHTS", "HIGHLIGHT_DISCS", "HIGHLIGHT_COSINE", "HIGHLIGHT_FRESNEL", "HIGHLIGHT_TABLE", "TABLE_SPAN",
           "table_cosines", "table_point", "KINDS", "PROJECTIONS", "ContextKey", "Projection", "apply", "check_context", "example_context",
           "get", "register"]
