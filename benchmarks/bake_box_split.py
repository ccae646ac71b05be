"""A saved cell's error, by angle from the nearest analytic source and by roughness, for bakes on the same pairs.

Each bake's share of the cell's nrmse^2 (sum w |a - L|^2 / sum w |L|^2, the pairs' weights w) in bins of the angle
between the mirror direction r = 2 (n.v) n - v and the nearest of the first bake's sources, and in bins of
roughness; the pairs' weight and L^2 share per bin. docs/notes/bake.md, "Studio below 0.15, twenty-first session".

    PYTHONPATH=src python benchmarks/bake_box_split.py PAIRS_DIR studio 0 BAKE [BAKE ...]
"""
import json
import sys
from pathlib import Path

import numpy as np

import homofac as hf

sys.path.insert(0, str(Path(__file__).parent))
from bake_source_aniso import cell  # noqa: E402

ANGLES = (0, 1, 2, 3, 5, 8, 20, 45, 180)  # degrees
ROUGH = (0.0, 0.07, 0.1, 0.125, 0.15, 0.3, 0.6, 1.0)


def main():
    pairs, name, band, bakes = Path(sys.argv[1]), sys.argv[2], int(sys.argv[3]), sys.argv[4:]
    z = cell(pairs, name, band)
    n, v, w, L = (np.asarray(z[k], np.float64) for k in ("n", "v", "w", "L"))
    r = 2 * np.sum(n * v, 1)[:, None] * n - v
    loaded = [hf.load(b) for b in bakes]
    ell = np.array([s.direction for s in loaded[0].sources]).reshape(-1, 3)
    ang = np.degrees(np.arccos(np.clip((r @ ell.T).max(1), -1, 1))) if len(ell) else np.full(len(w), 180.0)
    den = float(np.sum(w * np.sum(L * L, 1)))
    err = {b: w * np.sum((np.asarray(m.evaluate(z["n"], z["v"], z["c"], z["m"], z["rho"]), np.float64) - L) ** 2, 1) / den
           for b, m in zip(bakes, loaded)}
    for label, key, edges in (("degrees", ang, ANGLES), ("roughness", np.asarray(z["rho"]), ROUGH)):
        for lo, hi in zip(edges[:-1], edges[1:]):
            sel = (key >= lo) & (key < hi)
            if not sel.any():
                continue
            print(json.dumps({"cell": f"{name}-{band}", label: f"{lo}-{hi}", "weight": round(float(w[sel].sum() / w.sum()), 4),
                              "L2": round(float(np.sum((w * np.sum(L * L, 1))[sel]) / den), 4),
                              **{"/".join(Path(b).parts[-3:]): round(float(e[sel].sum()), 5) for b, e in err.items()}}))
    print(json.dumps({"cell": f"{name}-{band}", "total": {"/".join(Path(b).parts[-3:]): round(float(np.sqrt(e.sum())), 4)
                                                          for b, e in err.items()}}))


if __name__ == "__main__":
    main()
