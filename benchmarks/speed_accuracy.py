"""The presets' accuracy before and after the speed work (issue 41): new rows beside the old settings'.

    python benchmarks/presets.py --cases metal/forest --presets fast,balanced --truth-limit 256 --json /tmp/a.json
    python benchmarks/speed_accuracy.py /tmp/a.json ...   # -> benchmarks/speed_accuracy.{json,md}

The new rows are benchmarks/presets.py rows (a fresh process per row, no compilation or sample cache).
The old settings' rows are the accuracy benchmark's ``max_lookups 4`` and ``8`` rows
(benchmarks/accuracy.json: the lookup budgets of ``fast`` and ``balanced`` with the settings the presets
had before, fitted then), and, where given with ``--old``, presets.py rows run on the old code. Both are
nrmse on the same 20000 pairs against the converged ground truth (:func:`accuracy.ground_truth`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HERE = Path(__file__).resolve().parent
BUDGET = {"fast": "max_lookups 4", "balanced": "max_lookups 8", "best": "max_lookups 16"}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("new", nargs="+", type=Path, help="presets.py JSON files of the new code")
    ap.add_argument("--old", nargs="*", type=Path, default=[], help="presets.py JSON files of the old code")
    ap.add_argument("--out", type=Path, default=HERE / "speed_accuracy")
    args = ap.parse_args(argv)
    acc = {(r["material"], r["environment"], r["method"]): r for r in json.loads((HERE / "accuracy.json").read_text())}
    new = [r for f in args.new for r in json.loads(f.read_text())]
    old_runs = {(r["material"], r["environment"], r["method"]): r for f in args.old for r in json.loads(f.read_text())}
    rows = []
    for r in new:
        case = (r["material"], r["environment"])
        old = acc.get((*case, BUDGET.get(r["method"], r["method"])))
        run = old_runs.get((*case, r["method"]))
        rows.append({"material": r["material"], "environment": r["environment"], "method": r["method"],
                     "new_nrmse": r["nrmse"], "new_structure": r["structure"], "new_wall_s": r["wall_s"],
                     "new_cpu_s": r.get("cpu_s"), "load": r.get("load"),
                     "ground_truth_resolution": r["ground_truth_resolution"],
                     "old_nrmse": None if old is None else old["nrmse"],
                     "old_structure": None if old is None else old["structure"],
                     "old_fit_s": None if old is None else old["fit_s"],
                     "old_ground_truth_resolution": None if old is None else old["ground_truth_resolution"],
                     "old_run": None if run is None else {k: run[k] for k in ("nrmse", "structure", "wall_s", "cpu_s",
                                                                               "load") if k in run},
                     "change": None if old is None else r["nrmse"] / old["nrmse"] - 1.0})
    args.out.with_suffix(".json").write_text(json.dumps(rows, indent=1) + "\n")
    lines = ["| case | preset | old nrmse (structure) | new nrmse (structure) | change | new wall s (CPU s, load) |",
             "|---|---|---:|---:|---:|---:|"]
    for r in rows:
        old = "" if r["old_nrmse"] is None else f"{r['old_nrmse']:.4f} (`{r['old_structure']}`)"
        ch = "" if r["change"] is None else f"{100 * r['change']:+.1f} %"
        load = "" if not r["load"] else f", load {r['load'][0]:.0f}"
        cpu = "" if r["new_cpu_s"] is None else f"{r['new_cpu_s']:.0f}"
        lines.append(f"| {r['material']} / {r['environment']} | {r['method']} | {old} | {r['new_nrmse']:.4f} "
                     f"(`{r['new_structure']}`) | {ch} | {r['new_wall_s']:.0f} ({cpu}{load}) |")
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
