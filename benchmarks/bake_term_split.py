"""I_A and I_B alone: saved bakes against the converged reference and the product form's floor, per n.v bin.

Random visible pairs at roughness uniform in [LO, HI]; reference at 8192 samples. Per bin and case: sum ratio
and nrmse of I_A and of I_B alone, and for metals (c uniform in [0, 1], one grey value per pair) the sum ratio
and nrmse of c I_A + I_B, and that nrmse with the reference's I_B in place of the case's (what I_B's error costs
a metal). Cases: ``floor`` (azimuth means about r at the pair's roughness, :func:`bake_breakdown.azimuth_means`),
each bake directory, ``--lightsum`` the pinned light sum at 16 and 64 light resolution.

    PYTHONPATH=src python benchmarks/bake_term_split.py interior 300 0.3 0.6 BAKE_DIR [BAKE_DIR ...] [--lightsum]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import homofac as hf
from homofac.io.exr import read_exr
from homofac.light.integrals import integrals
from homofac.light.reference import reference_integrals, source_map

sys.path.insert(0, str(Path(__file__).parent))
import bake_accuracy as ba  # noqa: E402
import bake_breakdown as bb  # noqa: E402

BINS = ((0.0, 0.3), (0.3, 0.7), (0.7, 1.0))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("env")
    ap.add_argument("pairs", type=int)
    ap.add_argument("lo", type=float)
    ap.add_argument("hi", type=float)
    ap.add_argument("bakes", nargs="*")
    ap.add_argument("--lightsum", action="store_true")
    ap.add_argument("--no-floor", action="store_true")
    args = ap.parse_args(argv)
    src = source_map(read_exr(hf.light.bundled(args.env)), args.env)
    rng = np.random.default_rng(1)
    n, v = ba.pairs(args.pairs, rng)
    rho = rng.uniform(args.lo, args.hi, args.pairs)
    c = rng.uniform(0, 1, (args.pairs, 1))
    x = np.sum(n * v, 1)
    ref = np.asarray(reference_integrals(src, n, v, rho, samples=8192), np.float64)[:, 1:]
    cases = {}
    if not args.no_floor:
        cases["floor"] = bb.azimuth_means(hf.light.load_environment(args.env, 64), 2 * x[:, None] * n - v, x, rho)
    for d in args.bakes:
        cases[Path(d).name] = np.asarray(hf.load(d).terms(n, v, rho), np.float64)[:, 1:]
    if args.lightsum:
        for res in (16, 64):
            cases[f"lightsum{res}"] = np.asarray(integrals(hf.light.load_environment(args.env, res), n, v, rho), np.float64)[:, 1:]
    print("case | n.v | pairs | I_A sum ratio / nrmse | I_B sum ratio / nrmse | metal sum ratio / nrmse | metal nrmse, I_B exact")
    for label, p in cases.items():
        for a, b in BINS:
            s = (x >= a) & (x < b)
            cell = lambda P, R: f"{P.sum() / R.sum():.3f} / {np.linalg.norm(P - R) / np.linalg.norm(R):.3f}"  # noqa: E731
            Lr, Lb = c[s] * ref[s, 0] + ref[s, 1], c[s] * p[s, 0] + p[s, 1]
            Le = c[s] * p[s, 0] + ref[s, 1]
            print(f"{label} | {a:g}-{b:g} | {int(s.sum())} | {cell(p[s, 0], ref[s, 0])} | {cell(p[s, 1], ref[s, 1])} | "
                  f"{cell(Lb, Lr)} | {np.linalg.norm(Le - Lr) / np.linalg.norm(Lr):.3f}", flush=True)


if __name__ == "__main__":
    main()
