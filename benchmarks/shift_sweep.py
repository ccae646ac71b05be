"""beta of the off-specular reflection r_off (``target.shift``) against the converged ground truth.

One fit per case, method and beta, with the accuracy benchmark's settings (grid ALS, S = 32, light
resolution 32, its 20000 validation pairs and cached ground truth); one JSON line per fit on stdout:
nrmse against the ground truth (total and frontal bin), the fit's own validation nrmse and fit time.

    python benchmarks/shift_sweep.py plastic/interior 0.05,0.1,0.15,0.2,0.3 "E'+ROW+R" >> benchmarks/accuracy_shift.jsonl

docs/notes/sums-research.md#off-specular-products has the table of benchmarks/accuracy_shift.jsonl.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy as A  # noqa: E402 - the benchmark's cases, methods, pairs and ground truth

import homofac as hf  # noqa: E402


def main(case: str, shifts: list[float], methods: list[str]) -> None:
    material, env = case.split("/")
    groups = A.validation_pairs()
    val = groups.flatten()
    nv = np.sum(val.a * val.b, 1)
    gt, _, _ = A.ground_truth(material, env, groups, log=lambda m: None)
    e32 = hf.light.load_environment(env, 32)
    for beta in shifts:
        for m in methods:
            kw = dict(A.METHODS[m])
            p = kw.pop("parametrization")
            sampling = {"validation": 20000, **kw.pop("sampling"), "size": 32, "mapper": "dual_paraboloid"}
            t = hf.light.lighting_target(A.MATERIALS[material](), e32, parametrization=p, shift=beta)
            t0 = time.perf_counter()
            fac = hf.fit.factorize(t, p, texture_size=32, sampling=sampling, **kw)
            e = A.errors(np.asarray(fac.evaluate(val.a, val.b), np.float64), gt, nv)
            print(json.dumps({"case": case, "method": m, "shift": beta, "nrmse": round(e["nrmse"], 4),
                              "frontal": round(e["nrmse_frontal"], 4),
                              "own": round(fac.metrics["validation"]["float"]["nrmse"], 4),
                              "fit_s": round(time.perf_counter() - t0, 1)}), flush=True)


if __name__ == "__main__":
    main(sys.argv[1], [float(x) for x in sys.argv[2].split(",")], sys.argv[3].split(","))
