"""``balanced``'s race and polish vote on the accuracy benchmark's cases: what predicts the polish's gain.

    HOMOFAC_JAX_CACHE=0 PYTHONPATH=src python benchmarks/balanced_votes.py --cases all \
        > benchmarks/balanced_votes_bal23.jsonl 2> /tmp/votes.log          # one process, every case
    python benchmarks/balanced_votes.py --summary benchmarks/balanced_votes_bal23.jsonl   # the table

Each case (material / environment of benchmarks/accuracy.py) is fitted with ``preset="balanced"`` (light resolution
32) in one process, so the compiled programs are shared and the times are not a user's (benchmarks/presets.py gives
those). A json line per case: the kept structure, the race's rounds (every candidate's validation figure after 4
strided sweeps, those kept after 10), the polish vote (``selection.polish``: the validation nrmse before and after,
kept or not, or not run where the plan's gate said so) with the kept fit's off-grid figures
(:func:`homofac.fit.polish.off_grid_figures`: mean squared residual on the polish's strided grid pairs, on its
off-grid pairs, their ratio, and on the validation pairs). No ground truth: the votes read the fit's own validation
pairs. ``--preset-values``: a variant of the preset (as benchmarks/presets.py's); without a ``polish_gate`` in them
the gate is set to :data:`RECORD_GATE` (the figures computed and recorded, the polish never skipped).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import accuracy as acc  # noqa: E402

import homofac as hf  # noqa: E402


#: The polish gate of a study row: above 0, so that the off-grid figures are computed, and below any ratio.
RECORD_GATE = 1e-9


def run(cases: list[tuple[str, str]], preset_values: dict) -> None:
    """Fit ``balanced`` on each case; a json line per case on stdout, the fits' logs on stderr."""
    preset_values = {"polish_gate": RECORD_GATE, **preset_values}
    if preset_values:
        hf.fit.plan.PRESETS["balanced"] = hf.fit.plan.PRESETS["balanced"]._replace(
            **{k: tuple(v) if isinstance(v, list) else v for k, v in preset_values.items()})
    for material, env in cases:
        t0, c0 = time.perf_counter(), time.process_time()

        def log(msg: str) -> None:
            print(f"{material}/{env} {time.perf_counter() - t0:7.1f} {time.process_time() - c0:7.1f} {msg[:400]}",
                  file=sys.stderr, flush=True)

        target = hf.light.lighting_target(acc.MATERIALS[material](), hf.light.load_environment(env, 32))
        fac = hf.fit.factorize(target, preset="balanced", log=log)
        sel = fac.selection or {}
        print(json.dumps({"material": material, "environment": env, "structure": fac.parametrization,
                          "race": sel.get("race"),
                          "polish": {k: v for k, v in (sel.get("polish") or {}).items() if k != "stages"},
                          "fit_validation": float(fac.metrics["validation"]["float"]["nrmse"]),
                          "cpu_s": time.process_time() - c0, "preset_values": preset_values}), flush=True)


def summary(path: str) -> None:
    """The polish vote against the off-grid figures, and the race's picks, as markdown."""
    rows = [json.loads(line) for line in open(path) if line.strip()]
    print("| case | kept structure | off-grid / grid residual | validation / grid | polish: validation nrmse "
          "before -> after | kept |")
    print("|---|---|---:|---:|---|---|")
    for r in sorted(rows, key=lambda r: r["polish"].get("off_grid", {}).get("ratio", 0.0)):
        p, og = r["polish"], r["polish"].get("off_grid", {})
        vote = (f"{p['validation_nrmse_before']:.4f} -> {p['validation_nrmse_after']:.4f} "
                f"({100 * (p['validation_nrmse_after'] / p['validation_nrmse_before'] - 1):+.2f} %)"
                if "validation_nrmse_before" in p else f"not run ({p.get('rule')})")
        print(f"| {r['material']} / {r['environment']} | `{r['structure']}` | {og.get('ratio', float('nan')):.3f} | "
              f"{og.get('validation', float('nan')) / og.get('grid', float('nan')):.3f} | {vote} | {p.get('kept')} |")
    print()
    print("| case | race after 4 strided sweeps (the lowest first; %: above it) | kept after 10 |")
    print("|---|---|---|")
    for r in rows:
        first = r["race"]["rounds"][0]
        figs = dict(zip(first["labels"], first["validation_nrmse"]))
        low = min(figs.values())
        order = sorted(figs, key=figs.get)
        print(f"| {r['material']} / {r['environment']} | "
              + ", ".join(f"`{label}` {100 * (figs[label] / low - 1):.1f}" for label in order)
              + f" | `{r['race']['kept'][0]}` |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="all", help="material/env,... or all (the accuracy benchmark's 16)")
    ap.add_argument("--preset-values", default="{}")
    ap.add_argument("--summary", help="a jsonl of this script: print its tables instead of fitting")
    args = ap.parse_args()
    if args.summary:
        summary(args.summary)
        return
    cases = ([(m, e) for m in acc.MATERIALS for e in acc.ENVIRONMENTS] if args.cases == "all"
             else [tuple(c.split("/")) for c in args.cases.split(",")])
    run(cases, json.loads(args.preset_values))


if __name__ == "__main__":
    main()
