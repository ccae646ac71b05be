"""The presets on the default case, gold under the forest: wall time and error, split-sum beside them.

    python benchmarks/presets.py                               # every preset -> benchmarks/presets.json
    python benchmarks/presets.py --presets fast --json /tmp/p.json   # a subset (the committed file untouched)
    python benchmarks/presets.py --cases metal/forest,plastic/city   # other cases of benchmarks/accuracy.py

Each preset is fitted as a user would fit it: ``hf.fit.factorize(target, preset=NAME)`` on the
environment at its default light resolution (32) with the default texture size (32), in a fresh
process per row with no persistent compilation cache and an empty sample cache (so each row pays its
own JAX compilation and lighting integrals, as a user's first run does). ``wall_s`` is the whole call,
``cpu_s`` its CPU time (both cores). Errors are on the accuracy
benchmark's 20000 validation pairs against its converged ground truth (:func:`accuracy.ground_truth`):
``nrmse`` beside split-sum's (``ratio``), and the fit's own validation nrmse (``fit_validation``).

The machine is shared: wall times move by tens of percent with the load (``load`` records the 1-minute
load average before and after each row).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import accuracy as acc  # noqa: E402

import homofac as hf  # noqa: E402

PRESETS = ("fast", "balanced", "best")


def _polish_note(selection: dict | None) -> dict | None:
    """The polish vote's figures and whether it was kept (``selection.polish`` without its stages)."""
    pol = (selection or {}).get("polish")
    return None if pol is None else {k: v for k, v in pol.items() if k not in ("stages", "trial")}


def one(material: str, env: str, method: str, resolution: int, truth_limit: int = 512) -> dict:
    """One row: fit ``method`` (a preset name or ``split_sum``) and measure it."""
    t0, c0 = time.perf_counter(), time.process_time()
    target = hf.light.lighting_target(acc.MATERIALS[material](), hf.light.load_environment(env, resolution))
    if method == "split_sum":
        fac = hf.fit.factorize(target, "split_sum")
    else:
        fac = hf.fit.factorize(target, preset=method)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    groups = acc.validation_pairs()
    val = groups.flatten()
    nv = np.sum(val.a * val.b, axis=1)
    gt, r_gt, change = acc.ground_truth(material, env, groups, log=lambda m: None, limit=truth_limit)
    approx = np.asarray(fac.evaluate(val.a, val.b), np.float64)
    err = acc.errors(approx, gt, nv)
    return {"material": material, "environment": env, "method": method, "wall_s": wall, "cpu_s": cpu,
            "lookups": int(fac.model.lookups), "structure": fac.parametrization,
            "tried": len((fac.selection or {}).get("tried", [])),
            "screen": (fac.selection or {}).get("screen"), "polish": _polish_note(fac.selection),
            "nrmse": err["nrmse"], "nrmse_grazing": err["nrmse_grazing"], "nrmse_frontal": err["nrmse_frontal"],
            "fit_validation": float(fac.metrics["validation"]["float"]["nrmse"]),
            "ground_truth_resolution": r_gt, "ground_truth_change": change, "light_resolution": resolution,
            "timings": {k: float(v) for k, v in (fac.timings or {}).items()}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", default=",".join(PRESETS))
    ap.add_argument("--cases", default="metal/forest")
    ap.add_argument("--resolution", type=int, default=32, help="light resolution of the fitted environment")
    ap.add_argument("--json", default=str(HERE / "presets.json"))
    ap.add_argument("--truth-limit", type=int, default=512,
                    help="highest light resolution of the ground truth (its last doubling's change is recorded)")
    ap.add_argument("--one", help=argparse.SUPPRESS)  # material/env/method: one row in this process
    args = ap.parse_args(argv)
    if args.one:
        material, env, method = args.one.split("/")
        print(json.dumps(one(material, env, method, args.resolution, args.truth_limit)))
        return 0
    rows = []
    for case in args.cases.split(","):
        material, env = case.split("/")
        for method in ["split_sum", *[p for p in args.presets.split(",") if p]]:
            before = os.getloadavg()[0]
            with tempfile.TemporaryDirectory(prefix="homofac-presets-") as fresh:  # cold caches: a first run
                child = {**os.environ, "HOMOFAC_JAX_CACHE": "0", "HOMOFAC_CACHE_DIR": fresh}
                child.pop("JAX_COMPILATION_CACHE_DIR", None)
                out = subprocess.run([sys.executable, __file__, "--one", f"{material}/{env}/{method}",
                                      "--resolution", str(args.resolution), "--truth-limit", str(args.truth_limit)],
                                     capture_output=True, text=True, check=True, env=child)
            row = json.loads(out.stdout.strip().splitlines()[-1])
            row["load"] = [before, os.getloadavg()[0]]
            rows.append(row)
            print(f"{case} {method}: {row['wall_s']:.1f} s ({row['cpu_s']:.0f} s CPU), nrmse {row['nrmse']:.4f}, {row['lookups']} lookups, "
                  f"{row['structure']} ({row['tried']} tried), load {before:.1f}", flush=True)
    ss = {(r["material"], r["environment"]): r["nrmse"] for r in rows if r["method"] == "split_sum"}
    for r in rows:
        r["ratio"] = r["nrmse"] / ss[(r["material"], r["environment"])]
    Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
