"""Azimuth-averaged lobe kernels: the bake's integrals as isotropic filters of the environment.

For a view cosine x = n.v and a reflected direction r = 2 (n.v) n - v, the normals with n.r = x lie on a
cone around r (n.r = n.v). Averaged over that cone's azimuth phi, a lobe g(n, v, l) max(n.l, 0) depends
on the light only through gamma = angle(r, l) (rotation symmetry about r):

    K_x(gamma) = (1 / 2 pi) int_0^2pi g(n(phi), v(phi), l(gamma)) max(n.l, 0) dphi

so the azimuth mean of an integral I(n, v) over the pinned light sum is the isotropic filter
``sum_k L_k dw_k K_x(angle(r, l_k))``: the best any product P(r) W(n.v) can do with the azimuth
(the direction of n around r) is to match it (the azimuth variation is orthogonal to every such product).
The same holds for I_d with the axis n and v on the cone around n. Tables are over q = sin(gamma / 2) =
sqrt((1 - r.l) / 2), uniform in sqrt(q) (fine near gamma = 0, where narrow lobes live).
"""

from __future__ import annotations

import numpy as np
import jax
import jax.numpy as jnp

from ..brdf import albedo
from ..brdf.gltf import gltf, gltf_lobes_at
from ..compiling import jit

#: Azimuth quadrature nodes (the integrand is smooth and periodic in phi: the trapezoid rule converges fast).
PHI_NODES = 48
#: Kernel table nodes over q = sin(gamma / 2) in [0, 1].
TABLE_NODES = 1024


def q_grid(nodes: int = TABLE_NODES) -> np.ndarray:
    """Table nodes q_i = (i / (nodes - 1))^2; gamma = 2 asin(q): spacing ~1e-6 rad at the axis (the lobe of
    roughness 0.045, alpha = 0.002, is resolved), ~4e-3 rad at the antipode."""
    return np.linspace(0.0, 1.0, nodes) ** 2


def nv_centres(size: int) -> np.ndarray:
    """The weight tables' column centres x_i = (i + 0.5) / size (the pinned line-mapper texel centres)."""
    return (np.arange(size) + 0.5) / size


def _frame(n):
    """Tangent frame (t, b) of normals n (..., 3) (any orthonormal pair: the lobes are isotropic)."""
    a = jnp.where(jnp.abs(n[..., 0:1]) < 0.9, jnp.array([1.0, 0.0, 0.0], n.dtype), jnp.array([0.0, 1.0, 0.0], n.dtype))
    t = a - jnp.sum(a * n, -1, keepdims=True) * n
    t = t / jnp.linalg.norm(t, axis=-1, keepdims=True)
    return t, jnp.cross(n, t)


def _local(d, t, b, n):
    return (jnp.sum(d * t, -1), jnp.sum(d * b, -1), jnp.sum(d * n, -1))


def _cone_lobes(rough, x, gamma, shift):
    """The lobes (1 - s5) S and s5 S times max(n.l, 0), each (X, G, F), for the normals n at azimuth phi_f on the
    cone about the axis a = normalize((1 - s) r + s n) (a = +z) and the light at angle gamma from a, azimuth 0;
    the light's azimuth about a from the plane of (a, n) is then omega = -phi_f."""
    phi = (jnp.arange(PHI_NODES) + 0.5) * (2 * jnp.pi / PHI_NODES)
    theta = jnp.arccos(jnp.clip(x, -1.0, 1.0))  # angle(r, n) = angle(n, v)
    beta = jnp.arctan2(shift * jnp.sin(theta), (1.0 - shift) + shift * jnp.cos(theta))  # angle(r, a)
    tn = (theta - beta)[:, None]
    cp, sp = jnp.cos(phi)[None], jnp.sin(phi)[None]
    n = jnp.stack([jnp.sin(tn) * cp, jnp.sin(tn) * sp, jnp.cos(tn) + 0 * cp], -1)[:, None]  # (X, 1, F, 3)
    b = beta[:, None]
    r = jnp.stack([-jnp.sin(b) * cp, -jnp.sin(b) * sp, jnp.cos(b) + 0 * cp], -1)[:, None]
    v = 2.0 * x[:, None, None, None] * n - r  # (X, 1, F, 3)
    l = jnp.stack([jnp.sin(gamma), 0 * gamma, jnp.cos(gamma)], -1)[None, :, None]  # (1, G, 1, 3)
    t, bt = _frame(n)
    wi = _local(l, t, bt, n)
    wo = _local(v, t, bt, n)
    above = wi[2] > 0
    wi = (jnp.where(above, wi[0], 0.0), jnp.where(above, wi[1], 0.0), jnp.where(above, wi[2], 1.0))
    _, ga, gb = gltf_lobes_at(rough, wi, wo)
    cos = jnp.where(above, wi[2], 0.0)
    return ga * cos, gb * cos, phi


