"""The bake's diffuse term as a texture (1 lookup per E_d) or as SH9 constants (0 lookups): accuracy per fetch.

For each bundled environment, one bake (``--preset``, default sizes) is read twice: as baked (``diffuse:
texture``) and with its E_d maps replaced by their SH9 projections (``diffuse: sh9``, the same weights; what
``hf.bake(..., diffuse="sh9")`` builds). Against the pinned integrals at light resolution 32 on random visible
pairs (n, v), roughness uniform in 0.045 ... 1, random glTF materials (base colour uniform, metallic 0 / 1 /
uniform): the nrmse of I_d and of L (and of L of dielectrics at roughness > 0.6, where the diffuse term
weighs most), the lookups, and the error of SH9 against the exact irradiance
(``sh9.json``'s ``error``, the environment's own SH9).

    PYTHONPATH=src python benchmarks/bake_sh9.py [--preset fast] [--pairs 2000]

writes benchmarks/bake_sh9.json and benchmarks/bake_sh9.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import homofac as hf
from homofac.bake.model import diffuse_sh9
from homofac.light.integrals import integrals, material_radiance

HERE = Path(__file__).parent


def nrmse(a, e) -> float:
    return float(np.linalg.norm(np.asarray(a) - np.asarray(e)) / np.linalg.norm(np.asarray(e)))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--pairs", type=int, default=2000)
    ap.add_argument("--envs", nargs="*", default=list(hf.light.BUNDLED))
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    n = rng.normal(size=(args.pairs, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    v = rng.normal(size=(args.pairs, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v = np.where((np.sum(n * v, 1) < 0)[:, None], -v, v)
    rho = rng.uniform(0.045, 1.0, args.pairs)
    c = rng.uniform(0, 1, (args.pairs, 3))
    m = np.where(np.arange(args.pairs) % 3 == 0, 0.0, np.where(np.arange(args.pairs) % 3 == 1, 1.0, rng.uniform(0, 1, args.pairs)))
    rows = []
    for name in args.envs:
        bake = hf.bake(name, preset=args.preset)
        sh = dataclasses.replace(bake, plan=bake.plan._replace(diffuse_basis="sh9"), sh=diffuse_sh9(bake.E))
        env = hf.light.load_environment(name, 32)
        exact = np.asarray(integrals(env, jnp.asarray(n, jnp.float32), jnp.asarray(v, jnp.float32), jnp.asarray(rho, jnp.float32)))
        L = np.asarray(material_radiance(jnp.asarray(exact), c, m))
        Ld = np.asarray(material_radiance(jnp.asarray(exact), c, 0.0))  # the same pairs as dielectrics
        rough = rho > 0.6
        row = {"environment": name, "preset": args.preset, "sh9_irradiance_nrmse": bake.info["sh9"]["error"]["nrmse"]}
        for key, b in (("texture", bake), ("sh9", sh)):
            t = np.asarray(b.terms(n, v, rho))
            row[key] = {"lookups": b.lookups, "I_d_nrmse": nrmse(t[:, 0], exact[:, 0]),
                        "L_nrmse": nrmse(material_radiance(jnp.asarray(t), c, m), L),
                        "L_nrmse_rough_dielectric": nrmse(material_radiance(jnp.asarray(t), c, 0.0)[rough],
                                                          Ld[rough]),
                        "texture_bytes_half": b.texture_bytes()}
        rows.append(row)
        print(json.dumps(row))
    (HERE / "bake_sh9.json").write_text(json.dumps(rows, indent=1) + "\n")
    lines = [f"Bake `{args.preset}`, {args.pairs} random visible pairs and materials, roughness 0.045-1, against the "
             "pinned integrals at light resolution 32 (`PYTHONPATH=src python benchmarks/bake_sh9.py`).", "",
             "| environment | SH9 irradiance nrmse | I_d nrmse, texture | I_d nrmse, sh9 | L nrmse, texture | L nrmse, sh9 "
             "| L rough dielectrics, texture | L rough dielectrics, sh9 | lookups texture / sh9 |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['environment']} | {r['sh9_irradiance_nrmse']:.4f} | {r['texture']['I_d_nrmse']:.4f} | "
                     f"{r['sh9']['I_d_nrmse']:.4f} | {r['texture']['L_nrmse']:.4f} | {r['sh9']['L_nrmse']:.4f} | "
                     f"{r['texture']['L_nrmse_rough_dielectric']:.4f} | {r['sh9']['L_nrmse_rough_dielectric']:.4f} | "
                     f"{r['texture']['lookups']} / {r['sh9']['lookups']} |")
    (HERE / "bake_sh9.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
