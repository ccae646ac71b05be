"""Variants of the `balanced` bake measured on saved converged cells (bake_accuracy.py --save-pairs), in-process.

* ``nocross``: no crossing layer. With h_A, h_B in their own (third) table's channels, the last layer below the
  harmonic keeps its K-th product (8 fetches: E + 2 maps x 2 layers + 3 tables). Emulated as the unpacked
  harmonic bake (``mixed=False``) whose harmonic layers keep K - 1 products: what that packed layout reads
  (P_1 and the tensor in the harmonic layers, P_1 and P_2 below). Its ``texture_bytes`` holds the tensor in a
  map of its own, so the packed layout's bytes are not this figure (about the mixed bake's plus the crossing
  layer's P_2 block at half face and one more table).
* ``unpacked``: the harmonic layers keep both products and add the tensor in a map of its own (``mixed=False``,
  `balanced+h0.35` of the accuracy benchmark: 10 fetches, the upper bound of what packing the harmonic
  beside K = 2 could read).
* ``screen``: the layers' fit weighting the n.v columns by the screen measure 2 n.v (``build.NV_MEASURE``), the
  benchmark population's density of n.v, instead of uniformly.

    PYTHONPATH=src python benchmarks/bake_mid_variants.py PAIRS_DIR --variant nocross|unpacked|screen --envs forest ... --bands 1 2
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import homofac as hf
from homofac.bake import build
from homofac.bake.plan import BakePlan

from bake_pairs import weighted_nrmse


def no_crossing(self) -> tuple[int, ...]:
    """K - 1 products in the harmonic layers only (:meth:`BakePlan.layer_terms` without the crossing)."""
    h = self.harmonic_layers()
    return tuple(self.terms - 1 if j in h else self.terms for j in range(self.layers))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("pairs")
    ap.add_argument("--variant", choices=("nocross", "unpacked", "screen"), required=True)
    ap.add_argument("--envs", nargs="+", default=["forest", "interior", "studio"])
    ap.add_argument("--bands", nargs="+", type=int, default=[1, 2])
    args = ap.parse_args(argv)
    opts = {}
    if args.variant == "nocross":
        BakePlan.layer_terms = no_crossing
        opts["mixed"] = False
    elif args.variant == "unpacked":
        opts["mixed"] = False
    else:
        build.NV_MEASURE = "screen"
    for name in args.envs:
        t = time.process_time()
        b = hf.bake(name, preset="balanced", **opts)
        row = {"variant": args.variant, "environment": name, "cpu_s": round(time.process_time() - t, 1),
               "bytes": int(b.texture_bytes()), "layer_terms": list(b.plan.layer_terms())}
        for bi in args.bands:
            z = np.load(Path(args.pairs) / f"{name}-{bi}.npz")
            a = np.asarray(b.evaluate(z["n"], z["v"], z["c"], z["m"], z["rho"]), np.float64)
            row[f"band{bi}"] = {"variant": round(weighted_nrmse(a, z["reference"], z["w"]), 4),
                                "balanced": round(weighted_nrmse(z["bake_balanced"], z["reference"], z["w"]), 4),
                                "ideal": round(weighted_nrmse(z["split_sum_ideal"], z["reference"], z["w"]), 4)}
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