@jit(kind="texture")
def _lobes(rough, x, gamma, shift):
    """(2, 2, X, G): [0] the azimuth means of the lobes (1 - s5) S and s5 S times max(n.l, 0) about the axis
    a = normalize((1 - s) r + s n) (= r for s = 0; the lobe's dominant direction leans from r to n), a = +z;
    [1] their second azimuthal Fourier coefficients k_2(gamma) = (1/pi) int g cos(2 omega) domega (omega the
    light's azimuth about a from the plane of incidence): the lobe's elongation in (or across) that plane.
    One program for both (a process's first bake compiles it once)."""
    ga, gb, phi = _cone_lobes(rough, x, gamma, shift)
    c2 = 2.0 * jnp.cos(2.0 * phi)
    mean = jnp.stack([jnp.mean(ga, -1), jnp.mean(gb, -1)])
    second = jnp.stack([jnp.mean(ga * c2, -1), jnp.mean(gb * c2, -1)])
    return jnp.stack([mean, second]).reshape(2, 2, x.shape[0], gamma.shape[0])


@jit(kind="texture")
def _diffuse(x, gamma):
    """(X, G): the azimuth mean of (1 - s5)/pi max(n.l, 0) over views on the cone n.v = x, axis n = +z."""
    phi = (jnp.arange(PHI_NODES) + 0.5) * (2 * jnp.pi / PHI_NODES)
    sx = jnp.sqrt(jnp.clip(1.0 - x * x, 0.0, 1.0))
    v = (sx[:, None, None] * jnp.cos(phi), sx[:, None, None] * jnp.sin(phi), x[:, None, None] + 0 * phi)
    l = (jnp.sin(gamma)[None, :, None], 0.0, jnp.cos(gamma)[None, :, None])
    above = l[2] > 0
    li = (jnp.where(above, l[0], 0.0), jnp.zeros_like(l[0]), jnp.where(above, l[2], 1.0))
    gd, _, _ = gltf_lobes_at(1.0, li, v)
    return jnp.mean(gd * jnp.where(above, l[2], 0.0), -1)


