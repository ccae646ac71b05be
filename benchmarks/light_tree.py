"""The two-level light sum against the full sum: CPU time and the values' error (issue 41 item 4).

    PYTHONPATH=src python benchmarks/light_tree.py --json benchmarks/light_tree.json   # and prints markdown

For each case (the accuracy benchmark's speed cases, lights at the fit's resolution 32):

* the plan's validation-light decision (``homofac.fit.validation.decide``: 2048 pairs at 32, 64, ...) with
  the refined lightings summed over every light (light blocks of 4096) and as the plan says
  (``validation.light_sum``: the light tree where it pays), CPU seconds each, compilation included;
* the fit's 20 000 validation values at the decided resolution R, by every light and as the plan says, CPU seconds (cold: with its
  compilation; warm: a second call) and the tree's nrmse and largest relative error against the full sum;
* with ``--training``: the training-type evaluation (64 views per normal, the 6144 lights at 32) by the full
  sum and by trees of coarse face size 8 and 16, the evidence that the training grid keeps the full sum.

CPU seconds are process time (all threads): the machine is shared, wall time means little.
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
from homofac.fit import sampling, validation  # noqa: E402
from homofac.fit.draw import VALIDATION_VIEWS  # noqa: E402
from homofac.fit.metrics import metrics  # noqa: E402
from homofac.fit.samples import evaluate_blocked, evaluate_grouped  # noqa: E402
from homofac.light.tree import light_tree  # noqa: E402
from homofac.target import Target  # noqa: E402

CASES = "metal/forest,plastic/city,metal/interior,mirror/studio"
COUNT, SEED = 20_000, 1  # the fit's validation pairs: sampling.seed 0 + 1


def _cpu(fn):
    t = time.process_time()
    out = fn()
    return out, time.process_time() - t


def _errors(z, y) -> dict:
    return {"nrmse": float(metrics(z, y)["nrmse"]), "max_rel": float(np.max(np.abs(z - y)) / np.max(np.abs(y)))}


def validation_case(material: str, env_name: str) -> dict:
    env = hf.light.load_environment(env_name, 32)
    target = hf.light.lighting_target(acc.MATERIALS[material](), env)
    rule = validation.light_sum
    validation.light_sum = lambda start, resolution, visible: None  # every light, in blocks
    try:
        before, t_before = _cpu(lambda: validation._decide(target, env, COUNT, SEED, lambda m: None))
    finally:
        validation.light_sum = rule
    after, t_after = _cpu(lambda: validation._decide(target, env, COUNT, SEED, lambda m: None))
    row = {"case": f"{material}/{env_name}", "decision": {
        "full": {"cpu_s": t_before, "resolution": before.resolution, "changes": before.changes},
        "tree": {"cpu_s": t_after, "resolution": after.resolution, "changes": after.changes,
                 "light_sum": after.light_sum}}}
    r = after.resolution
    groups = sampling.grouped_random(COUNT, SEED, views=VALIDATION_VIEWS)
    full_t, tree_t = validation.lighting_at(target, r, None), validation.lighting_at(target, r)
    y, t_full = _cpu(lambda: evaluate_blocked(full_t, groups))
    _, t_full_warm = _cpu(lambda: evaluate_blocked(full_t, groups))
    z, t_tree = _cpu(lambda: evaluate_blocked(tree_t, groups))
    _, t_tree_warm = _cpu(lambda: evaluate_blocked(tree_t, groups))
    row["validation"] = {"resolution": r, "lights": int(full_t.fn.env.num_lights), "pairs": int(len(y)),
                         "light_sum": None if tree_t.fn.tree is None else [tree_t.fn.tree.coarse, tree_t.fn.tree.refine],
                         "full_cpu_s": t_full, "full_warm_cpu_s": t_full_warm,
                         "tree_cpu_s": t_tree, "tree_warm_cpu_s": t_tree_warm, **_errors(z, y)}
    return row


def training_case(material: str, env_name: str, trees: list[tuple[int, int]]) -> dict:
    env = hf.light.load_environment(env_name, 32)
    brdf = acc.MATERIALS[material]()
    groups = sampling.grouped_random(64_000, 7, views=64)
    fn = hf.light.Lighting(brdf, env)
    y, t_cold = _cpu(lambda: np.asarray(evaluate_grouped(Target("lighting", fn, "lighting"), groups), np.float64))
    _, t_warm = _cpu(lambda: evaluate_grouped(Target("lighting", fn, "lighting"), groups))
    rows = [{"case": f"{material}/{env_name}", "sum": "full", "cpu_s": t_cold, "warm_cpu_s": t_warm}]
    for c, k in trees:
        tg = Target("lighting", hf.light.Lighting(brdf, env, tree=light_tree(env, c, k)), "lighting")
        z, t_cold = _cpu(lambda: np.asarray(evaluate_grouped(tg, groups), np.float64))
        _, t_warm = _cpu(lambda: evaluate_grouped(tg, groups))
        rows.append({"case": f"{material}/{env_name}", "sum": f"tree {c} x {k}", "cpu_s": t_cold, "warm_cpu_s": t_warm,
                     **_errors(z, y)})
    return {"training": rows}


def markdown(rows: list[dict]) -> str:
    out = ["| case | R (lights) | decision CPU s: full / tree | validation values CPU s (cold, warm): full / tree "
           "| tree's nrmse | largest relative error |", "|---|---:|---:|---:|---:|---:|"]
    for row in rows:
        if "validation" not in row:
            continue
        d, v = row["decision"], row["validation"]
        out.append(f"| {row['case']} | {v['resolution']} ({v['lights']}) | {d['full']['cpu_s']:.1f} / {d['tree']['cpu_s']:.1f} "
                   f"| {v['full_cpu_s']:.1f}, {v['full_warm_cpu_s']:.1f} / {v['tree_cpu_s']:.1f}, {v['tree_warm_cpu_s']:.1f} "
                   f"| {v['nrmse']:.5f} | {v['max_rel']:.2e} |")
    train = [t for row in rows for t in row.get("training", [])]
    if train:
        out += ["", "| case (64 000 pairs, 64 views a normal, 6144 lights) | sum | CPU s cold | warm | nrmse | largest relative |",
                "|---|---|---:|---:|---:|---:|"]
        out += [f"| {t['case']} | {t['sum']} | {t['cpu_s']:.2f} | {t['warm_cpu_s']:.2f} | {t.get('nrmse', 0):.5f} "
                f"| {t.get('max_rel', 0):.2e} |" for t in train]
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=CASES)
    ap.add_argument("--training", default="", help="cases of the training-type rows (e.g. metal/forest)")
    ap.add_argument("--trees", default="8x32,8x64,16x64")
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    rows = []
    for case in [c for c in args.cases.split(",") if c]:
        rows.append(validation_case(*case.split("/")))
        print(json.dumps(rows[-1]), flush=True)
    trees = [tuple(int(x) for x in t.split("x")) for t in args.trees.split(",")]
    for case in [c for c in args.training.split(",") if c]:
        rows.append(training_case(*case.split("/"), trees))
        print(json.dumps(rows[-1]), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")
    print(markdown(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
