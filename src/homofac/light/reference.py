"""A converged reference for the bake's integrals at every roughness: importance sampling of the source map.

The pinned light sum (:mod:`.integrals`) evaluates the BRDF at the centres of the light texels. A GGX lobe
of alpha = roughness^2 = 0.002-0.02 (roughness 0.045-0.15) is narrower than a texel of a 256^2 x 6 cube, so
that sum does not converge there with the light resolution. This module integrates instead the continuous
environment the light sum converges to: the lat-long source image looked up bilinearly (the resampler's
reading, :func:`homofac.light.latlong.latlong_taps`), scaled per channel so that its integral is the source's
energy (as the resampler rescales every resolution). For pairs (n, v) with a roughness each,

    I_d = int (1 - s5)/pi Li(l) (n.l)+ dl,   I_A = int (1 - s5) S Li(l) (n.l)+ dl,   I_B = int s5 S Li(l) (n.l)+ dl

(the lobes of :func:`homofac.brdf.gltf.gltf_lobes_at`) are estimated by multiple importance sampling with the
balance heuristic (Veach 1997, ch. 9), ``S`` samples per strategy:

    F = 1/S  sum_{x in X_brdf u X_env}  f(x) Li(x) (n.x)+ / (p_brdf(x) + p_env(x))

* ``X_brdf``: for I_A, I_B the GGX distribution of visible normals (Heitz 2018, "Sampling the GGX
  distribution of visible normals", JCGT 7(4)), ``l = reflect(-v, h)``, ``p = G1(v) D(h) / (4 n.v)``;
  for I_d the cosine distribution ``p = (n.l)/pi``;
* ``X_env``: the source pixels drawn in proportion to their luminance (3 x 3 maximum, so the bilinear
  spread of a bright pixel is covered) times their solid angle, plus a uniform floor, then uniform in solid
  angle inside the pixel; ``p_env = P(pixel) / dw(pixel)``. Shared by every pair (one set of directions).

Points are a scrambled Sobol' sequence (the first ``S`` of a fixed sequence, so doubling ``S`` refines the
same estimate), shifted per pair (Cranley-Patterson rotation), so each pair's estimate is unbiased. float64
throughout; pairs go through ``lax.map`` in chunks, nothing is looped in Python.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float
from scipy.stats import qmc

from .. import sphere
from ..brdf.analytic import _smith_lambda_ggx
from ..brdf.gltf import gltf_lobes_at
from ..errors import HomofacError
from .clean import clean
from .environment import luminance
from .latlong import latlong_solid_angles, latlong_taps

#: Pairs per lax.map step (each holds 3 S directions and their lobes).
CHUNK = 8
#: Share of the environment proposal spread uniformly over the sphere (keeps p_env > 0 everywhere).
UNIFORM_FLOOR = 0.02
#: Sub-points per pixel side of the quadrature of the bilinear map's integral (its energy rescale).
ENERGY_SUBSAMPLE = 4


class SourceMap(eqx.Module):
    """The continuous environment of the reference: a lat-long image read bilinearly, and its sampler.

    ``image`` (H W, 3) the cleaned pixels times the per-channel energy ``scale`` (3,), ``cdf`` (H W,) the
    cumulative proposal over the pixels, ``prob`` (H W,) each pixel's probability, ``cos_edges`` (H + 1,) the
    cosines of the rows' edges. Build with :func:`source_map`.
    """

    image: Float[np.ndarray, "P 3"]
    cdf: Float[np.ndarray, "P"]
    prob: Float[np.ndarray, "P"]
    cos_edges: Float[np.ndarray, "H1"]
    scale: Float[np.ndarray, "3"]
    height: int = eqx.field(static=True)


def _bilinear_energy(img: np.ndarray) -> np.ndarray:
    """``int bilinear(img)(l) dl`` per channel: midpoint rule on ``ENERGY_SUBSAMPLE^2`` sub-cells per pixel."""
    h, w = img.shape[:2]
    k = ENERGY_SUBSAMPLE
    th = np.pi * (np.arange(h * k) + 0.5) / (h * k)
    ph = 2 * np.pi * (np.arange(w * k) + 0.5) / (w * k)
    dw = latlong_solid_angles(h * k, w * k)
    total = np.zeros(3)
    for rows in np.array_split(np.arange(h * k), max(1, h * k // 64)):  # strips bound the memory
        st = np.sin(th[rows])[:, None]
        d = np.stack([st * np.cos(ph), st * np.sin(ph), np.broadcast_to(np.cos(th[rows])[:, None], (len(rows), w * k))], -1)
        idx, wts = latlong_taps(h, w, d.reshape(-1, 3))
        vals = np.einsum("nk,nkc->nc", wts, img.reshape(-1, 3)[idx])
        total += (vals.reshape(len(rows), w * k, 3) * dw[rows, None, None]).sum((0, 1))
    return total


def source_map(image, source: str = "<latlong array>") -> SourceMap:
    """The :class:`SourceMap` of a lat-long image (H, 2H, 3) in the pinned layout (docs/conventions.md):
    cleaned as the loaders clean it, scaled per channel to the source's energy ``sum img dw`` (module
    docstring), with the pixel proposal of the environment strategy."""
    a = np.asarray(image)
    if a.ndim != 3 or a.shape[2] < 3 or a.shape[1] != 2 * a.shape[0]:
        raise HomofacError(f"{source}: the reference needs a 2:1 lat-long (H, 2H, 3) image, got shape {a.shape}")
    img, _, _ = clean(a[..., :3], source)
    h, w = img.shape[:2]
    dw = latlong_solid_angles(h, w)
    e_src = (img * dw[:, None, None]).sum((0, 1))
    if not np.any(e_src > 0):
        raise HomofacError(f"{source}: environment is all zero: nothing to light with")
    e_bil = _bilinear_energy(img)
    scale = np.where(e_bil > 0, e_src / np.where(e_bil > 0, e_bil, 1.0), 1.0)
    lum = luminance(img)
    pad = np.pad(lum, ((1, 1), (0, 0)), mode="edge")
    pad = np.concatenate([pad[:, -1:], pad, pad[:, :1]], axis=1)
    spread = np.max(np.stack([pad[1 + i:1 + i + h, 1 + j:1 + j + w] for i in (-1, 0, 1) for j in (-1, 0, 1)]), axis=0)
    weight = spread * dw[:, None]
    total = weight.sum()
    weight = (1 - UNIFORM_FLOOR) * weight / total + UNIFORM_FLOOR * (dw[:, None] / (4 * np.pi)) * np.ones((1, w))
    prob = (weight / weight.sum()).reshape(-1)
    edges = np.cos(np.pi * np.arange(h + 1) / h)
    # NumPy float64 leaves: they become float64 arrays inside reference_integrals' x64 scope.
    return SourceMap((img * scale).reshape(-1, 3), np.cumsum(prob), prob, edges, scale, int(h))


def _pixel(m: SourceMap, d):
    """Flat pixel index and solid angle of the pixel holding each direction ``d`` (..., 3)."""
    h = m.height
    th = jnp.arccos(jnp.clip(d[..., 2], -1.0, 1.0))
    ph = jnp.mod(jnp.arctan2(d[..., 1], d[..., 0]), 2 * jnp.pi)
    row = jnp.clip(jnp.floor(th * h / jnp.pi).astype(jnp.int32), 0, h - 1)
    col = jnp.clip(jnp.floor(ph * h / jnp.pi).astype(jnp.int32), 0, 2 * h - 1)
    dw = (m.cos_edges[row] - m.cos_edges[row + 1]) * (jnp.pi / h)
    return row * 2 * h + col, dw


def _lookup(m: SourceMap, d):
    """Bilinear lookup of the map at unit directions ``d`` (..., 3): row = theta H/pi - 0.5 (clamped),
    column = phi W/2pi - 0.5 (wrapped), as :func:`homofac.light.latlong.latlong_taps`."""
    h, w = m.height, 2 * m.height
    th = jnp.arccos(jnp.clip(d[..., 2], -1.0, 1.0))
    ph = jnp.mod(jnp.arctan2(d[..., 1], d[..., 0]), 2 * jnp.pi)
    row = th * (h / jnp.pi) - 0.5
    col = ph * (w / (2 * jnp.pi)) - 0.5
    r0, c0 = jnp.floor(row), jnp.floor(col)
    tr, tc = (row - r0)[..., None], (col - c0)[..., None]
    r0 = r0.astype(jnp.int32)
    c0 = c0.astype(jnp.int32)
    r1, r0 = jnp.clip(r0 + 1, 0, h - 1) * w, jnp.clip(r0, 0, h - 1) * w
    c1, c0 = jnp.mod(c0 + 1, w), jnp.mod(c0, w)
    im = m.image
    return ((1 - tr) * ((1 - tc) * im[r0 + c0] + tc * im[r0 + c1]) + tr * ((1 - tc) * im[r1 + c0] + tc * im[r1 + c1]))


def _env_pdf(m: SourceMap, d):
    idx, dw = _pixel(m, d)
    return m.prob[idx] / dw


def _env_samples(m: SourceMap, u):
    """Directions (S, 3) drawn from the pixel proposal with points ``u`` (S, 3) in [0, 1)."""
    h = m.height
    idx = jnp.clip(jnp.searchsorted(m.cdf, u[:, 0] * m.cdf[-1], side="right"), 0, m.prob.shape[0] - 1)
    row, col = idx // (2 * h), idx % (2 * h)
    z = m.cos_edges[row] - u[:, 1] * (m.cos_edges[row] - m.cos_edges[row + 1])
    ph = (col + u[:, 2]) * (jnp.pi / h)
    s = jnp.sqrt(jnp.maximum(1 - z * z, 0.0))
    return jnp.stack([s * jnp.cos(ph), s * jnp.sin(ph), z], -1)


def _ggx_d(h, a2):
    """GGX D at local half vectors (components), written as :func:`gltf_lobes_at` writes it."""
    return a2 / (jnp.pi * (a2 * h[2] * h[2] + h[0] * h[0] + h[1] * h[1]) ** 2)


def _vndf(wo, alpha, u1, u2):
    """Heitz 2018: a visible normal (local components) for view ``wo`` (components, (B, 1))."""
    vx, vy, vz = alpha * wo[0], alpha * wo[1], wo[2]
    vn = jnp.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx / vn, vy / vn, vz / vn
    lensq = vx * vx + vy * vy
    inv = jnp.where(lensq > 0, jax.lax.rsqrt(jnp.where(lensq > 0, lensq, 1.0)), 0.0)
    t1 = (jnp.where(lensq > 0, -vy * inv, 1.0), jnp.where(lensq > 0, vx * inv, 0.0), 0.0 * vz)
    t2 = (vy * t1[2] - vz * t1[1], vz * t1[0] - vx * t1[2], vx * t1[1] - vy * t1[0])
    r = jnp.sqrt(u1)
    phi = 2 * jnp.pi * u2
    p1, p2 = r * jnp.cos(phi), r * jnp.sin(phi)
    s = 0.5 * (1 + vz)
    p2 = (1 - s) * jnp.sqrt(jnp.maximum(1 - p1 * p1, 0.0)) + s * p2
    p3 = jnp.sqrt(jnp.maximum(1 - p1 * p1 - p2 * p2, 0.0))
    nh = tuple(p1 * a + p2 * b + p3 * c for a, b, c in zip(t1, t2, (vx, vy, vz)))
    hx, hy, hz = alpha * nh[0], alpha * nh[1], jnp.maximum(nh[2], 0.0)
    hn = jnp.sqrt(hx * hx + hy * hy + hz * hz)
    return hx / hn, hy / hn, hz / hn


def _half(wi, wo):
    hx, hy, hz = wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]
    n = jnp.sqrt(jnp.maximum(hx * hx + hy * hy + hz * hz, 1e-300))
    return hx / n, hy / n, hz / n


def _chunk(m: SourceMap, env_dirs, env_rad, env_p, u_brdf, n, v, rough, shifts):
    """(B, 3 lobes, 3 channels) for one chunk of pairs (module docstring)."""
    S = u_brdf.shape[0]
    t, b, nn = sphere.frame(n)
    to_world = lambda w: w[0][..., None] * t[:, None] + w[1][..., None] * b[:, None] + w[2][..., None] * nn[:, None]  # noqa: E731
    wo3 = sphere.to_local(v, t, b, nn)
    wo = tuple(wo3[:, c:c + 1] for c in range(3))
    nv = jnp.maximum(wo[2], 1e-12)
    alpha = (rough * rough)[:, None]
    a2 = alpha * alpha
    g1v = 1.0 / (1.0 + _smith_lambda_ggx(wo, a2))

    def p_spec(wi):
        return g1v * _ggx_d(_half(wi, wo), a2) / (4 * nv)

    def p_cos(wi):
        return jnp.maximum(wi[2], 0.0) / jnp.pi

    def lobes(wi):
        above = wi[2] > 0
        safe = (jnp.where(above, wi[0], 0.0), jnp.where(above, wi[1], 0.0), jnp.where(above, wi[2], 1.0))
        return tuple(jnp.where(above, g * wi[2], 0.0) for g in gltf_lobes_at(rough[:, None], safe, wo))

    u = jnp.mod(u_brdf[None] + shifts[:, None, :], 1.0)  # (B, S, 4): per-pair rotation
    # GGX visible normals -> I_A, I_B
    h = _vndf(wo, alpha, u[..., 0], u[..., 1])
    vh = wo[0] * h[0] + wo[1] * h[1] + wo[2] * h[2]
    wi = tuple(2 * vh * hc - woc for hc, woc in zip(h, wo))
    dw = to_world(wi)
    rad = _lookup(m, dw)
    _, la, lb = lobes(wi)
    den = p_spec(wi) + _env_pdf(m, dw)
    wa, wb = la / den, lb / den
    spec = jnp.stack([jnp.einsum("bs,bsc->bc", wa, rad), jnp.einsum("bs,bsc->bc", wb, rad)], 1)
    # cosine -> I_d
    r = jnp.sqrt(u[..., 2])
    ph = 2 * jnp.pi * u[..., 3]
    wi = (r * jnp.cos(ph), r * jnp.sin(ph), jnp.sqrt(jnp.maximum(1 - u[..., 2], 0.0)))
    dw = to_world(wi)
    ld, _, _ = lobes(wi)
    diff = jnp.einsum("bs,bsc->bc", ld / (p_cos(wi) + _env_pdf(m, dw)), _lookup(m, dw))
    # the environment's samples -> all three
    wi = tuple(c @ env_dirs.T for c in (t, b, nn))  # (B, S) local components
    ld, la, lb = lobes(wi)
    ps, pc = p_spec(wi), p_cos(wi)
    env = jnp.stack([(ld / (pc + env_p)) @ env_rad, (la / (ps + env_p)) @ env_rad, (lb / (ps + env_p)) @ env_rad], 1)
    out = (jnp.concatenate([diff[:, None], spec], 1) + env) / S
    valid = jnp.sum(n * v, axis=-1) > 0
    return jnp.where(valid[:, None, None], out, 0.0)


@functools.partial(jax.jit, static_argnames=("chunk",))
def _reference(m: SourceMap, u_env, u_brdf, n, v, rough, shifts, chunk: int):
    env_dirs = _env_samples(m, u_env)
    env_rad = _lookup(m, env_dirs)
    env_p = _env_pdf(m, env_dirs)
    count = n.shape[0]
    pad = (-count) % chunk
    if pad:
        n, v, rough, shifts = (jnp.concatenate([a, jnp.broadcast_to(a[:1], (pad,) + a.shape[1:])]) for a in (n, v, rough, shifts))
    out = jax.lax.map(lambda a: _chunk(m, env_dirs, env_rad, env_p, u_brdf, *a),
                      (n.reshape(-1, chunk, 3), v.reshape(-1, chunk, 3), rough.reshape(-1, chunk), shifts.reshape(-1, chunk, 4)))
    return out.reshape(-1, 3, 3)[:count]


def sobol_points(samples: int, dims: int, seed: int) -> np.ndarray:
    """The first ``samples`` points of a scrambled Sobol' sequence in ``dims`` dimensions (float64)."""
    return qmc.Sobol(dims, scramble=True, seed=seed).random(int(samples))


