"""Named structures fitted alone as ``best``'s race or full fit would fit them: does a short fit rank them as
their full fits do? (docs/notes/speed.md, "best, seventeenth session")

    python benchmarks/race_sweeps.py metal/forest 75000 10 "E'+NROW x4+HFT x1,E'+ROW x4+R+HFW x2"
    python benchmarks/race_sweeps.py metal/forest 300000 30 "E'+NROW x4+HFT x1"      # a full fit
    python benchmarks/race_sweeps.py plastic/city 300000 30 "E'+ROW x1+R+HFCW x1" '{"nv_balance": 1.0}'

Each structure (``Structure.parse(label).keywords()``) is fitted on COUNT grid pairs (comma-separated: each
count in turn) with SWEEPS ALS sweeps, ``best``'s linear options (``nv_balance`` 0, the stop at 1e-3) and
20 000 validation pairs; one JSON line per fit: its validation nrmse (``val``, the fit's lighting) and its
nrmse against the accuracy benchmark's converged ground truth (``truth_nrmse``, at most resolution 256).
The race's first round fits every 4th of 300 000 pairs (75 000). An optional fifth argument (JSON) replaces
linear options (e.g. ``{"nv_balance": 1.0}``, ``balanced``'s n.v balance).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import accuracy as acc  # noqa: E402

import homofac as hf  # noqa: E402
from homofac.fit.structures import Structure  # noqa: E402


def main(argv: list[str]) -> int:
    case, counts, sweeps, labels = argv[0], argv[1], int(argv[2]), argv[3].split(",")
    linear = {"nv_balance": 0.0, "tolerance": 1e-3, "iterations": sweeps, **(json.loads(argv[4]) if len(argv) > 4 else {})}
    material, env = case.split("/")
    target = hf.light.lighting_target(acc.MATERIALS[material](), hf.light.load_environment(env, 32))
    groups = acc.validation_pairs()
    val = groups.flatten()
    nv = np.sum(val.a * val.b, axis=1)
    gt, _, _ = acc.ground_truth(material, env, groups, log=lambda m: None, limit=256)
    for count in (int(c) for c in counts.split(",")):
        for label in labels:
            kw = Structure.parse(label).keywords()
            kw["advanced"]["linear"] = dict(linear)
            t0, c0 = time.perf_counter(), time.process_time()
            fac = hf.fit.factorize(target, sampling={"count": count, "validation": 20000}, **kw)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            err = acc.errors(np.asarray(fac.evaluate(val.a, val.b), np.float64), gt, nv)
            print(json.dumps({"label": label, "count": count, "sweeps": sweeps, "wall": wall, "cpu": cpu,
                              "truth_nrmse": err["nrmse"], "val": float(fac.metrics["validation"]["float"]["nrmse"]),
                              "iters": fac.solver.get("iterations"), "nv_balance": linear["nv_balance"]}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
