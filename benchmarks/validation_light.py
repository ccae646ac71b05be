"""How far the fit's own validation figure is from a converged one: the lighting at the fit's light
resolution against the converged ground truth, on the accuracy benchmark's 20000 pairs (issue 41 item 3).

    python benchmarks/validation_light.py --cases metal/forest,plastic/city   # prints a markdown table

The votes read the validation nrmse against the lighting at the fit's own resolution (32). Its own
distance from the converged lighting (the nrmse of the resolution-32 values against the converged ones)
is an error floor the validation pairs cannot see; where it is as large as the candidates' differences,
a vote at resolution 32 cannot rank them as the converged lighting would.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import accuracy as acc  # noqa: E402

import homofac as hf  # noqa: E402
from homofac.fit.samples import evaluate_grouped  # noqa: E402
from homofac.target import Target  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="metal/forest")
    ap.add_argument("--resolutions", default="16,32,64")
    ap.add_argument("--truth-limit", type=int, default=256)
    args = ap.parse_args(argv)
    groups = acc.validation_pairs()
    res = [int(r) for r in args.resolutions.split(",")]
    print("| case | converged at | " + " | ".join(f"nrmse of resolution {r}" for r in res) + " |")
    print("|---|---:|" + "---:|" * len(res))
    for case in args.cases.split(","):
        material, env = case.split("/")
        gt, r_gt, _ = acc.ground_truth(material, env, groups, log=lambda m: None, limit=args.truth_limit)
        cells = []
        for r in res:
            e = hf.light.load_environment(env, r)
            target = Target("lighting", hf.light.Lighting(acc.MATERIALS[material](), e, horizon="centroid"), "lighting")
            y = np.asarray(evaluate_grouped(target, groups), np.float64)
            cells.append(f"{hf.fit.metrics.metrics(y, gt)['nrmse']:.4f}")
        print(f"| {material} / {env} | {r_gt} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
