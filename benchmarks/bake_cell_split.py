"""A converged cell's squared error, split by n.v, roughness and term, for any bakes, from a saved cell.

``benchmarks/bake_accuracy.py --save-pairs DIR`` writes each cell's pairs, weights, every method's radiance and
the reference's (I_d, I_A, I_B) to DIR/NAME-BAND.npz. This reads one, and for each bake given (saved bake
directories, read with ``hf.load``) evaluates its terms at the cell's pairs against the saved reference, so a
variant of the bake is measured on the converged cell's pairs without recomputing the reference. Printed:

* per bake (and the methods saved in the file): the cell's weighted nrmse (bake_pairs.py (3));
* ``--nv``: per n.v interval, the population's share (weighted), the share of sum w |L|^2, and each method's
  part of the cell's nrmse^2: nrmse_bin^2 = sum_bin w |a - L|^2 / sum_all w |L|^2 (the bins add to the cell's
  nrmse^2), with the bake's error by term (d, A, B: |e_t| as in bake_breakdown.parts_nrmse);
* ``--layers``: the same by the interval between two of the first bake's layers holding the pair's roughness;
* ``--top N``: the N pairs of largest w |a - L|^2 for the first bake.

    PYTHONPATH=src python benchmarks/bake_cell_split.py /tmp/pairs/forest-1.npz BAKE_DIR [BAKE_DIR ...]
        [--nv 0 0.1 0.3 0.7 1] [--layers] [--top 5]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import homofac as hf
from homofac.light.environment import LUMINANCE
from homofac.light.integrals import material_radiance


def term_errors(parts, ref, c, m) -> np.ndarray:
    """|e_t|^2 (N, 3) of the terms d, A, B with their material factors (1 - m) 0.96 c, f0_eff, 1."""
    f0 = (1 - m)[:, None] * 0.04 + m[:, None] * c
    fac = [(1 - m)[:, None] * 0.96 * c, f0, np.ones_like(c)]
    return np.stack([np.sum((fac[t] * (parts[:, t] - ref[:, t])) ** 2, 1) for t in range(3)], 1)


def split(key, edges, w, L2, errs) -> list[dict]:
    """Rows per interval of ``key``: population share, |L|^2 share and each method's nrmse_bin^2 part."""
    total = np.sum(w * L2)
    rows = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        s = (key >= lo) & (key < hi) if hi < edges[-1] else (key >= lo) & (key <= hi)
        row = {"interval": [round(float(lo), 3), round(float(hi), 3)], "pairs": int(s.sum()),
               "population": round(float(np.sum(w[s]) / np.sum(w)), 4), "L2_share": round(float(np.sum((w * L2)[s]) / total), 4)}
        for k, e in errs.items():
            row[k] = round(float(np.sum((w * e)[s]) / total), 5) if e.ndim == 1 else [round(float(np.sum((w * e[:, t])[s]) / total), 5) for t in range(e.shape[1])]
        rows.append(row)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("cell", help="an .npz of bake_accuracy.py --save-pairs")
    ap.add_argument("bakes", nargs="*", help="saved bake directories")
    ap.add_argument("--nv", nargs="+", type=float, default=[0, 0.1, 0.3, 0.7, 1.0], help="n.v interval edges")
    ap.add_argument("--layers", action="store_true", help="split by the first bake's layer intervals")
    ap.add_argument("--top", type=int, default=0)
    args = ap.parse_args(argv)
    z = np.load(args.cell)
    n, v, c, m, rho, w = (z[k] for k in ("n", "v", "c", "m", "rho", "w"))
    L, ref = z["reference"], z["reference_parts"]
    L2 = np.sum(L * L, 1)
    x = np.sum(n * v, 1)
    errs, terms = {}, {}
    for k in z.files:
        if k.startswith(("bake_", "split_sum", "sampler")):
            errs[k] = np.sum((z[k] - L) ** 2, 1)
    bakes = {}
    for d in args.bakes:
        b = hf.load(d)
        label = Path(d).name
        bakes[label] = b
        parts = np.asarray(b.terms(n, v, rho), np.float64)
        a = np.asarray(material_radiance(jnp.asarray(parts), c, m), np.float64)
        errs[label] = np.sum((a - L) ** 2, 1)
        terms[label + " (d, A, B)"] = term_errors(parts, ref, c, m)
    total = np.sum(w * L2)
    print(json.dumps({"cell": args.cell, "pairs": len(w), **{k: round(float(np.sqrt(np.sum(w * e) / total)), 4) for k, e in errs.items()}}))
    allerr = {**errs, **terms}
    if args.nv:
        for row in split(x, np.asarray(args.nv), w, L2, allerr):
            print(json.dumps({"n.v": row.pop("interval"), **row}))
    if args.layers and bakes:
        rl = np.asarray(next(iter(bakes.values())).roughness)
        edges = rl[(rl >= rho.min() - 1e-9) | (np.arange(len(rl)) == np.searchsorted(rl, rho.min()) - 1)]
        edges = np.unique(np.clip(np.concatenate([[rho.min()], edges, [rho.max()]]), rho.min(), rho.max()))
        for row in split(rho, edges, w, L2, allerr):
            print(json.dumps({"roughness": row.pop("interval"), **row}))
    if args.top and bakes:
        label, b = next(iter(bakes.items()))
        lum = np.asarray(LUMINANCE, np.float64)
        parts = np.asarray(b.terms(n, v, rho), np.float64)
        e = w * errs[label]
        r = 2 * x[:, None] * n - v
        sun = np.asarray(b.sources[0].direction) if getattr(b, "sources", None) else None
        for i in np.argsort(e)[::-1][:args.top]:
            print(json.dumps({"pair": int(i), "share": round(float(e[i] / e.sum()), 3), "w": round(float(w[i]), 3),
                              "rho": round(float(rho[i]), 3), "nv": round(float(x[i]), 3), "metal": round(float(m[i]), 2),
                              "deg_from_source": None if sun is None else round(float(np.degrees(np.arccos(np.clip(r[i] @ sun, -1, 1)))), 1),
                              "ref_dAB": [round(float(ref[i, t] @ lum), 4) for t in range(3)],
                              "bake_dAB": [round(float(parts[i, t] @ lum), 4) for t in range(3)]}))


if __name__ == "__main__":
    main()
