"""A cell's weighted nrmse with the bake's analytic sources changed at evaluation (their power scaled, their core
width factor set), the maps unchanged: what the source's power and CORE are worth on converged pairs.

    PYTHONPATH=src python benchmarks/bake_core_power.py PAIRS.npz BAKE_DIR [--preset balanced] [--scale 1 1.03]
        [--core 1.1 1.15 1.2 1.25]

PAIRS.npz: a cell written by ``bake_accuracy.py --save-pairs`` (n, v, c, m, rho, w, reference, bake_<preset>);
BAKE_DIR: the bake those pairs were measured with (the first line checks that it reads the saved column).
docs/notes/bake.md, "Forest below 0.15, twenty-first session".
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

import homofac as hf


def weighted_nrmse(a, ref, w) -> float:
    """sqrt(sum w |a - L|^2 / sum w |L|^2) (the benchmark's cell error, pairs weighted by ``w``)."""
    return float(np.sqrt(np.sum(w[:, None] * (a - ref) ** 2) / np.sum(w[:, None] * ref ** 2)))


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("pairs")
    p.add_argument("bake")
    p.add_argument("--preset", default="balanced")
    p.add_argument("--scale", type=float, nargs="+", default=[1.0])
    p.add_argument("--core", type=float, nargs="+", default=[1.1, 1.15, 1.2, 1.25])
    args = p.parse_args(argv)
    z = np.load(args.pairs)
    b = hf.load(args.bake)
    n, v, c, m, rho, w, ref = (z[k] for k in ("n", "v", "c", "m", "rho", "w", "reference"))

    def err(bake) -> float:
        return weighted_nrmse(np.asarray(bake.evaluate(n, v, c, m, rho), np.float64), ref, w)

    print(f"saved {weighted_nrmse(z[f'bake_{args.preset}'], ref, w):.4f}, this bake {err(b):.4f}")
    for scale in args.scale:
        for core in args.core:
            src = tuple(s._replace(power=tuple(q * scale for q in s.power), core=core) for s in b.sources)
            print(f"power x{scale:g}, core {core:g}: {err(dataclasses.replace(b, sources=src)):.4f}", flush=True)


if __name__ == "__main__":
    main()