def reference_integrals(source, n: Float[Array, "N 3"], v: Float[Array, "N 3"], roughness, *, samples: int = 4096,
                        seed: int = 0, chunk: int = CHUNK) -> np.ndarray:
    """``(I_d, I_A, I_B)`` stacked on axis 1, RGB on axis 2: (N, 3, 3) float64, the MIS estimate of the module
    docstring with ``samples`` points per strategy (a power of two) for pairs (n, v) with a roughness each
    (scalar or (N,)). ``source``: a :class:`SourceMap` or a lat-long image (H, 2H, 3). Pairs with n.v <= 0
    give 0. Same layout as :func:`homofac.light.integrals.integrals`."""
    m = source if isinstance(source, SourceMap) else source_map(source)
    samples = int(samples)
    if samples < 1 or samples & (samples - 1):
        raise HomofacError(f"reference samples must be a power of two, got {samples}")
    n = np.asarray(n, np.float64).reshape(-1, 3)
    v = np.asarray(v, np.float64).reshape(-1, 3)
    rough = np.broadcast_to(np.asarray(roughness, np.float64), n.shape[:1])
    shifts = np.random.default_rng(seed + 1).random((len(n), 4))
    with jax.enable_x64(True):
        out = _reference(m, jnp.asarray(sobol_points(samples, 3, seed)), jnp.asarray(sobol_points(samples, 4, seed + 2)),
                         jnp.asarray(n), jnp.asarray(v), jnp.asarray(rough), jnp.asarray(shifts),
                         max(1, min(int(chunk), len(n))))
        return np.asarray(out, np.float64)


__all__ = ["SourceMap", "reference_integrals", "sobol_points", "source_map"]
