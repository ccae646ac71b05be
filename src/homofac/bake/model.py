"""A bake: the textures of one environment and how they give I_d, I_A, I_B (hence L of any glTF material).

    u(rho)   = (layers - 1) log(rho / rho_0) / log(rho_last / rho_0), clamped to [0, layers - 1]
    P_k      = sum_j hat(u - j) P_kj(a_j),  a_j = normalize((1 - s_j) r + s_j n)   (two layers, blended by hand)
    T_c      = sum_j hat(u - j) line(T_jc, n.v)                 (the RGB weight tables, bilinear in (n.v, u))
    I_A = sum_k P_k a_k,   I_B = sum_k P_k b_k,   I_d = sum_d E_d(n) w_d          (a_k = T_2k, b_k = T_2k+1)

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
from ..param import mappers
from .atlas import Atlas, pack
from .plan import BakePlan

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
    layer's array; empty: every layer its own block); ``roughness`` the layers' roughnesses; ``shift`` each layer's axis shift s (P_kj is read at
    a_j = normalize((1 - s_j) r + s_j n)); ``info`` provenance and timings (JSON-friendly).
    """

    plan: BakePlan
    roughness: tuple[float, ...]
    shift: tuple[float, ...]
    P: tuple[Any, ...]
    E: Any
    W: Any
    info: dict
    blocks: tuple[int, ...] = ()

    # --- structure -------------------------------------------------------------------------------------
    @property
    def lookups(self) -> int:
        """Texture fetches per pixel (pinned: a hand blend of two layers counts 2)."""
        return self.plan.lookups

    @property
    def atlas(self) -> Atlas:
        """The layout of each P_k's layers in its 2D texture (:mod:`.atlas`)."""
        return pack([int(p.shape[0]) for p in self.P], self.blocks or None)

    def texture_bytes(self, bytes_per_channel: int = 2) -> int:
        """GPU memory of the textures in half floats (RGB): P_k atlases, E_d maps, weight tables."""
        a = self.atlas
        p = self.plan.terms * a.width * a.height * 3
        e = self.plan.diffuse * int(np.prod(np.shape(self.E)[:2])) * 3
        w = self.plan.tables * self.plan.layers * self.plan.nv_size * 3
        return (p + e + w) * bytes_per_channel

    def describe(self) -> str:
        return (f"{self.plan.describe()}; layers {', '.join(f'{r:.3g}' for r in self.roughness)}; sizes "
                f"{', '.join(str(int(p.shape[0])) for p in self.P)}; {self.texture_bytes() / 1e6:.2f} MB in half floats")

    # --- evaluation ------------------------------------------------------------------------------------
    def layer_coordinate(self, roughness) -> Array:
        """u(rho) of the module docstring (continuous layer index)."""
        r = jnp.asarray(self.roughness, jnp.float32)
        rho = jnp.clip(jnp.asarray(roughness, jnp.float32), r[0], r[-1])
        return jnp.clip((len(self.roughness) - 1) * jnp.log(rho / r[0]) / jnp.log(r[-1] / r[0]), 0.0,
                        len(self.roughness) - 1)

    def terms(self, n: Float[Array, "N 3"], v: Float[Array, "N 3"], roughness) -> Float[Array, "N 3 3"]:
        """``(I_d, I_A, I_B)`` stacked on axis 1 (N, 3, 3): the bake's approximation of
        :func:`homofac.light.integrals.integrals`."""
        n = jnp.asarray(n, jnp.float32)
        v = jnp.asarray(v, jnp.float32)
        rho = jnp.broadcast_to(jnp.asarray(roughness, jnp.float32), n.shape[:1])
        return _terms(tuple(jnp.asarray(p, jnp.float32) for p in self.P), jnp.asarray(self.E, jnp.float32),
                      jnp.asarray(self.W, jnp.float32), jnp.asarray(self.shift, jnp.float32),
                      self.layer_coordinate(rho), n, v, self.plan.terms,
                      self.plan.diffuse)

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


@jax.jit(static_argnums=(7, 8))
def _terms(P, E, W, shift, u, n, v, K: int, D: int):
    x = jnp.sum(n * v, axis=-1)
    r = 2.0 * x[:, None] * n - v
    xc = jnp.clip(x, 0.0, 1.0)
    pb = 0.0
    for j, layer in enumerate(P):  # the layers (a handful), not samples
        hat = jnp.maximum(0.0, 1.0 - jnp.abs(u - j))[:, None, None]
        a = (1.0 - shift[j]) * r + shift[j] * n
        a = a / jnp.maximum(jnp.linalg.norm(a, axis=-1, keepdims=True), 1e-12)
        pb = pb + hat * _cube(layer, a).reshape(-1, K, 3)
    rows = jnp.arange(W.shape[0], dtype=jnp.float32)
    hats = jnp.maximum(0.0, 1.0 - jnp.abs(u[:, None] - rows[None]))  # (N, L)
    t = jnp.sum(hats[:, :, None] * _line(W, xc), axis=1)  # (N, C)
    ia = jnp.sum(pb * t[:, 0:2 * K:2, None], axis=1)
    ib = jnp.sum(pb * t[:, 1:2 * K:2, None], axis=1)
    e = _cube(E, n).reshape(-1, D, 3)
    idf = jnp.sum(e * t[:, 2 * K:2 * K + D, None], axis=1)
    out = jnp.stack([idf, ia, ib], axis=1)
    return jnp.where((x > 0)[:, None, None], out, 0.0)


__all__ = ["Bake", "register_writer"]
