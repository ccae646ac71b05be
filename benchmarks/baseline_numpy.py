"""The lighting computation as a user writes it first: plain NumPy, no JAX (the speed baseline).

L(v, n) = sum_k f(l_k, v) L_k max(n . l_k, 0) dw_k (docs/conventions.md, the pinned sum, with the cosine taken at
the texel centre), in the world frame: for each chunk of pairs, the local frame of n, every light
rotated into it, the BRDF evaluated on a (B, L) grid by the model's formula written in NumPy
(Cook-Torrance, the same maths as homofac.brdf.analytic), and the weighted sum. ``python benchmarks/baseline_numpy.py``
times it on a slice of the default workload and extrapolates to all pairs.
"""

from __future__ import annotations

import json
import time

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import homofac as hf
from homofac.fit import sampling
from homofac.fit.samples import evaluate_grouped
from homofac.light.lights import moments_of


def frames(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An orthonormal tangent pair (t, b) for each normal (Frisvad / Duff et al. branchless basis)."""
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    bb = n[:, 0] * n[:, 1] * a
    t = np.stack([1 + sign * n[:, 0] ** 2 * a, sign * bb, -sign * n[:, 0]], axis=1)
    b = np.stack([bb, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return t, b


def lighting(brdf_np, dirs: np.ndarray, power: np.ndarray, n: np.ndarray, v: np.ndarray, chunk: int = 256) -> np.ndarray:
    """L(v, n) for N pairs. ``brdf_np(wi (B, L, 3), wo (B, 1, 3)) -> (B, L, 3)``; ``power`` = L_k dw_k (L, 3)."""
    out = np.empty((n.shape[0], 3))
    for s in range(0, n.shape[0], chunk):
        nn, vv = n[s : s + chunk], v[s : s + chunk]
        t, b = frames(nn)
        local = lambda d: np.stack([d @ t.T, d @ b.T, d @ nn.T], axis=-1)  # noqa: E731 - (L, B, 3)
        wi = np.transpose(local(dirs), (1, 0, 2))  # (B, L, 3)
        wo = np.stack([np.sum(vv * t, 1), np.sum(vv * b, 1), np.sum(vv * nn, 1)], axis=-1)[:, None, :]
        f = brdf_np(wi, wo)
        cos = np.maximum(wi[..., 2], 0.0)
        out[s : s + chunk] = np.einsum("blc,bl,lc->bc", f, cos, power)
    return out


def numpy_brdf(brdf):
    """Cook-Torrance ``brdf``'s formula on NumPy arrays (the baseline implements only this model)."""
    if brdf.model != "cook_torrance":
        raise ValueError(f"the NumPy baseline implements cook_torrance only, not {brdf.model}")
    params = {k: np.asarray(v, np.float64) for k, v in brdf.params.items()}
    return lambda wi, wo: _cook_torrance_np(params, wi, wo)


def _cook_torrance_np(p, wi, wo):
    """Cook-Torrance (Beckmann D, Cook-Torrance G, Schlick F), as in homofac.brdf.analytic, in NumPy."""
    kd, ks, m, f0 = (np.broadcast_to(np.asarray(p[k], np.float64), s) for k, s in
                     (("kd", (3,)), ("ks", (3,)), ("roughness", ()), ("f0", (3,))))
    wo = np.broadcast_to(wo, wi.shape)
    ci, co = wi[..., 2], wo[..., 2]
    valid = (ci > 0) & (co > 0)
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-12)
    ch = np.clip(h[..., 2], 1e-6, 1.0)
    vh = np.clip(np.sum(wo * h, -1), 1e-6, 1.0)
    tan2 = (1 - ch * ch) / (ch * ch)
    d = np.exp(-tan2 / (m * m)) / (np.pi * m * m * ch**4)
    g = np.minimum(1.0, np.minimum(2 * ch * co / vh, 2 * ch * ci / vh))
    fres = f0 + (1 - f0) * (1 - vh[..., None]) ** 5
    spec = ks * (d * g / np.maximum(4 * ci * co, 1e-12))[..., None] * fres
    return np.where(valid[..., None], kd / np.pi + spec, 0.0)


def delta_env(env):
    """The same lights as point lights at their centres (corners 0): homofac then uses max(n.l, 0) dw too."""
    corners = jnp.zeros_like(env.corners)
    env = eqx.tree_at(lambda e: e.corners, env, corners)
    return eqx.tree_at(lambda e: e.moments, env, moments_of(np.asarray(env.directions), np.asarray(env.solid_angle),
                                                         np.zeros(corners.shape)))


def main(slice_pairs: int = 4096) -> dict:

    env = hf.light.load_environment("forest", resolution=16)
    brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    groups = sampling.grouped_pairs("texels", 16, mapper="dual_paraboloid")
    pairs = groups.flatten()
    dirs = np.asarray(env.directions, np.float64)
    power = np.asarray(env.radiance * env.solid_angle[:, None], np.float64)
    idx = np.random.default_rng(0).choice(len(pairs), size=min(slice_pairs, len(pairs)), replace=False)
    t0 = time.perf_counter()
    lighting(numpy_brdf(brdf), dirs, power, pairs.a[idx].astype(np.float64), pairs.b[idx].astype(np.float64))
    np_s = (time.perf_counter() - t0) * len(pairs) / len(idx)
    target = hf.light.lighting_target(brdf, env)
    evaluate_grouped(target, groups)  # numpy: waited for
    t0 = time.perf_counter()
    evaluate_grouped(target, groups)  # numpy: waited for
    hf_s = time.perf_counter() - t0
    return {"pairs": len(pairs), "lights": int(dirs.shape[0]), "numpy_s_extrapolated": np_s, "homofac_s": hf_s,
            "speedup": np_s / hf_s, "slice": len(idx)}


if __name__ == "__main__":
    print(json.dumps(main(), indent=2))
