"""Where the bake's error comes from: a per-term, per-cause breakdown against the converged reference.

For one environment and the benchmark's cells (:mod:`bake_accuracy`'s weighted pairs, :mod:`bake_pairs`: the
first ``--pairs`` of a cell, every figure weighted as the cell's nrmse), with e_t the error vector of term t in
L = (1 - m) 0.96 c I_d + f0_eff I_A + I_B:

* ``bake``: nrmse of L; ``d``, ``A``, ``B``: |e_t| / |L| of each term alone (the bake's I_t minus the reference's,
  times its material factor);
* ``floor``: the same for the product form's own limit: the azimuth mean of each lobe about the bake's axis at the
  pair's exact (n.v, roughness) (:func:`homofac.bake.kernels.specular_kernels`, calibrated to the albedo,
  filtered at the pair's axis with lights at ``--lights``): what any P(a) W(n.v) with infinitely many layers,
  terms and texels reads (the azimuth variance about the axis remains);
* ``layers``: the same azimuth means blended between the two layers around the pair's roughness with the bake's
  hat weights (the error of interpolating along roughness alone);
* ``ideal``: idealized split-sum (the benchmark's);
* ``--snap``: the bake at the drawn roughness, at the nearest layer's and midway between two layers (in u);
* ``--top N``: the N pairs carrying most of the bake's squared error: share, roughness, n.v, angle of r from the
  bake's analytic source (degrees), and I_A, I_B (luminance) of the reference, the bake and the idealized split-sum.

    PYTHONPATH=src python benchmarks/bake_breakdown.py forest [--preset balanced] [--pairs 1024] [--bands 1 2]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import homofac as hf
from homofac.bake import kernels as kn
from homofac.bake.build import texel_radius
from homofac.bake.filter import normalized, prefilter
from homofac.io.exr import read_exr
from homofac.light.environment import LUMINANCE
from homofac.light.integrals import material_radiance
from homofac.light.reference import reference_integrals, source_map

sys.path.insert(0, str(Path(__file__).parent))
import bake_accuracy as ba  # noqa: E402
from bake_pairs import weighted_pairs  # noqa: E402


def azimuth_means(env, axis, x, rho, shift=0.0):
    """(N, 2, 3): the azimuth means of I_A, I_B about ``axis`` at each pair's (x, rho) (one kernel per pair)."""
    tables, masses = [], []
    for xi, ri in zip(x, rho):
        xa = np.array([xi])
        k = kn.calibrate(kn.specular_kernels(float(ri), xa, shift=shift), kn.albedos(float(ri), xa))[:, 0]  # (2, G)
        tables.append(k)
    t = kn.smooth(np.concatenate(tables), texel_radius(env))  # (2N, G)
    num, den = prefilter(t, axis, env)  # (N, 2N, 3)
    out = normalized(num, den, kn.mass(t))
    i = np.arange(len(x))
    return np.stack([out[i, 2 * i], out[i, 2 * i + 1]], 1)


