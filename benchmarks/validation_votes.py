"""Do the votes pick better fits when the validation pairs read a converged lighting? (issue 41 item 3)

    python benchmarks/validation_votes.py --cases metal/interior,mirror/studio --preset fast

For each case the preset is fitted twice in one process, the fit's light resolution 32 both times: the
validation pairs read the lighting at 32 (``advanced.validation_light: 32``, what the votes read before) and
the lighting the plan decides (homofac.fit.validation). Each kept fit is scored on the accuracy benchmark's
20000 pairs against the converged ground truth (:func:`accuracy.ground_truth`, up to ``--truth-limit``):
``nrmse``. Printed and written as JSON lines (``--out``): the decided validation lighting, each run's kept
structure, the figures of every candidate the structure vote read, the polish vote and the wall time.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import accuracy as acc  # noqa: E402

import homofac as hf  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="metal/interior")
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--truth-limit", type=int, default=256)
    ap.add_argument("--out", type=Path, default=HERE / "validation_votes.jsonl")
    args = ap.parse_args(argv)
    groups = acc.validation_pairs()
    val = groups.flatten()
    for case in args.cases.split(","):
        material, env = case.split("/")
        target = hf.light.lighting_target(acc.MATERIALS[material](), hf.light.load_environment(env, args.resolution))
        gt, r_gt, _ = acc.ground_truth(material, env, groups, log=print, limit=args.truth_limit)
        for label, advanced in (("fit's lighting", {"validation_light": args.resolution}), ("decided", None)):
            t0 = time.perf_counter()
            fac = hf.fit.factorize(target, preset=args.preset, advanced=advanced, sampling={"cache": False})
            wall = time.perf_counter() - t0
            approx = np.asarray(fac.evaluate(val.a, val.b), np.float64)
            sel = fac.selection
            row = {"material": material, "environment": env, "preset": args.preset, "validation": label,
                   "validation_light": sel.get("validation_light"), "structure": sel["chosen"]["label"],
                   "nrmse": hf.fit.metrics.metrics(approx, gt)["nrmse"], "ground_truth_resolution": r_gt,
                   "fit_validation": float(fac.metrics["validation"]["float"]["nrmse"]),
                   "tried": {t["label"]: t["validation_nrmse"] for t in sel["tried"]},
                   "polish": {k: sel.get("polish", {}).get(k) for k in ("kept", "validation_nrmse_before",
                                                                          "validation_nrmse_after")},
                   "wall_s": wall}
            print(json.dumps(row), flush=True)
            with args.out.open("a") as f:
                f.write(json.dumps(row) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
