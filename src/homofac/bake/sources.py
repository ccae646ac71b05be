"""The environment's brightest compact source, taken out of the map and shaded as an analytic light.

A bake's prefiltered maps blur a sun into every lobe; at low and middle roughness that blur is most of the
bake's error (docs/notes/bake.md, "Today's bake with the brightest source as an analytic light"). So the bake
removes the brightest compact source from the lights before every filter and adds it back as a light at its
direction with the glTF lobes (:func:`source_terms`): per source of direction l, RGB power Phi (its radiance
integral, sum (L - fill) dw) and angular radius sigma,

    I_d += (1 - s5)/pi (n.l)+ Phi,   I_A += (1 - s5) S' (n.l)+ Phi,   I_B += s5 S' (n.l)+ Phi

(the pinned integrals of I_d, I_A, I_B, docs/format.md), at zero texture fetches. The source is a blob of RMS
angle sigma, not a point, so S' is the lobe convolved with it. At the peak a light direction moves the half
vector by dh = dl / 2 in the plane of incidence and dh = dl / (2 n.v) across it (u = n x v), so a source of
angular radius t covers half vectors of squared half-widths t^2 / 4 and t^2 / (4 (n.v)^2), and a GGX lobe of
width alpha in half vectors covers light directions of squared widths 4 alpha^2 and 4 (n.v)^2 alpha^2. Both
parts below are widened **per axis** by that footprint, P = (SPREAD sigma)^2 / 4, and weighted by the source's
share of the combined width in half vectors, w = S / (alpha^2 + S), S = P / (n.v) the footprint's geometric mean:

* **the core** (weight w): the source as a Gaussian blob about l in light space, read at the mirror direction
  r = 2 (n.v) n - v with the mirror's albedos, exact as alpha -> 0 (I_A -> Phi K(r) (1 - (1 - n.v)^5), I_B ->
  Phi K(r) (1 - n.v)^5); with t = r - l, t' = (t.e_1, t.e_2), e_i the source's unit principal axes and a_i its
  semi-axes (:func:`principal_axes`; a round source: |a_i| = sigma),

      K(r) = exp(-t'^T G^-1 t' - (t.l)^2 / min(G_11, G_22)) / (pi sqrt(det G) (1 + 2 Lambda(n.v))),
      G = diag((CORE |a_1|)^2, (CORE |a_2|)^2) + 4 alpha^2 (I - u' u'^T),   u' = (u.e_1, u.e_2)

  (a 2-D Gaussian with the source's covariance plus the lobe's own, 4 alpha^2 in the plane of incidence and
  4 alpha^2 (1 - |u|^2) = 4 (n.v)^2 alpha^2 across it, :func:`core_widths`; the (t.l)^2 term keeps it at l's
  side of the sphere; the Smith term at the mirror, Lambda(n.v) the glTF one);
* **the tail** (weight 1 - w): the glTF lobes at l with D the anisotropic GGX of squared widths alpha^2 + P in
  the plane of incidence and alpha^2 + P / (n.v)^2 across it (:func:`widened_ratio`; D' keeps D's normalization,
  Karis 2013's roughness modification per axis), so far from the source the tail is GGX's own.

A core wider than the source map's pixels is a box blurred by a Gaussian instead (:func:`box_widths`,
:func:`box_blob`): the same covariance G, the box taking the source's variance above BLUR pixel^2 per axis, read
in G's principal frame so the lobe's coupling g_12 is kept; a softbox's image at low roughness is flat-topped, and
a Gaussian of its covariance peaks too high at its centre and reaches too far.

Each light is shaded as two such sources of the same total power (:func:`core_and_halo`): its core, the finer
light texels at least 1/SPLIT as bright as its brightest, and its halo, the rest; one Gaussian of all the texels'
covariance is too low at a bright sun and too wide around it (forest's sun and its dimmer neighbours).

As alpha -> 0 (w -> 1) the source reads as its own image, which is what the reference reads (the source map's
pixels, bilinearly; a sun of one or two lat-long pixels is an elongated blob, close to a Gaussian of its
covariance); as alpha >> sigma (w -> 0) it is a point light. GGX widened alone has GGX's long tails and a low
peak (measured in docs/notes/bake.md, "Below 0.15, eighteenth session").
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import erfc
from jaxtyping import Array, Bool, Float

from ..brdf.gltf import gltf_lobes_at
from ..light import Environment
from ..light.environment import LUMINANCE
from .kernels import _frame, _local

#: Angular radius (rad) of the core taken out: pixels within it of the brightest one. Measured
#: (benchmarks/bake_sun.py, fast and balanced): 0.15 rad moves city 0.15-0.3 from 1.26x to 0.15x the idealized
#: split-sum but costs forest (a 5.5-degree sun) below 0.3 (balanced 1.20 -> 1.34x below 0.15); the core only
#: (0.05 rad) turns forest below 0.15 into a small gain (1.46 -> 1.36x fast) and holds the same compact suns.
RADIUS = 0.05

#: A pixel of the core is at least 1/RATIO of the brightest one's luminance (bake_sun.py's rule).
RATIO = 20.0

#: The source's extent in half vectors: (SPREAD radius)^2 / 4 in the plane of incidence, (SPREAD radius)^2 /
#: (4 (n.v)^2) across it (the tail's widening per axis), S = (SPREAD radius)^2 / (4 n.v) their geometric mean (the
#: core's weight S / (alpha^2 + S)); module docstring. Measured on every band below 0.6
#: (benchmarks/bake_source_aniso.py, docs/notes/bake.md "Below 0.3, nineteenth session"): 1.25 the smallest
#: error or within 1 % of it on 9 of the 12 cells, 1.0 up to 12 % worse (city < 0.15), 1.5 up to 7 % worse
#: (city 0.3-0.6).
SPREAD = 1.25

#: The core's widths in units of the source's semi-axes (module docstring); the axes are measured on light
#: texels' centres, and the reference's bilinear read of the source's pixels is wider. Measured with each light
#: split into its core and halo (:func:`core_and_halo`, SPLIT 6) on the cells' first 4096 weighted pairs, the
#: bakes' maps unchanged (docs/notes/bake.md, "Forest below 0.15, twentieth session"): below 0.15 city, forest,
#: interior, studio at 1.1: 0.138, 0.122, 0.137, 0.152; 1.15: 0.116, 0.116, 0.116, 0.139; **1.2: 0.108, 0.118,
#: 0.105, 0.134**; 1.25: 0.115, 0.126, 0.103, 0.136 (0.15-0.3: interior 0.087 / 0.093 / 0.100 / 0.105, the
#: others within 2 %). One Gaussian per light (before the split): 1.15 (the eighteenth session's sweep). A bake sets
#: each entry's own factor instead (:func:`core_factor`); CORE is :class:`Source`'s default.
CORE = 1.2

#: Each entry's core from its own texels (:func:`core_factor`): its width factor is 1 + CORE_PIXEL pixel / g, g =
#: sqrt(|a_1| |a_2|) the geometric mean of its semi-axes and ``pixel`` the source map's pixel angle, so the core's
#: mean width g x factor is the texels' own g plus CORE_PIXEL of a pixel (the reference reads the source's pixels
#: bilinearly, which widens a sub-pixel sun relatively more than a softbox). Measured with :data:`BLUR` on the
#: converged cells with the bakes' maps unchanged (docs/notes/bake.md, "Below 0.15, twenty-second session"): one
#: CORE fits one cell each (forest and studio 1.15, city 1.2, interior 1.25, each losing 5-13 % at the others'
#: best); below 0.15 city, forest, interior, studio at CORE_PIXEL **0.1** / 0.11 (BLUR 1/5): **0.0951, 0.1122,
#: 0.1008, 0.1108** / 0.0976, 0.1139, 0.1025, 0.1093; 0.11 with BLUR 1/3: 0.1034, 0.1144, 0.1008, 0.1214; CORE
#: 1.2 with BLUR 1/3 (before): 0.1042, 0.1192, 0.1030, 0.1225.
CORE_PIXEL = 0.1

#: A light's core and halo (:func:`core_and_halo`): its finer light texels whose excess is at least 1/SPLIT of
#: the brightest one's form the core, the rest the halo, each a Gaussian of its own covariance. Measured with
#: CORE on the cells below 0.3 (CORE's comment): below 0.15 at CORE 1.2, SPLIT 4 / 6 / 8 / 12 read forest 0.112 /
#: 0.118 / 0.135 / 0.144, city 0.117 / 0.108 / 0.108 / 0.109, interior 0.119 / 0.105 / 0.107 / 0.115, studio
#: 0.135 / 0.134 / 0.135 / 0.134 (one Gaussian: 0.149, 0.105, 0.125, 0.137).
SPLIT = 6.0

#: Smallest share of the environment's luminance power a source must hold to be taken out. The bundled
#: environments' compact sources hold 6-33 % (city's sun 23.7 %, interior's lamp 20.3 %, forest's sun core 6.1 %);
#: a uniform or smooth sky holds ~0 (its fill equals its core) and is left to the maps.
MIN_SHARE = 0.03

#: Most lights a bake takes out, each the brightest compact source of the map the previous ones left while it
#: holds MIN_SHARE of that map's power; each light is one or two bake.json entries (:func:`core_and_halo`), at
#: most 2 MAX_SOURCES = 16, bake.json's limit. On the bundled environments (balanced, 64 lights; the share of the
#: map each is taken from): city and forest one (23.6, 5.8 %; the next 0.8 and 2.0 %); interior three lamps
#: (22.3, 16.5, 6.2 %; the next 0.9 %); studio, whose four lights are softboxes of 2-8 degrees (82 % of its power),
#: eight cores of 0.05 rad (10.4, 11.7, 12.0, 4.2, 3.1, 3.9, 6.9, 5.2 %; the ninth would hold 5.9 %). Four left
#: studio's fourth light in the maps; eight measured in docs/notes/bake.md, "Studio below 0.15, twentieth session".
MAX_SOURCES = 8


class Source(NamedTuple):
    """One analytic light: unit ``direction`` (3,), RGB ``power`` (3,) (the radiance integral over the removed
    texels, W sr-free: radiance x solid angle), angular ``radius`` (rad: the power-weighted RMS angle of the
    removed texels about the direction; it widens the lobe, :data:`SPREAD`)."""

    direction: tuple[float, float, float]
    power: tuple[float, float, float]
    radius: float
    #: The source's two principal semi-axes in the plane normal to ``direction`` (rad; :func:`principal_axes`),
    #: or () for a round source of RMS angle ``radius``: the core's shape (module docstring).
    axes: tuple = ()
    #: The core's box half-widths (b_1, b_2) (rad) along its unit axes (:meth:`core_frame`; :func:`box_widths`), or
    #: () for a Gaussian core: the core is then a box of these half-widths blurred by a Gaussian of the rest of its
    #: variance (:func:`box_blob`).
    box: tuple = ()
    #: The core's widths in units of the semi-axes (:data:`CORE` when baked; bake.json's ``core``, schema 8).
    core: float = CORE

    def describe(self) -> str:
        d, p = self.direction, self.power
        shape = "" if not self.axes else f" (axes {float(np.linalg.norm(self.axes[0])):.3g}, {float(np.linalg.norm(self.axes[1])):.3g} rad)"
        box = "" if not any(self.box) else f", box {self.box[0]:.3g} x {self.box[1]:.3g} rad"
        return (f"direction ({d[0]:.3f}, {d[1]:.3f}, {d[2]:.3f}), power ({p[0]:.4g}, {p[1]:.4g}, {p[2]:.4g}), "
                f"radius {self.radius:.3g} rad{shape}{box}")

    def core_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """``(e (2, 3), s2 (2,))``: unit principal axes normal to the direction and the core's squared widths
        along them before the lobe's, (core |a_i|)^2; a round source: any orthonormal pair, (core radius)^2."""
        ell = np.asarray(self.direction, np.float64)
        a = np.asarray(self.axes, np.float64).reshape(-1, 3)
        lengths = np.linalg.norm(a, axis=1)
        if len(a) == 2 and lengths.min() > 1e-9:
            return a / lengths[:, None], (self.core * lengths) ** 2
        helper = np.array([1.0, 0.0, 0.0]) if abs(ell[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = np.cross(ell, helper)
        e1 /= np.linalg.norm(e1)
        return np.stack([e1, np.cross(ell, e1)]), np.full(2, (self.core * max(self.radius, 1e-9)) ** 2)


def brightest_source(env: Environment, radius: float = RADIUS, ratio: float = RATIO,
                     min_share: float = MIN_SHARE) -> tuple[Environment, Source | None, float]:
    """``(environment without the source, source or None, its luminance power share)``.

    The rule (benchmarks/bake_sun.py): the brightest light texel seeds the source; the texels within ``radius``
    rad of it whose luminance is at least 1/``ratio`` of the seed's form its core; they are replaced by the
    solid-angle weighted mean radiance ("fill") of the ring ``radius``-``2 radius`` around the seed (at least
    two texels wide), and the
    removed power sum (L - fill) dw becomes one point light at its power-weighted mean direction. No source
    (the environment unchanged) when the removed luminance power is below ``min_share`` of the total (a
    uniform map, a smooth sky) or not positive in every channel."""
    d = np.asarray(env.directions, np.float64)
    rad = np.asarray(env.radiance, np.float64)
    dw = np.asarray(env.solid_angle, np.float64)
    lum = rad @ np.asarray(LUMINANCE, np.float64)
    seed = int(np.argmax(lum))
    cos = d @ d[seed]
    core = (cos > np.cos(radius)) & (lum >= lum[seed] / ratio)
    outer = max(2 * radius, radius + 2 * float(np.sqrt(dw.max())))  # at least two texels wide on a coarse map
    ring = (cos <= np.cos(radius)) & (cos > np.cos(outer))
    return take_core(env, core, ring, min_share)


def take_core(env: Environment, core: Bool[np.ndarray, " N"], ring: Bool[np.ndarray, " N"],
              min_share: float = MIN_SHARE) -> tuple[Environment, Source | None, float]:
    """``(environment without the core, source or None, its luminance power share)`` for a chosen ``core`` of
    texels: they are replaced by the solid-angle weighted mean radiance of the ``ring`` texels ("fill"), and the
    removed power sum (L - fill) dw becomes one Gaussian source at its power-weighted mean direction, of the
    power-weighted RMS angle and principal axes of the removed texels. None (the environment unchanged) when
    that luminance power is below ``min_share`` of the map's or not positive in every channel."""
    d = np.asarray(env.directions, np.float64)
    rad = np.asarray(env.radiance, np.float64)
    dw = np.asarray(env.solid_angle, np.float64)
    total = float(np.sum((rad @ np.asarray(LUMINANCE, np.float64)) * dw))
    fill = (rad[ring] * dw[ring, None]).sum(0) / max(float(dw[ring].sum()), 1e-300) if ring.any() else np.zeros(3)
    excess = np.maximum(rad[core] - fill, 0.0) * dw[core, None]  # (C, 3)
    power = excess.sum(0)
    share = float(power @ np.asarray(LUMINANCE, np.float64)) / total if total > 0 else 0.0
    if not (share >= min_share and np.all(power > 0)):
        return env, None, share
    weight = excess @ np.asarray(LUMINANCE, np.float64)
    mean = weight @ d[core]
    direction = mean / np.linalg.norm(mean)
    ang = np.arccos(np.clip(d[core] @ direction, -1.0, 1.0))
    spread = float(np.sqrt(np.sum(weight * ang * ang) / np.sum(weight)))
    out = rad.copy()
    out[core] = np.minimum(rad[core], fill)
    rest = eqx.tree_at(lambda e: e.radiance, env, jnp.asarray(out, jnp.asarray(env.radiance).dtype))
    src = Source(tuple(float(c) for c in direction), tuple(float(c) for c in power), spread,
                 principal_axes(d[core], weight, direction) if spread > 0 else ())
    return rest, src, share


def principal_axes(directions, weights, direction) -> tuple:
    """The principal semi-axes a_1, a_2 ((2, 3) as nested tuples, rad) of ``weights`` (N,) at unit ``directions``
    (N, 3) about the unit ``direction``: the eigenvectors of their weighted covariance in the plane normal to it,
    each scaled by sqrt 2 x the standard deviation along it, so a Gaussian exp(-sum (t.a_i)^2 / |a_i|^4) with
    that covariance has |a_1|^2 + |a_2|^2 = 2 x its RMS angle^2 (a round source: |a_i| = its RMS angle)."""
    d = np.asarray(directions, np.float64)
    w = np.asarray(weights, np.float64)
    ell = np.asarray(direction, np.float64)
    p = d - (d @ ell)[:, None] * ell
    cov = (p * w[:, None]).T @ p / max(float(w.sum()), 1e-300)
    val, vec = np.linalg.eigh(cov)  # ascending; the smallest is along ell
    return tuple(tuple(float(c) for c in vec[:, i] * np.sqrt(2 * max(val[i], 0.0))) for i in (2, 1))


def core_and_halo(source: Source, directions, weights, split: float = SPLIT) -> tuple[Source, ...]:
    """``source`` as two Gaussians of the same total power: its core, the texels (unit ``directions`` (N, 3),
    luminance power ``weights`` (N,), measured on lights finer than the ones it was found on) whose weight is at
    least 1/``split`` of the largest, and its halo, the rest; each at its power-weighted mean direction with its
    RMS angle and :func:`principal_axes`, and ``source.power`` shared in proportion to their weights. A bright
    sun's core is narrower than the covariance of all its texels (forest's sun and its dimmer neighbours); one
    Gaussian of that covariance reads too low at the sun and too wide around it. ``(source,)`` when either part
    has fewer than two texels."""
    d = np.asarray(directions, np.float64)
    w = np.asarray(weights, np.float64)
    core = w >= w.max() / split if len(w) else np.zeros(0, bool)
    if min(int(core.sum()), int((~core).sum())) < 2:
        return (source,)
    power = np.asarray(source.power, np.float64)
    parts = []
    for part in (core, ~core):
        wp = w[part]
        mean = wp @ d[part]
        direction = mean / np.linalg.norm(mean)
        ang = np.arccos(np.clip(d[part] @ direction, -1.0, 1.0))
        parts.append(Source(tuple(float(c) for c in direction), tuple(float(c) for c in power * wp.sum() / w.sum()),
                            float(np.sqrt(np.sum(wp * ang * ang) / wp.sum())), principal_axes(d[part], wp, direction)))
    return tuple(parts)


def core_factor(source: Source, pixel: float, k: float = CORE_PIXEL) -> float:
    """The core's width factor of ``source`` (:attr:`Source.core`) from its own texels against the source map's
    ``pixel`` angle (rad): 1 + ``k`` pixel / g, g = sqrt(|a_1| |a_2|) the geometric mean of its semi-axes (a round
    source: its ``radius``), at least pixel / 4 (the finer lights' texel, below which the axes are not measured),
    so g x factor = g + ``k`` pixel: a sun narrower than a pixel gets a wider core in its own units than a softbox
    (:data:`CORE_PIXEL`)."""
    lengths = np.linalg.norm(np.asarray(source.axes, np.float64).reshape(-1, 3), axis=1)
    g = float(np.sqrt(lengths[0] * lengths[1])) if len(lengths) == 2 else float(source.radius)
    return float(1.0 + k * pixel / max(g, pixel / 4))


def with_cores(sources, pixel: float, k: float = CORE_PIXEL) -> tuple[Source, ...]:
    """``sources`` each with its :func:`core_factor` at the source map's ``pixel`` angle (rad); before
    :func:`with_boxes`, whose box takes the core's variance."""
    return tuple(s._replace(core=core_factor(s, pixel, k)) for s in sources)


def widened_ratio(a2, sx2, sy2, nh2, hx2, hy2):
    """D'(h) / D(h): the anisotropic GGX of squared widths ``a2`` + ``sx2`` (along x) and ``a2`` + ``sy2`` (along y)
    over GGX at ``a2`` (alpha^2), at the unit half vector's squared components ``hx2``, ``hy2``, ``nh2`` (h.n):
    D' = (ax^2 ay^2)^(3/2) / (pi Q^2), Q = hx^2 ay^2 + hy^2 ax^2 + (h.n)^2 ax^2 ay^2 (Heitz 2014 eq. 85, written
    without divisions), D = alpha^2 / (pi (alpha^2 (h.n)^2 + hx^2 + hy^2)^2); no cancellation at the peak."""
    ax2, ay2 = a2 + sx2, a2 + sy2
    q = hx2 * ay2 + hy2 * ax2 + nh2 * ax2 * ay2
    return (ax2 * ay2) ** 1.5 * (a2 * nh2 + hx2 + hy2) ** 2 / (a2 * q * q)


def core_widths(widths, u1, u2, a2):
    """``(G11, G12, G22)``: the core's covariance G in the source's axes (light directions, module docstring):
    ``widths`` (CORE |a_i|)^2 plus the lobe's 4 alpha^2 (I - u u^T), u = n x v of length sqrt(1 - (n.v)^2) across
    the plane of incidence (4 alpha^2 in the plane, 4 (n.v)^2 alpha^2 across it); ``u1``, ``u2`` u's components
    along the axes, ``a2`` alpha^2 (n.v enters through |u|)."""
    g = 4 * a2
    return widths[0] + g * (1 - u1 * u1), -g * u1 * u2, widths[1] + g * (1 - u2 * u2)


#: A light's core is a box blurred by a Gaussian (:func:`box_widths`): the Gaussian holds at most BLUR x the
#: source map's pixel angle squared of the core's variance per axis, the box the rest. The reference reads the
#: source's pixels bilinearly (a tent, variance pixel^2 / 6 per axis); a light no wider than that stays the
#: Gaussian of its core. Measured on the converged cells below 0.15 (docs/notes/bake.md, "Studio below 0.15,
#: twenty-first session": 1/3 with one CORE 1.2; "Below 0.15, twenty-second session": 1/5 with each entry's
#: :func:`core_factor`, about the tent's own pixel^2 / 6: below 0.15 city, forest, interior, studio at BLUR 1/6 /
#: **1/5** / 2/9 / 1/4 / 1/3 (CORE_PIXEL 0.1): 0.0944 / **0.0951** / 0.0964 / 0.0984 / 0.1046, 0.1131 / **0.1122**
#: / 0.1123 / 0.1126 / 0.1140, 0.1020 / **0.1008** / 0.1005 / 0.1003 / 0.1004, 0.1097 / **0.1108** / 0.1123 / 0.1148
#: / 0.1245; 0.15-0.3 at 1/5 against CORE 1.2, BLUR 1/3: city 0.0964 / 0.0974, forest 0.0861 / 0.0863, interior
#: 0.0839 / 0.0846, studio 0.1027 / 0.1022).
BLUR = 1.0 / 5.0


def box_widths(source: Source, pixel: float, blur: float = BLUR) -> tuple:
    """``(b_1, b_2)``: the half-widths (rad) of the box along the core's axes (:meth:`Source.core_frame`). The core's
    variance along axis i is V_i = (CORE |a_i|)^2 / 2 (the Gaussian's); the box takes the part above ``blur``
    ``pixel``^2 (``pixel`` the source map's pixel angle, rad): v_i = max(0, V_i - blur pixel^2), b_i = sqrt(3 v_i)
    (a box of half-width b has variance b^2 / 3), and the Gaussian the rest, so the total variance is the
    Gaussian core's. () for a round source or when both are 0 (a compact sun: the Gaussian core)."""
    if len(source.axes) != 2:
        return ()
    _, widths = source.core_frame()
    v = np.maximum(widths / 2 - blur * pixel * pixel, 0.0)
    return tuple(float(b) for b in np.sqrt(3 * v)) if np.any(v > 0) else ()


def with_boxes(sources, pixel: float, blur: float = BLUR) -> tuple[Source, ...]:
    """``sources`` each with its :func:`box_widths` at the source map's ``pixel`` angle (rad)."""
    return tuple(s._replace(box=box_widths(s, pixel, blur)) for s in sources)


def box_profile(s, b, g):
    """The 1-D box of half-width ``b`` (unit integral) convolved with exp(-s^2 / g) / sqrt(pi g) (variance g / 2),
    at offset ``s``: (erfc((|s| - b) / sqrt g) - erfc((|s| + b) / sqrt g)) / (4 b), written with erfc so the tails
    do not cancel; the Gaussian itself where b < 1e-3 sqrt g (the box's limit b -> 0)."""
    sg = jnp.sqrt(g)
    a = jnp.abs(s)
    bs = jnp.maximum(b, 1e-3 * sg)
    box = (erfc((a - bs) / sg) - erfc((a + bs) / sg)) / (4 * bs)
    return jnp.where(b >= 1e-3 * sg, box, jnp.exp(-s * s / g) / jnp.sqrt(jnp.pi * g))


def box_blob(t1, t2, g11, g12, g22, b1, b2):
    """The core's 2-D profile at offset (t1, t2) in the source's axes: its box of half-widths (b1, b2) blurred by
    the Gaussian of the rest of the total covariance G / 2 (G = (g11, g12; g12, g22) of :func:`core_widths`, the
    source's and the lobe's, coupled by g12), unit integral. It is read in G's principal frame f_1, f_2 (angle
    theta, tan 2 theta = 2 g12 / (g11 - g22), eigenvalues lambda_i): per axis the box's variance projected on f_i,
    c_i = (2/3) (b1^2 cos^2 + b2^2 sin^2) in G's units (swapped for f_2), and the Gaussian the rest, lambda_i - c_i
    (>= 0: G minus the box's covariance is the Gaussian part's and the lobe's), the product of two
    :func:`box_profile`. The second moments are G's exactly; the box's own cross term in G's frame is dropped. As
    b -> 0 it is the Gaussian exp(-t^T G^-1 t) / (pi sqrt det G) (the built core); with no lobe G is diagonal in
    the source's axes and it is the source's box blurred, exactly."""
    d = jnp.sqrt((g11 - g22) ** 2 + 4 * g12 * g12)
    big = d > 1e-6 * (g11 + g22)
    c2 = jnp.where(big, (g11 - g22) / jnp.where(big, d, 1.0), 1.0)
    s2 = jnp.where(big, 2 * g12 / jnp.where(big, d, 1.0), 0.0)
    cos2, sin2 = (1 + c2) / 2, (1 - c2) / 2
    cs, sn = jnp.sqrt(cos2), jnp.where(s2 < 0, -1.0, 1.0) * jnp.sqrt(sin2)
    lam1, lam2 = (g11 + g22 + d) / 2, (g11 + g22 - d) / 2
    bb1, bb2 = b1 * b1, b2 * b2
    v1, v2 = bb1 * cos2 + bb2 * sin2, bb1 * sin2 + bb2 * cos2  # the box's variance x 3 along f_1, f_2
    r1 = jnp.maximum(lam1 - 2 * v1 / 3, 1e-3 * lam1)
    r2 = jnp.maximum(lam2 - 2 * v2 / 3, 1e-3 * lam2)
    return (box_profile(cs * t1 + sn * t2, jnp.sqrt(v1), r1) * box_profile(cs * t2 - sn * t1, jnp.sqrt(v2), r2))


def source_terms(sources, n: Float[Array, "N 3"], v: Float[Array, "N 3"], roughness) -> Float[Array, "N 3 3"]:
    """``(I_d, I_A, I_B)`` (N, 3, 3) of the analytic lights ``sources`` (a sequence of :class:`Source`) at the
    pairs: I_d the point light's, I_A and I_B the core and the tail of the lobe convolved with the source, each
    widened per axis of the plane of incidence (module docstring), times each power; 0 where n.v <= 0 or
    n.l <= 0."""
    n = jnp.asarray(n, jnp.float32)
    v = jnp.asarray(v, jnp.float32)
    rho = jnp.broadcast_to(jnp.asarray(roughness, jnp.float32), n.shape[:1])
    out = jnp.zeros(n.shape[:1] + (3, 3), jnp.float32)
    if not sources:
        return out
    t, b = _frame(n)
    wo = _local(v, t, b, n)
    a2 = rho ** 4
    x = jnp.where(wo[2] > 0, wo[2], 1.0)
    r = 2 * x[:, None] * n - v
    u = jnp.cross(n, v)  # across the plane of incidence, |u|^2 = 1 - x^2
    ut2 = jnp.maximum(wo[0] * wo[0] + wo[1] * wo[1], 1e-12)  # |u|^2 in the local frame, u = (-wo_y, wo_x, 0)
    lam = 0.5 * (jnp.sqrt(1 + a2 * (1 - x * x) / (x * x)) - 1)
    m5 = (1 - x) ** 5
    for s in sources:  # a handful of lights, not samples
        ell = jnp.asarray(s.direction, jnp.float32)
        wi = _local(jnp.broadcast_to(ell, n.shape), t, b, n)
        above = (wi[2] > 0) & (wo[2] > 0)
        wi = tuple(jnp.where(above, c, 0.0 if i < 2 else 1.0) for i, c in enumerate(wi))
        wo_ = (wo[0], wo[1], x)
        d, la, lb = gltf_lobes_at(rho, wi, wo_)
        h = [a + c for a, c in zip(wi, wo_)]
        hn2 = h[0] * h[0] + h[1] * h[1] + h[2] * h[2]
        hy2 = (h[1] * wo[0] - h[0] * wo[1]) ** 2 / ut2 / hn2
        sin2 = (h[0] * h[0] + h[1] * h[1]) / hn2
        base = (SPREAD * s.radius) ** 2 / 4
        k = widened_ratio(a2, base, base / (x * x), jnp.maximum(h[2], 0.0) ** 2 / hn2,
                          jnp.maximum(sin2 - hy2, 0.0), hy2)
        S = base / x
        w = S / (a2 + S) if s.radius > 0 else jnp.zeros_like(x)
        axes, widths = s.core_frame()
        e1, e2 = (jnp.asarray(a, jnp.float32) for a in axes)
        g11, g12, g22 = core_widths(widths.astype(np.float32), u @ e1, u @ e2, a2)
        det = g11 * g22 - g12 * g12
        e = r - ell
        t1, t2, t3 = e @ e1, e @ e2, e @ ell
        if any(s.box):
            blob = box_blob(t1, t2, g11, g12, g22, *s.box) * jnp.exp(-t3 * t3 / jnp.minimum(g11, g22)) / (1 + 2 * lam)
        else:
            q = (g22 * t1 * t1 - 2 * g12 * t1 * t2 + g11 * t2 * t2) / det + t3 * t3 / jnp.minimum(g11, g22)
            blob = jnp.exp(-q) / (jnp.pi * jnp.sqrt(det)) / (1 + 2 * lam)
        tail = jnp.stack([d, la * k, lb * k], 1) * wi[2][:, None]  # (N, 3)
        core = jnp.stack([jnp.zeros_like(x), (1 - m5) * blob, m5 * blob], 1)
        lobes = jnp.where(above[:, None], (1 - w)[:, None] * tail + w[:, None] * core, 0.0)
        lobes = lobes.at[:, 0].set(jnp.where(above, tail[:, 0], 0.0))
        out = out + lobes[:, :, None] * jnp.asarray(s.power, jnp.float32)[None, None, :]
    return out


__all__ = ["BLUR", "CORE", "CORE_PIXEL", "MAX_SOURCES", "MIN_SHARE", "RADIUS", "RATIO", "SPLIT", "SPREAD", "Source", "box_blob", "box_profile", "box_widths", "brightest_source", "with_boxes",
           "core_and_halo", "core_factor", "core_widths", "with_cores",
           "principal_axes", "take_core", "source_terms", "widened_ratio"]