def parts_nrmse(parts, ref, c, m, w=None):
    """Weighted nrmse of L and |e_t| / |L| per term (d, A, B), weights ``w`` (N,) (1 when None)."""
    sw = np.sqrt(np.ones(len(c)) if w is None else w)[:, None]
    L = np.asarray(material_radiance(jnp.asarray(ref), c, m)) * sw
    Lb = np.asarray(material_radiance(jnp.asarray(parts), c, m)) * sw
    f0 = (1 - m)[:, None] * 0.04 + m[:, None] * c
    fac = [(1 - m)[:, None] * 0.96 * c, f0, np.ones_like(c)]
    norm = np.linalg.norm(L)
    terms = [float(np.linalg.norm(sw * fac[t] * (parts[:, t] - ref[:, t])) / norm) for t in range(3)]
    return float(np.linalg.norm(Lb - L) / norm), terms


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("env")
    ap.add_argument("--preset", default="balanced")
    ap.add_argument("--pairs", type=int, default=1024, help="the first PAIRS of each cell's pairs (a power of two)")
    ap.add_argument("--bands", nargs="+", type=int, default=[0, 1, 2, 3])
    ap.add_argument("--lights", type=int, default=64, help="light resolution of the floor's filter")
    ap.add_argument("--samples", type=int, default=8192)
    ap.add_argument("--bake", default=None, help="a saved bake directory instead of baking")
    ap.add_argument("--options", default="{}", help="JSON bake options")
    ap.add_argument("--shifts", nargs="+", type=float, default=[0.0], help="axis shifts of the floor (in units of alpha)")
    ap.add_argument("--no-bake", action="store_true", help="only the floor and idealized split-sum (the bake's I_d: the reference's)")
    ap.add_argument("--top", type=int, default=0, help="print the pairs carrying most of the bake's squared error")
    ap.add_argument("--snap", action="store_true", help="only the bake at the drawn roughness, snapped to the nearest layer and "
                                                        "midway between layers (reference recomputed at each)")
    args = ap.parse_args(argv)
    name = args.env
    src = source_map(read_exr(hf.light.bundled(name)), name)
    uniform = source_map(np.ones((8, 16, 3)))
    t = time.perf_counter()
    b = None
    if not args.no_bake:
        b = hf.load(args.bake) if args.bake else hf.bake(name, preset=args.preset, **json.loads(args.options))
        print(f"bake {time.perf_counter() - t:.1f} s: {b.describe()}", flush=True)
    env = hf.light.load_environment(name, args.lights)
    image = read_exr(hf.light.bundled(name))
    for bi in args.bands:
        band = ba.BANDS[bi]
        n, v, c, m, rho, w = weighted_pairs(image, band, args.pairs, ba.cell_seed(name, bi))
        ref = reference_integrals(src, n, v, rho, samples=args.samples)
        if args.snap and b is not None:
            rl = np.asarray(b.roughness)
            hi = np.clip(np.searchsorted(rl, rho), 1, len(rl) - 1)
            row = {"env": name, "band": band}
            for label, r in (("drawn", rho), ("snapped", rl[np.argmin(np.abs(np.log(rho[:, None] / rl[None])), axis=1)]),
                             ("midway", np.sqrt(rl[hi - 1] * rl[hi]))):
                ref_r = reference_integrals(src, n, v, r, samples=args.samples)
                row[label] = round(parts_nrmse(np.asarray(b.terms(n, v, r), np.float64), ref_r, c, m, w)[0], 4)
            print(json.dumps(row), flush=True)
            continue
        parts = ref.copy() if b is None else np.asarray(b.terms(n, v, rho), np.float64)
        x = np.sum(n * v, 1)
        r = 2 * x[:, None] * n - v
        ideal = ba.ideal_split_sum(src, uniform, name, n, v, rho, args.samples)
        cases = [("ideal", ideal)] + ([("bake", parts)] if b is not None else [])
        # the floor: azimuth means at the pair's exact roughness about the axis normalize((1 - s) r + s n),
        # s = shift alpha; the diffuse term the bake's
        for sh in args.shifts:
            floor = parts.copy()
            s = np.minimum(1.0, sh * rho ** 2)[:, None]
            axis = (1 - s) * r + s * n
            axis /= np.linalg.norm(axis, axis=1, keepdims=True)
            floor[:, 1:] = np.concatenate([azimuth_means(env, axis[i:i + 1], x[i:i + 1], rho[i:i + 1], float(s[i, 0]))
                                           for i in range(len(x))]) if sh else azimuth_means(env, r, x, rho)
            cases.append((f"floor s={sh:g}a", floor))
        if b is not None:
            # layers: the azimuth means at the two layers around rho blended with the bake's hat weights
            rl = np.asarray(b.roughness)
            u = np.asarray(b.layer_coordinate(rho))
            j0 = np.clip(np.floor(u).astype(int), 0, len(rl) - 2)
            f = u - j0
            lay = parts.copy()
            lay[:, 1:] = ((1 - f)[:, None, None] * azimuth_means(env, r, x, rl[j0])
                          + f[:, None, None] * azimuth_means(env, r, x, rl[j0 + 1]))
            cases.append(("layers", lay))
        row = {"env": name, "band": band}
        for label, p in cases:
            tot, terms = parts_nrmse(p, ref, c, m, w)
            row[label] = [round(tot, 4)] + [round(e, 4) for e in terms]
        L = np.asarray(material_radiance(jnp.asarray(ref), c, m))
        e2 = w * np.sum((np.asarray(material_radiance(jnp.asarray(cases[-1][1] if b is None else parts), c, m)) - L) ** 2, 1)
        row["err_share_nv<0.3"] = round(float(e2[x < 0.3].sum() / e2.sum()), 3)
        row["err_top5_share"] = round(float(np.sort(e2)[-5:].sum() / e2.sum()), 3)
        print(json.dumps(row), flush=True)
        if args.top and b is not None:
            lum = np.asarray(LUMINANCE, np.float64)
            sun = np.asarray(b.sources[0].direction) if b.sources else None
            for i in np.argsort(e2)[::-1][:args.top]:
                print(json.dumps({"pair": int(i), "share": round(float(e2[i] / e2.sum()), 3), "rho": round(float(rho[i]), 3),
                                  "nv": round(float(x[i]), 3),
                                  "deg_from_source": None if sun is None else round(float(np.degrees(np.arccos(np.clip(r[i] @ sun, -1, 1)))), 1),
                                  **{f"{k}_AB": [round(float(p[i, t] @ lum), 4) for t in (1, 2)]
                                     for k, p in (("ref", ref), ("bake", parts), ("ideal", ideal))}}), flush=True)


if __name__ == "__main__":
    main()
