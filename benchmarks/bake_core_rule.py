"""A cell's weighted nrmse with each analytic source's core width set by a rule at evaluation, the maps unchanged:
one CORE for every entry, or each entry's own :func:`homofac.bake.sources.core_factor` (1 + K pixel / sqrt(|a1||a2|))
at several K and BLUR (the box's Gaussian part, :func:`homofac.bake.sources.box_widths`).

    PYTHONPATH=src python benchmarks/bake_core_rule.py ENV:PAIRS.npz:BAKE_DIR [...] [--pixel RAD]
        [--core 1.15 1.2 1.25] [--k 0.1 0.11] [--blur 0.2 0.333333]

PAIRS.npz: a cell written by ``bake_accuracy.py --save-pairs`` (n, v, c, m, rho, w, reference); BAKE_DIR: a bake of
that environment (its sources' axes are re-read with each rule; the first column is the bake as saved). ``--pixel``:
the source map's pixel angle (pi / 128 for the bundled 256 x 128 lat-longs). docs/notes/bake.md, "Below 0.15,
twenty-second session".
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

import homofac as hf
from homofac.bake.sources import box_widths, core_factor


def weighted_nrmse(a, ref, w) -> float:
    """sqrt(sum w |a - L|^2 / sum w |L|^2) (the benchmark's cell error, pairs weighted by ``w``)."""
    return float(np.sqrt(np.sum(w[:, None] * (a - ref) ** 2) / np.sum(w[:, None] * ref ** 2)))


def with_rule(sources, pixel: float, core: float | None, k: float, blur: float):
    """``sources`` with their ``core`` (``core`` for all, or each one's :func:`core_factor` at ``k`` when None) and
    the box of that core at ``blur``."""
    out = []
    for s in sources:
        s = s._replace(core=core if core is not None else core_factor(s, pixel, k))
        out.append(s._replace(box=box_widths(s, pixel, blur)))
    return tuple(out)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("cells", nargs="+", help="ENV:PAIRS.npz:BAKE_DIR")
    p.add_argument("--pixel", type=float, default=np.pi / 128)
    p.add_argument("--core", type=float, nargs="*", default=[1.2])
    p.add_argument("--k", type=float, nargs="*", default=[0.1])
    p.add_argument("--blur", type=float, nargs="*", default=[0.2])
    args = p.parse_args(argv)
    rules = [(f"CORE {c:g}, BLUR {b:.3g}", c, 0.0, b) for c in args.core for b in args.blur]
    rules += [(f"K {k:g}, BLUR {b:.3g}", None, k, b) for k in args.k for b in args.blur]
    for cell in args.cells:
        env, pairs, bake_dir = cell.split(":")
        z = np.load(pairs)
        bake = hf.load(bake_dir)
        n, v, c, m, rho, w, ref = (z[k] for k in ("n", "v", "c", "m", "rho", "w", "reference"))

        def err(b) -> float:
            return weighted_nrmse(np.asarray(b.evaluate(n, v, c, m, rho), np.float64), ref, w)

        row = [f"{env} ({len(w)} pairs): as baked {err(bake):.4f}"]
        for name, core, k, blur in rules:
            row.append(f"{name} {err(dataclasses.replace(bake, sources=with_rule(bake.sources, args.pixel, core, k, blur))):.4f}")
        print(" | ".join(row), flush=True)


if __name__ == "__main__":
    main()
