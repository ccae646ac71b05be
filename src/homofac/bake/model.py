"""A bake: the textures of one environment and how they give I_d, I_A, I_B (hence L of any glTF material).

    u(rho)   = (layers - 1) log(rho / rho_0) / log(rho_last / rho_0), clamped to [0, layers - 1]
    P_k      = sum_j hat(u - j) P_kj(a_j),  a_j = normalize((1 - s_j) r + s_j n)   (two layers, blended by hand;
               P_kj read at its block's face in map k's atlas, e.g. P_2 at half the layer's face in balanced)
    T_c      = sum_j hat(u - j) line(T_jc, n.v)                 (the RGB weight tables, bilinear in (n.v, u))
    I_A = sum_k P_k a_k,   I_B = sum_k P_k b_k,   I_d = sum_d E_d(n) w_d          (a_k = T_2k, b_k = T_2k+1)

With the plan's ``diffuse_basis`` ``sh9``, E_d(n) is ``sum_i c_di Y_i(n)`` instead (the 9 real SH of
:mod:`homofac.light.sh`, pinned order, +z up; c_d the least-squares projection of the E_d map on them,
:func:`diffuse_sh9`): no texture fetch, the weights w_d unchanged.

With the plan's ``harmonic`` (the layers from that roughness up), the luminance's second azimuthal harmonic about
each layer's axis is added, coloured as the products (:func:`homofac.bake.gauge.gauge_read`, :func:`harmonic_colour`):

    H = sum_j hat(u - j) t_j^T M_j(a_j) t_j,   t_j = normalize(n - (n.a_j) a_j)
      (M_j stored in 3 channels, the face gauge of :mod:`.gauge`: t^T M t = t_u^2 M'_uu + t_v^2 M'_vv + 2 t_u t_v M'_uv)
    I_A <- I_A max(0, 1 + h_A H / Y(I_A)),     I_B <- I_B max(0, 1 + h_B H / Y(I_B))   (h_A, h_B: table channels)

With the plan's ``shared_gain`` the tables hold h_A only and I_B takes I_A's gain: I_B <- I_B max(0, 1 + h_A H / Y(I_A)).

With the plan's ``mixed`` (:meth:`~homofac.bake.plan.BakePlan.layer_terms`) the harmonic layers store P_K = 0
and h_A, h_B in a_K, b_K's channels, and the layer below them stores P_K = 0, a_K = b_K = 0 and no tensor: the
formulas above then hold unchanged with h_A = T_{2K-2}, h_B = T_{2K-1} (every blended channel is, in both
layers of a blend, either one meaning or 0).

with hat(t) = max(0, 1 - |t|), r = 2 (n.v) n - v, every 2D read the cube mapper's bilinear lookup and every
n.v read the line mapper's (:func:`homofac.param.mappers.lookup`: what the GPU's filter computes on the
clamped coordinates). Pairs with n.v <= 0 give 0.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..errors import HomofacError
from ..light.integrals import material_radiance
from ..light.environment import LUMINANCE
from ..light.sh import SH9_NORM
from ..param import mappers
from .atlas import Atlas, down, pack
from .gauge import gauge_read
from .plan import BakePlan
from .sources import Source, source_terms

#: Writers of a bake's directory, registered by :mod:`homofac.output` (a layer above this one).
_WRITERS: list = []


def register_writer(fn) -> None:
    """Let ``Bake.save`` call ``fn(bake, out_dir, **kwargs)`` (:mod:`homofac.output` registers its writer)."""
    _WRITERS[:] = [fn]


@dataclasses.dataclass(frozen=True)
class Bake:
    """The textures of a bake (float32) and its record.

    ``P[j]`` (S_j, 6 S_j, K, 3): layer j of the K prefiltered maps; ``E`` (S_E, 6 S_E, D, 3): the diffuse maps;
    ``W`` (layers, X, 2K + D): the weight tables' channels a_1, b_1, ..., a_K, b_K, w_1, ..., w_D (three
    per RGB table when saved); ``blocks[j]`` the first layer whose block layer j shares (``P[j]`` is then that
    layer's array; empty: every layer its own block); ``roughness`` the layers' roughnesses; ``shift`` each layer's
    axis shift s (P_kj is read at a_j = normalize((1 - s_j) r + s_j n)); ``info`` provenance and timings
    (JSON-friendly); ``sh`` (D, 9, 3) the SH9 coefficients of the E_d maps when the plan's ``diffuse_basis`` is
    ``sh9`` (then ``E`` is not read and may be None); ``sources`` the analytic lights taken out of the map
    (:mod:`.sources`), whose exact glTF lobes the integrals add; ``H[j]`` (S_j, 6 S_j, 3) layer j's tensor map
    of the luminance's second harmonic in the face gauge (M'_uu, M'_vv, M'_uv; :mod:`.gauge`), or None (the plan's ``harmonic``; empty
    without it; the tables' last two channels are then h_A, h_B); ``layouts[i]`` the blocks of specular map
    ``P<i>`` in its own atlas (:class:`~.atlas.Atlas`, one per map, read from bake.json's schema 5; empty: every
    map in :func:`~.atlas.pack`'s layout). ``P`` and ``H`` hold every layer at its face S_j; map i of layer j is
    read at its block's size ``layouts[i].sizes[j]`` (S_j or S_j / 2^m: the layer box-averaged per face,
    :meth:`read_maps`), as the shaders read it.
    """

    plan: BakePlan
    roughness: tuple[float, ...]
    shift: tuple[float, ...]
    P: tuple[Any, ...]
    E: Any
    W: Any
    info: dict
    sh: Any = None
    blocks: tuple[int, ...] = ()
    sources: tuple[Source, ...] = ()
    H: tuple[Any, ...] = ()
    layouts: tuple[Atlas, ...] = ()

    # --- structure -------------------------------------------------------------------------------------
    @property
    def lookups(self) -> int:
        """Texture fetches per pixel (pinned: a hand blend of two layers counts 2)."""
        return self.plan.lookups

    @property
    def atlases(self) -> tuple[Atlas, ...]:
        """The layout of each specular map ``P<i>``'s layers in its own 2D texture (:mod:`.atlas`), one per map."""
        if self.layouts:
            return tuple(self.layouts)
        return (pack([int(p.shape[0]) for p in self.P], self.blocks or None),) * self.plan.maps

    @property
    def atlas(self) -> Atlas:
        """The first specular map's layout (``atlases[0]``)."""
        return self.atlases[0]

    def texture_bytes(self, bytes_per_channel: int = 2) -> int:
        """GPU memory of the textures in half floats, all RGB (the harmonic's tensor in its 3 face-gauge channels):
        each P map's atlas, the E_d maps, the weight tables."""
        p = sum(a.width * a.height for a in self.atlases) * 3
        e = self.plan.diffuse * 6 * self.plan.diffuse_size ** 2 * 3 if self.plan.diffuse_basis == "texture" else 0
        w = self.plan.tables * self.plan.layers * self.plan.nv_size * 3
        return (p + e + w) * bytes_per_channel

    def describe(self) -> str:
        return (f"{self.plan.describe()}; layers {', '.join(f'{r:.3g}' for r in self.roughness)}; sizes "
                f"{', '.join(str(int(p.shape[0])) for p in self.P)}; {self.texture_bytes() / 1e6:.2f} MB in half floats; "
                f"analytic source: {self._sources_line()}")

    def _sources_line(self) -> str:
        """The analytic sources (direction, power, power share, radius) or ``none``, with the share found."""
        record = (self.info or {}).get("analytic_source", {})
        share = record.get("share")
        pct = f"{100 * share:.1f} % of the power" if share is not None else ""
        if not self.sources:
            return f"none (brightest compact source {pct})" if pct else ("none (off)" if record else "none")
        return "; ".join(s.describe() for s in self.sources) + (f", {pct}" if pct else "")

    # --- evaluation ------------------------------------------------------------------------------------
    def layer_coordinate(self, roughness) -> Array:
        """u(rho) of the module docstring (continuous layer index)."""
        r = jnp.asarray(self.roughness, jnp.float32)
        rho = jnp.clip(jnp.asarray(roughness, jnp.float32), r[0], r[-1])
        return jnp.clip((len(self.roughness) - 1) * jnp.log(rho / r[0]) / jnp.log(r[-1] / r[0]), 0.0,
                        len(self.roughness) - 1)

    def terms(self, n: Float[Array, "N 3"], v: Float[Array, "N 3"], roughness) -> Float[Array, "N 3 3"]:
        """``(I_d, I_A, I_B)`` stacked on axis 1 (N, 3, 3): the bake's approximation of
        :func:`homofac.light.integrals.integrals` (the maps' products plus the sources' exact lobes)."""
        n = jnp.asarray(n, jnp.float32)
        v = jnp.asarray(v, jnp.float32)
        rho = jnp.broadcast_to(jnp.asarray(roughness, jnp.float32), n.shape[:1])
        sh9 = self.plan.diffuse_basis == "sh9"
        if sh9 and self.sh is None:
            raise HomofacError("this bake's plan reads the diffuse term from SH9 coefficients, and it has none")
        diffuse = jnp.asarray(self.sh if sh9 else self.E, jnp.float32)
        P, H = self.read_maps()
        maps = _terms(P, diffuse,
                      jnp.asarray(self.W, jnp.float32), jnp.asarray(self.shift, jnp.float32),
                      self.layer_coordinate(rho), n, v, self.plan.terms,
                      self.plan.diffuse, sh9, H, self.plan.harmonic_channel, self.plan.shared_gain)
        return maps + source_terms(self.sources, n, v, rho) if self.sources else maps

    def read_maps(self) -> tuple[tuple, tuple | None]:
        """``(P, H)`` as the shaders read them: ``P[j][k]`` (s, 6 s, 3) layer j of P_k and ``H[j]`` (s, 6 s, 3) its
        tensor (zeros without one; None without the harmonic), each at its block's size s in its map's atlas
        (:attr:`atlases`; the layer's map box-averaged per face, :func:`~.atlas.down`, where the block is smaller
        than the layer's face)."""
        atlases, pl = self.atlases, self.plan
        g = pl.terms - 1 if pl.mixed else pl.terms  # the map holding the tensor

        def at(m, i, j):
            return jnp.asarray(down(m, int(m.shape[0]) // atlases[i].sizes[j]), jnp.float32)

        P = tuple(tuple(at(np.asarray(p)[:, :, k], k, j) for k in range(pl.terms)) for j, p in enumerate(self.P))
        if not self.H:
            return P, None
        return P, tuple(at(np.zeros(np.shape(p)[:2] + (3,), np.float32) if h is None else h, g, j)
                        for j, (p, h) in enumerate(zip(self.P, self.H)))

    def evaluate(self, n, v, base_color, metallic, roughness) -> Float[Array, "N 3"]:
        """L(n, v; c, m, rho) = (1 - m) 0.96 c I_d + f0_eff I_A + I_B (pinned) from the bake's integrals:
        n, v, base_color (N, 3); metallic, roughness (N,) (or scalars)."""
        n = jnp.asarray(n, jnp.float32)
        if n.ndim != 2 or n.shape[-1] != 3 or jnp.shape(v) != n.shape:
            raise HomofacError(f"bake.evaluate: n and v must be (N, 3) arrays of one shape, got {n.shape} and {jnp.shape(v)}")
        c = jnp.broadcast_to(jnp.asarray(base_color, jnp.float32), n.shape)
        m = jnp.broadcast_to(jnp.asarray(metallic, jnp.float32), n.shape[:1])
        return material_radiance(self.terms(n, v, roughness), c, m)

    def save(self, out_dir, **kwargs):
        """Write the bake directory (``bake.json`` and EXR textures, docs/format.md) atomically."""
        if not _WRITERS:
            raise HomofacError("no bake writer registered: import homofac.output (import homofac does)")
        return _WRITERS[0](self, out_dir, **kwargs)


@jax.jit
def _line(table, x):
    """The line mapper's lookup of every row of ``table`` (L, X, C) at x (N,) -> (N, L, C)."""
    X = table.shape[1]
    c = jnp.clip(x * X - 0.5, 0.0, X - 1.0)
    i0 = jnp.clip(jnp.floor(c), 0, X - 2).astype(jnp.int32)
    f = (c - i0)[:, None, None]
    return (1.0 - f) * jnp.moveaxis(table[:, i0], 1, 0) + f * jnp.moveaxis(table[:, i0 + 1], 1, 0)


def _cube(texture, d):
    """Bilinear cube-mapper lookup of a (S, 6S, ...) texture at directions d (N, 3)."""
    s = texture.shape[0]
    flat = texture.reshape(s, 6 * s, -1)
    return mappers.lookup("cube", flat, d)


def sh9_basis(d: Float[Array, "N 3"]) -> Float[Array, "N 9"]:
    """The 9 real SH Y_i(d) of :mod:`homofac.light.sh` (pinned order, +z up) in JAX."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    poly = jnp.stack([jnp.ones_like(x), y, z, x, x * y, y * z, 3 * z * z - 1, x * z, x * x - y * y], axis=-1)
    return poly * jnp.asarray(SH9_NORM, d.dtype)


def diffuse_sh9(E) -> np.ndarray:
    """SH9 coefficients (D, 9, 3) of the diffuse maps E (S, 6S, D, 3): the least-squares fit
    ``c_d = argmin sum_t dw_t |E_d(n_t) - sum_i c_di Y_i(n_t)|^2`` over the cube texels (solid-angle weights),
    i.e. the projection of E_d on the first three SH bands (near-orthonormal on the texel grid; solved exactly)."""
    E = np.asarray(E, np.float64)
    s = E.shape[0]
    d = np.asarray(mappers.texel_directions("cube", s), np.float64).reshape(-1, 3)
    w = np.asarray(mappers.texel_solid_angles("cube", s), np.float64).reshape(-1)
    y = np.asarray(sh9_basis(jnp.asarray(d)), np.float64) * np.sqrt(w)[:, None]
    rhs = E.reshape(len(d), -1) * np.sqrt(w)[:, None]
    c, *_ = np.linalg.lstsq(y, rhs, rcond=None)  # (9, D*3)
    return np.moveaxis(c.reshape(9, E.shape[2], 3), 1, 0).astype(np.float32)


def tensor_read(m: Float[Array, "N 5"], t: Float[Array, "N 3"]) -> Float[Array, "N"]:
    """t^T M t of the stored symmetric traceless tensors m = (M_xx, M_yy, M_xy, M_xz, M_yz), M_zz = -M_xx - M_yy."""
    xx, yy, xy, xz, yz = (m[:, i] for i in range(5))
    tx, ty, tz = t[:, 0], t[:, 1], t[:, 2]
    return (xx * (tx * tx - tz * tz) + yy * (ty * ty - tz * tz)
            + 2.0 * (xy * tx * ty + xz * tx * tz + yz * ty * tz))


def harmonic_gain(i0: Float[Array, "N 3"], h: Float[Array, "N"]) -> Float[Array, "N"]:
    """The factor max(0, 1 + h / Y(i0)) that adds a lobe's second harmonic's luminance ``h`` to its isotropic RGB
    part ``i0`` coloured as i0 (Y the Rec. 709 luminance; 1 where Y(i0) <= 0)."""
    y = i0 @ jnp.asarray(LUMINANCE, i0.dtype)
    return jnp.where(y > 1e-20, jnp.maximum(0.0, 1.0 + h / jnp.where(y > 1e-20, y, 1.0)), 1.0)


def harmonic_colour(i0: Float[Array, "N 3"], h: Float[Array, "N"]) -> Float[Array, "N 3"]:
    """A lobe's RGB integral with its second harmonic's luminance ``h`` added, coloured as its isotropic part
    ``i0``: i0 max(0, 1 + h / Y(i0)) (:func:`harmonic_gain`; Y(i0) <= 0 adds nothing)."""
    return i0 * harmonic_gain(i0, h)[:, None]


#: |n - (n.a) a| below which the tangent t fades to 0 (t = g / max(|g|, floor)): where the axis is n (a layer of
#: shift 1) g is float32 rounding, which a smaller floor would magnify into a random t (GPU and CPU then differ,
#: and the face gauge's read, :mod:`.gauge`, weighs t's component along a).
TANGENT_FLOOR = 1e-3


@jax.jit(static_argnums=(7, 8, 9, 11, 12))
def _terms(P, E, W, shift, u, n, v, K: int, D: int, sh9: bool = False, H=None, hc: int = 0, shared: bool = False):
    x = jnp.sum(n * v, axis=-1)
    r = 2.0 * x[:, None] * n - v
    xc = jnp.clip(x, 0.0, 1.0)
    pb = 0.0
    hb = 0.0
    for j, layer in enumerate(P):  # the layers (a handful), not samples
        hat = jnp.maximum(0.0, 1.0 - jnp.abs(u - j))[:, None, None]
        a = (1.0 - shift[j]) * r + shift[j] * n
        a = a / jnp.maximum(jnp.linalg.norm(a, axis=-1, keepdims=True), 1e-12)
        pb = pb + hat * jnp.stack([_cube(m, a).reshape(-1, 3) for m in layer], axis=1)  # each map at its own size
        if H is not None:  # t: the unit tangent from the axis towards n (the plane of incidence)
            tg = n - jnp.sum(n * a, -1, keepdims=True) * a
            tg = tg / jnp.maximum(jnp.linalg.norm(tg, axis=-1, keepdims=True), TANGENT_FLOOR)
            hb = hb + hat[:, 0, 0] * gauge_read(_cube(H[j], a).reshape(-1, 3), a, tg)
    rows = jnp.arange(W.shape[0], dtype=jnp.float32)
    hats = jnp.maximum(0.0, 1.0 - jnp.abs(u[:, None] - rows[None]))  # (N, L)
    t = jnp.sum(hats[:, :, None] * _line(W, xc), axis=1)  # (N, C)
    ia = jnp.sum(pb * t[:, 0:2 * K:2, None], axis=1)
    ib = jnp.sum(pb * t[:, 1:2 * K:2, None], axis=1)
    if H is not None and shared:  # h_A: the tables' channel hc; its gain scales I_A and I_B
        g = harmonic_gain(ia, hb * t[:, hc])[:, None]
        ia, ib = ia * g, ib * g
    elif H is not None:  # h_A, h_B: the tables' channels hc, hc + 1
        ia = harmonic_colour(ia, hb * t[:, hc])
        ib = harmonic_colour(ib, hb * t[:, hc + 1])
    # the diffuse maps: cube textures, or (sh9) E holds their SH coefficients (D, 9, 3)
    e = jnp.einsum("ni,dic->ndc", sh9_basis(n), E) if sh9 else _cube(E, n).reshape(-1, D, 3)
    idf = jnp.sum(e * t[:, 2 * K:2 * K + D, None], axis=1)
    out = jnp.stack([idf, ia, ib], axis=1)
    return jnp.where((x > 0)[:, None, None], out, 0.0)


__all__ = ["Bake", "diffuse_sh9", "harmonic_colour", "harmonic_gain", "register_writer", "sh9_basis", "tensor_read"]
