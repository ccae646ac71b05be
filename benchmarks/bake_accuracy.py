"""Accuracy of the material-parametric bake against a converged brute-force integral, beside split-sum.

For each bundled environment and roughness band (0.045-0.15, 0.15-0.3, 0.3-0.6, 0.6-1): random visible pairs
(n, v) with random glTF materials (roughness uniform in the band, base colour uniform, metallic 0 for a
third, 1 for a third, uniform for the rest); the nrmse of L = (1 - m) 0.96 c I_d + f0_eff I_A + I_B against

* the reference: :func:`homofac.light.integrals.integrals` (the pinned light sum) at light resolution 32, 64,
  ... doubled until one more doubling moves the band's L by < 1 % nrmse (or the cap, reported);
* the bake (``hf.bake``, per preset), its time and texture memory;
* idealized split-sum: I_A ~ P(r) A, I_B ~ P(r) B with P Karis' prefilter (GGX D at the pair's own roughness,
  n = v = r, normalized) at the reference's light resolution, A and B the exact DFG at the pair's (n.v, rho)
  (albedo quadrature on a 48 x 48 grid, bilinear), I_d ~ E(n)/pi times the exact diffuse albedo d(n.v) pi;
* split-sum the engines' way: E(n) from a 32^2 x 6 irradiance map, P from a prefiltered mip chain (face size
  the source's detail down to 4, level lod = rho (levels - 1), each level prefiltered at its roughness, read
  bilinearly per face and blended between levels), A, B, d from 32 x 32 tables (bilinear).

    PYTHONPATH=src python benchmarks/bake_accuracy.py [--pairs 200] [--presets fast balanced] [--envs forest ...]

writes benchmarks/bake_accuracy.json and benchmarks/bake_accuracy.md.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import homofac as hf
from homofac.bake import kernels as kn
from homofac.bake.build import source_size
from homofac.bake.filter import prefilter
from homofac.baselines.base import irradiance_map
from homofac.light.integrals import integrals, material_radiance
from homofac.param import mappers

BANDS = ((0.045, 0.15), (0.15, 0.3), (0.3, 0.6), (0.6, 1.0))
HERE = Path(__file__).parent


def pairs(count, rng):
    n = rng.normal(size=(count, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    v = rng.normal(size=(count, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v = np.where((np.sum(n * v, 1) < 0)[:, None], -v, v)
    return n, v


def materials(count, band, rng):
    rho = rng.uniform(*band, count)
    c = rng.uniform(0, 1, (count, 3))
    m = np.where(np.arange(count) % 3 == 0, 0.0, np.where(np.arange(count) % 3 == 1, 1.0, rng.uniform(0, 1, count)))
    return c, m, rho


def nrmse(a, e):
    return float(np.linalg.norm(np.asarray(a) - np.asarray(e)) / np.linalg.norm(np.asarray(e)))


def reference(name, n, v, rho, c, m, start=32, cap=256):
    """(parts, resolution, converged, last change) of the doubling loop."""
    prev, res, change = None, start, None
    while True:
        env = hf.light.load_environment(name, res)
        parts = np.asarray(integrals(env, jnp.asarray(n, jnp.float32), jnp.asarray(v, jnp.float32), jnp.asarray(rho, jnp.float32)))
        L = np.asarray(material_radiance(jnp.asarray(parts), c, m))
        if prev is not None:
            change = nrmse(prev, L)
            if change < 0.01:
                return parts, res, True, change
        if res >= cap:
            return parts, res, False, change
        prev, res = L, 2 * res


@eqx.filter_jit
def _karis(r, rho, dirs, power, sa):
    """Karis' normalized GGX prefilter at each pair's own roughness: (N, 3)."""
    def one(a):
        rr, ro = a
        c = rr @ dirs.T
        ch2 = jnp.clip((1.0 + c) * 0.5, 0.0, 1.0)
        a2 = (ro ** 4)[:, None]
        w = a2 / (jnp.pi * (ch2 * (a2 - 1.0) + 1.0) ** 2) * jnp.maximum(c, 0.0)
        return (w @ power) / jnp.maximum((w @ sa)[:, None], 1e-30)
    k = 50
    return jax.lax.map(one, (r.reshape(-1, k, 3), rho.reshape(-1, k))).reshape(-1, 3)


class DFG:
    """The DFG terms A, B (albedos of the lobes (1 - s5) S and s5 S) and d (of (1 - s5)/pi, so that I_d ~ E d)
    on a grid, bilinear in (n.v, rho)."""

    def __init__(self, size):
        self.x = kn.nv_centres(size)
        self.r = np.linspace(0.04, 1.0, size)
        self.ab = np.stack([kn.albedos(float(r), self.x) for r in self.r])  # (R, 2, X)
        self.d = kn.mass(kn.diffuse_kernels(self.x))

    def __call__(self, x, rho):
        fr = np.clip((rho - self.r[0]) / (self.r[1] - self.r[0]), 0, len(self.r) - 1.0001)
        i = np.floor(fr).astype(int)
        t = fr - i
        def line(table):  # (X,) per row
            return np.interp(x, self.x, table)
        a = np.array([(1 - t[k]) * np.interp(x[k], self.x, self.ab[i[k], 0]) + t[k] * np.interp(x[k], self.x, self.ab[i[k] + 1, 0]) for k in range(len(x))])
        b = np.array([(1 - t[k]) * np.interp(x[k], self.x, self.ab[i[k], 1]) + t[k] * np.interp(x[k], self.x, self.ab[i[k] + 1, 1]) for k in range(len(x))])
        return a, b, line(self.d)


def engines_split_sum(name, n, v, rho, dfg32, source):
    """I_d, I_A, I_B the engines' way (see the module docstring)."""
    env_e = hf.light.load_environment(name, 32)
    e = irradiance_map(env_e, "cube", 32)
    x = np.sum(n * v, 1)
    r = 2 * x[:, None] * n - v
    ev = np.asarray(mappers.lookup("cube", jnp.asarray(e, jnp.float32), jnp.asarray(n, jnp.float32)))
    levels = int(np.log2(source)) - 1  # down to 4
    sizes = [source >> j for j in range(levels)]
    lod = rho * (levels - 1)
    q = kn.q_grid()
    ch2 = 1 - q * q
    cosg = 1 - 2 * q * q
    p = 0.0
    for j, s in enumerate(sizes):
        rj = j / (levels - 1)
        env = hf.light.load_environment(name, max(s, 8))
        dirs = mappers.texel_directions("cube", s).reshape(-1, 3)
        a2 = max(rj, 0.045) ** 4  # level 0: the sharpest roughness the engines serve (a near mirror)
        kern = kn.smooth((a2 / (np.pi * (ch2 * (a2 - 1) + 1) ** 2) * np.maximum(cosg, 0))[None], (np.pi / 2) / max(s, 8))
        num, den = prefilter(kern, dirs, env)
        level = (num[:, 0] / den[:, :1]).reshape(s, 6 * s, 3)
        w = np.maximum(0, 1 - np.abs(lod - j))[:, None]
        p = p + w * np.asarray(mappers.lookup("cube", jnp.asarray(level, jnp.float32), jnp.asarray(r, jnp.float32)))
    a, b, d = dfg32(x, rho)
    return np.stack([ev / np.pi * d[:, None], p * a[:, None], p * b[:, None]], 1), sum(6 * s * s * 3 * 2 for s in sizes)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--pairs", type=int, default=150)
    ap.add_argument("--presets", nargs="+", default=["fast", "balanced"])
    ap.add_argument("--envs", nargs="+", default=list(hf.light.BUNDLED))
    ap.add_argument("--cap", type=int, default=256)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    dfg_exact, dfg32 = DFG(48), DFG(32)
    rows, bakes = [], {}
    for name in args.envs:
        source = source_size(name)
        for preset in args.presets:
            t = time.perf_counter()
            b = hf.bake(name, preset=preset)
            bakes[(name, preset)] = b
            print(f"{name} {preset}: {time.perf_counter() - t:.1f} s; {b.describe()}", flush=True)
        for band in BANDS:
            n, v = pairs(args.pairs, rng)
            c, m, rho = materials(args.pairs, band, rng)
            parts, res, conv, change = reference(name, n, v, rho, c, m, cap=args.cap)
            L = np.asarray(material_radiance(jnp.asarray(parts), c, m))
            x = np.sum(n * v, 1)
            r = 2 * x[:, None] * n - v
            env = hf.light.load_environment(name, res)
            power = env.radiance * env.solid_angle[:, None]
            pad = (-len(r)) % 50
            rp = np.concatenate([r, r[:pad]]) if pad else r
            rhop = np.concatenate([rho, rho[:pad]]) if pad else rho
            p = np.asarray(_karis(jnp.asarray(rp, jnp.float32), jnp.asarray(rhop, jnp.float32), env.directions, power, env.solid_angle))[:len(r)]
            e = np.asarray(hf.light.irradiance(hf.light.load_environment(name, 64), jnp.asarray(n, jnp.float32)))
            a, bb, d = dfg_exact(x, rho)
            ideal = np.stack([e / np.pi * d[:, None], p * a[:, None], p * bb[:, None]], 1)
            eng, eng_bytes = engines_split_sum(name, n, v, rho, dfg32, source)
            row = {"environment": name, "band": list(band), "pairs": args.pairs, "reference_resolution": res,
                   "reference_converged": conv, "reference_last_change": change,
                   "split_sum_ideal": nrmse(material_radiance(jnp.asarray(ideal), c, m), L),
                   "split_sum_engines": nrmse(material_radiance(jnp.asarray(eng), c, m), L),
                   "split_sum_engines_bytes": eng_bytes + 32 * 32 * 6 * 3 * 2 + 32 * 32 * 3 * 2}
            for preset in args.presets:
                b = bakes[(name, preset)]
                got = np.asarray(b.evaluate(n, v, c, m, rho))
                row[f"bake_{preset}"] = nrmse(got, L)
                row[f"bake_{preset}_lookups"] = b.lookups
                row[f"bake_{preset}_s"] = b.info["timings"]["total_s"]
                row[f"bake_{preset}_bytes"] = b.texture_bytes()
                row[f"bake_{preset}_timings"] = b.info["timings"]
            rows.append(row)
            print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items() if "timings" not in k}), flush=True)
    (HERE / "bake_accuracy.json").write_text(json.dumps(rows, indent=1))
    lines = ["| environment | band | ref. res. (converged) | split-sum ideal | split-sum engines | "
             + " | ".join(f"bake {p} ({bakes[(args.envs[0], p)].lookups} lookups)" for p in args.presets) + " | "
             + " | ".join(f"ratio {p} / ideal" for p in args.presets) + " |",
             "|---|---|---|---|---|" + "---|" * (2 * len(args.presets))]
    for row in rows:
        lines.append(f"| {row['environment']} | {row['band'][0]}-{row['band'][1]} | {row['reference_resolution']} "
                     f"({'yes' if row['reference_converged'] else 'no, last %.3f' % (row['reference_last_change'] or 0)}) | "
                     f"{row['split_sum_ideal']:.4f} | {row['split_sum_engines']:.4f} | "
                     + " | ".join(f"{row[f'bake_{p}']:.4f}" for p in args.presets) + " | "
                     + " | ".join(f"{row[f'bake_{p}'] / row['split_sum_ideal']:.2f}" for p in args.presets) + " |")
    lines.append("")
    lines.append("| environment | preset | lookups | bake time (s) | texture MB (half) | split-sum engines MB |")
    lines.append("|---|---|---|---|---|---|")
    for (name, preset), b in bakes.items():
        eng = next(r for r in rows if r["environment"] == name)["split_sum_engines_bytes"]
        t = b.info["timings"]
        lines.append(f"| {name} | {preset} | {b.lookups} | {t['total_s']:.1f} (maps {t['maps_s']:.1f}, weights "
                     f"{t['weights_s']:.1f}, kernels {t['kernels_s']:.1f}, diffuse {t['diffuse_s']:.1f}) | "
                     f"{b.texture_bytes() / 1e6:.2f} | {eng / 1e6:.2f} |")
    (HERE / "bake_accuracy.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