def lobe_kernels(roughness: float, x: np.ndarray, nodes: int = TABLE_NODES, shift: float = 0.0
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``(K (2, X, nodes), k_2 (2, X, nodes))``: :func:`specular_kernels` and :func:`harmonic_kernels` of one
    roughness and shift from one evaluation of the lobes (float64)."""
    gamma = 2.0 * np.arcsin(q_grid(nodes))
    with jax.enable_x64(True):
        out = _lobes(jnp.float64(roughness), jnp.asarray(x, jnp.float64), jnp.asarray(gamma), jnp.float64(shift))
    out = np.asarray(out, np.float64)
    return out[0], out[1]


def specular_kernels(roughness: float, x: np.ndarray, nodes: int = TABLE_NODES, shift: float = 0.0) -> np.ndarray:
    """``(2, X, nodes)``: K^A_x and K^B_x (lobes (1 - s5) S and s5 S) at the table nodes (float64), about the
    axis normalize((1 - shift) r + shift n)."""
    return lobe_kernels(roughness, x, nodes, shift)[0]


def harmonic_kernels(roughness: float, x: np.ndarray, nodes: int = TABLE_NODES, shift: float = 0.0) -> np.ndarray:
    """``(2, X, nodes)``: the second harmonics k^A_2, k^B_2 of the lobes about the axis
    normalize((1 - shift) r + shift n) (:func:`_lobes`), at the table nodes (float64): the lobe is
    K_x(gamma) + k_2(gamma) cos(2 omega) + (odd and higher harmonics)."""
    return lobe_kernels(roughness, x, nodes, shift)[1]


def albedos(roughness: float, x: np.ndarray, n: int = 128) -> np.ndarray:
    """``(2, X)``: the directional albedos of the lobes (1 - s5) S and s5 S at view cosines x (Gauss-Legendre
    quadrature of :func:`homofac.brdf.albedo`): the exact masses of :func:`specular_kernels`' rows. One
    quadrature: a metal of base colour (1, 0, 0) reads S (f0 = 1) in red and s5 S (f0 = 0) in green."""
    wo = jnp.asarray(np.stack([np.sqrt(1.0 - x * x), 0.0 * x, x], -1), jnp.float32)
    rg = np.asarray(albedo(gltf(base_color=(1.0, 0.0, 0.0), metallic=1.0, roughness=roughness), wo, n=n), np.float64)
    both, b = rg[:, 0], rg[:, 1]
    return np.stack([both - b, b])


def calibrate(kernel: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Each kernel row scaled so that its mass is ``target`` (the exact albedo): the azimuth quadrature
    under-resolves the stretched lobes of low roughness at grazing views (rho 0.045, n.v = 0.05: mass 0.836
    against the albedo 0.999); a furnace then reads exactly 1 x albedo."""
    m = mass(kernel)
    return kernel * np.where(np.abs(m) > 1e-12, target / np.where(np.abs(m) > 1e-12, m, 1.0), 1.0)[..., None]


def diffuse_kernels(x: np.ndarray, nodes: int = TABLE_NODES) -> np.ndarray:
    """``(X, nodes)``: K^d_x (lobe (1 - s5)/pi) at the table nodes (float64)."""
    gamma = 2.0 * np.arcsin(q_grid(nodes))
    with jax.enable_x64(True):
        out = _diffuse(jnp.asarray(x, jnp.float64), jnp.asarray(gamma))
    return np.asarray(out, np.float64)


def mass(kernel: np.ndarray) -> np.ndarray:
    """``int K dw = 2 pi int K(gamma) sin(gamma) dgamma`` over the last (table) axis; with q = sin(gamma/2),
    dw = 2 pi sin(gamma) dgamma = 8 pi q dq (trapezoid rule)."""
    q = q_grid(kernel.shape[-1])
    return np.trapezoid(kernel * (8.0 * np.pi * q), q, axis=-1)


def smooth(kernel: np.ndarray, radius: float) -> np.ndarray:
    """The kernel box-averaged over +-radius in gamma along a slice through its axis (a light texel's half
    width), its mass kept: a lobe narrower than the light texels then covers the texel around its axis
    instead of falling between texel centres (a point-sampled sum would alias), and a wide one is barely
    changed. The box average is exact for any narrow kernel: a difference of the slice's cumulative integral."""
    if kernel.size == 0:
        return kernel.copy()
    q = q_grid(kernel.shape[-1])
    gamma = 2.0 * np.arcsin(q)
    g = np.concatenate([-gamma[:0:-1], gamma])  # the slice s in [-pi, pi]
    flat = kernel.reshape(-1, kernel.shape[-1])
    rows = np.concatenate([flat[:, :0:-1], flat], axis=1)
    cum = np.concatenate([np.zeros((len(flat), 1)), np.cumsum(0.5 * (rows[:, 1:] + rows[:, :-1]) * np.diff(g), axis=1)], axis=1)
    hi = np.minimum(gamma + radius, np.pi)
    lo = gamma - radius
    out = np.stack([(np.interp(hi, g, c) - np.interp(lo, g, c)) / (hi - lo) for c in cum]).reshape(kernel.shape)
    m0, m1 = mass(kernel), mass(out)
    scale = np.where(np.abs(m1) > 1e-30, m0 / np.where(np.abs(m1) > 1e-30, m1, 1.0), 1.0)
    return out * scale[..., None]


def support(kernel: np.ndarray, fraction: float = 0.999) -> float:
    """The angle gamma within which ``fraction`` of every kernel's absolute mass lies (the lights farther than
    it from a direction are culled in :func:`homofac.bake.filter.prefilter`)."""
    q = q_grid(kernel.shape[-1])
    flat = np.abs(kernel.reshape(-1, kernel.shape[-1])) * (8.0 * np.pi * q)
    c = np.cumsum(flat, axis=-1)
    c = c / np.maximum(c[:, -1:], 1e-300)
    idx = np.max(np.argmax(c >= fraction, axis=-1))
    return float(2.0 * np.arcsin(q[min(idx + 1, len(q) - 1)]))


__all__ = ["PHI_NODES", "TABLE_NODES", "albedos", "calibrate", "diffuse_kernels", "harmonic_kernels", "lobe_kernels", "mass", "nv_centres", "q_grid", "smooth",
           "specular_kernels", "support"]
