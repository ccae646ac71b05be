"""The `balanced` layouts from roughness 0.3 up, on saved converged cells (bake_accuracy.py --save-pairs), in-process.

Layouts (each a `balanced` bake of the current code, evaluated in float32 at the cell's pairs against the saved
reference; nrmse and its ratio to the saved idealized split-sum, bake_pairs.py (3)):

* ``mixed``: the eighteenth session's preset (``--mixed --diffuse texture --no-shared-gain``): K = 2 below 0.35,
  P_1 + the tensor in the harmonic layers, E_0 a texture: 7 fetches, 806 400 bytes;
* ``shared``: the preset of schema 7 (the defaults): K = 2 in every layer, the tensor in its own map, E_0 as SH9,
  one harmonic channel h_A whose gain scales I_A and I_B: 8 fetches, 824 832 bytes;
* ``own``: as ``shared`` with h_A and h_B (``--no-shared-gain``: a third table, 9 fetches);
* ``hB0``: ``own`` with the h_B channel read as 0 (I_B without the harmonic; what dropping h_B without the
  shared gain reads).

    PYTHONPATH=src python benchmarks/bake_k2_layout.py PAIRS_DIR [--envs ...] [--bands 1 2] [--layouts ...]
        [--save-bakes DIR] [--json ROWS.jsonl]

``--save-bakes``: each bake written to DIR/ENV-balanced (shared) or DIR/ENV-balanced+m0.35+tex (mixed), the names
bake_accuracy.py --bake-dir reads. docs/notes/bake.md, "From 0.3 up, nineteenth session".
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import homofac as hf
from homofac.bake.model import Bake

from bake_pairs import weighted_nrmse

LAYOUTS = {"mixed": dict(mixed=True, diffuse="texture", shared_gain=False), "shared": {},
           "own": dict(shared_gain=False), "hB0": dict(shared_gain=False)}
NAMES = {"mixed": "balanced+m0.35+tex", "shared": "balanced"}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("pairs")
    ap.add_argument("--envs", nargs="+", default=list(hf.light.BUNDLED))
    ap.add_argument("--bands", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--layouts", nargs="+", choices=list(LAYOUTS), default=["mixed", "shared"])
    ap.add_argument("--save-bakes", default=None)
    ap.add_argument("--json", default=None, help="append the rows to this JSON-lines file")
    args = ap.parse_args(argv)
    for name in args.envs:
        own = None
        for lay in args.layouts:
            t = time.process_time()
            if lay == "hB0" and own is not None:
                b = own
            else:
                b = hf.bake(name, preset="balanced", **LAYOUTS[lay])
            cpu = time.process_time() - t
            if lay == "own":
                own = b
            if lay == "hB0":
                w = np.array(b.W)
                w[..., b.plan.harmonic_channel + 1] = 0.0
                b = Bake(**{**b.__dict__, "W": w})
            if args.save_bakes and lay in NAMES:
                b.save(f"{args.save_bakes}/{name}-{NAMES[lay]}")
            row = {"environment": name, "layout": lay, "cpu_s": round(cpu, 1), "bytes": int(b.texture_bytes()),
                   "lookups": b.lookups,
                   "stages_cpu_s": {k: round(v, 1) for k, v in b.info["timings"].items() if k.endswith("cpu_s")}}
            for bi in args.bands:
                z = np.load(f"{args.pairs}/{name}-{bi}.npz")
                a = np.asarray(b.evaluate(z["n"], z["v"], z["c"], z["m"], z["rho"]), np.float64)
                e = weighted_nrmse(a, z["reference"], z["w"])
                i = weighted_nrmse(z["split_sum_ideal"], z["reference"], z["w"])
                row[f"band{bi}"] = {"nrmse": round(float(e), 4), "ideal": round(float(i), 4), "ratio": round(float(e / i), 3)}
            print(json.dumps(row), flush=True)
            if args.json:
                with open(args.json, "a") as f:
                    f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
