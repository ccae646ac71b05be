"""The presets on the default case, gold under the forest: wall time and error, split-sum beside them.

    python benchmarks/presets.py                               # every preset -> benchmarks/presets.json
    python benchmarks/presets.py --presets fast --json /tmp/p.json   # a subset (the committed file untouched)
    python benchmarks/presets.py --cases metal/forest,plastic/city   # other cases of benchmarks/accuracy.py
    python benchmarks/presets.py --presets fast --warm               # also a row with a warm compilation cache
    python benchmarks/presets.py --presets fast --no-split-sum --overrides '{"sampling": {"count": 150000}}'
    python benchmarks/presets.py --presets best --no-split-sum --log   # each fit's stage log (wall, CPU s) on stderr
    python benchmarks/presets.py --presets balanced,best --cases plastic/city --dense   # also on the dense pairs
    python benchmarks/presets.py --presets best --preset-values '{"race": [10, 20, 30], "race_keep": [11, 11, 1]}'

Each preset is fitted as a user would fit it: ``hf.fit.factorize(target, preset=NAME)`` on the
environment at its default light resolution (32) with the default texture size (32), in a fresh
process per row with no persistent compilation cache and an empty sample cache (so each row pays its
own JAX compilation and lighting integrals, as a user's first run does). ``wall_s`` is the whole call,
``cpu_s`` its CPU time (both cores). Errors are on the accuracy
benchmark's 20000 validation pairs against its converged ground truth (:func:`accuracy.ground_truth`):
``nrmse`` beside split-sum's (``ratio``), and the fit's own validation nrmse (``fit_validation``). Under a sun
those 20000 pairs (141 normals) see the sun's grazing ridge through a few pairs; ``--dense`` adds the nrmse on the
accuracy benchmark's 270 000 dense pairs of 9000 normals and its three disjoint parts (:func:`accuracy.dense_errors`,
against their own converged ground truth, cached in benchmarks/.cache after the first row).

``--warm`` adds, per preset, the second run of a user who changed the material: a first fit of copper
(same environment, preset and overrides) fills a fresh compilation cache, then the row's material is fitted
with it (``warm: true``; the sample cache is empty for both). ``--overrides`` replaces preset values with
factorize keywords (a variant under study, recorded as ``overrides``); ``--preset-values`` replaces the preset's own
values (:class:`homofac.fit.plan.Preset` fields, lists as tuples: a preset variant under study, recorded as
``preset_values``).

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


#: The material whose fit fills the compilation cache before a ``--warm`` row (another metal than gold).
WARM_FIRST = "copper"
WARM_MATERIALS = {"copper": lambda: hf.brdf.cook_torrance(kd=(0.04, 0.02, 0.01), ks=1.0, roughness=0.3,
                                                          f0=(0.95, 0.64, 0.54))}


def _polish_note(selection: dict | None) -> dict | None:
    """The polish vote's figures and whether it was kept (``selection.polish`` without its stages)."""
    pol = (selection or {}).get("polish")
    return None if pol is None else {k: v for k, v in pol.items() if k not in ("stages", "trial")}


def one(material: str, env: str, method: str, resolution: int, truth_limit: int = 512,
        overrides: dict | None = None, log: bool = False, dense: bool = False, preset_values: dict | None = None) -> dict:
    """One row: fit ``method`` (a preset name or ``split_sum``, with ``overrides``: factorize keywords
    that replace the preset's values) and measure it; with ``log``, the fit's log on stderr, each line
    after the wall and CPU seconds since the row started."""
    if preset_values:  # a variant of the preset under study (this process only)
        hf.fit.plan.PRESETS[method] = hf.fit.plan.PRESETS[method]._replace(
            **{k: tuple(v) if isinstance(v, list) else v for k, v in preset_values.items()})
    t0, c0 = time.perf_counter(), time.process_time()

    def stage(msg: str) -> None:
        print(f"{time.perf_counter() - t0:8.2f} {time.process_time() - c0:8.2f} {msg}", file=sys.stderr, flush=True)

    target = hf.light.lighting_target({**acc.MATERIALS, **WARM_MATERIALS}[material](),
                                      hf.light.load_environment(env, resolution))
    if method == "split_sum":
        fac = hf.fit.factorize(target, "split_sum")
    else:
        fac = hf.fit.factorize(target, preset=method, log=stage if log else None, **(overrides or {}))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    if material in WARM_MATERIALS:  # a warm row's first fit: its time only
        return {"wall_s": wall, "cpu_s": cpu}
    groups = acc.validation_pairs()
    val = groups.flatten()
    nv = np.sum(val.a * val.b, axis=1)
    gt, r_gt, change = acc.ground_truth(material, env, groups, log=lambda m: None, limit=truth_limit)
    approx = np.asarray(fac.evaluate(val.a, val.b), np.float64)
    err = acc.errors(approx, gt, nv)
    more = {}
    if dense:
        groups = acc.dense_pairs()
        flat = groups.flatten()
        dgt, dr, _ = acc.ground_truth(material, env, groups, log=lambda m: None, limit=truth_limit)
        more = {**acc.dense_errors(np.asarray(fac.evaluate(flat.a, flat.b), np.float64), dgt, groups),
                "dense_ground_truth_resolution": dr}
    return {**more, "material": material, "environment": env, "method": method, "wall_s": wall, "cpu_s": cpu,
            "lookups": int(fac.model.lookups), "structure": fac.parametrization,
            "tried": len((fac.selection or {}).get("tried", [])),
            "race": (fac.selection or {}).get("race"), "polish": _polish_note(fac.selection),
            "nrmse": err["nrmse"], "nrmse_grazing": err["nrmse_grazing"], "nrmse_frontal": err["nrmse_frontal"],
            "fit_validation": float(fac.metrics["validation"]["float"]["nrmse"]),
            "ground_truth_resolution": r_gt, "ground_truth_change": change, "light_resolution": resolution,
            "timings": {k: float(v) for k, v in (fac.timings or {}).items()}, "overrides": overrides or {},
            **({"preset_values": preset_values} if preset_values else {})}


def _child(args, material: str, env: str, method: str, fresh: str, cache_dir: str | None, overrides: dict) -> dict:
    """One row in a fresh process: the sample cache in ``fresh`` (empty), the compilation cache in
    ``cache_dir`` (None: none)."""
    child = {**os.environ, "HOMOFAC_CACHE_DIR": fresh}
    child.pop("JAX_COMPILATION_CACHE_DIR", None)
    child["HOMOFAC_JAX_CACHE"] = cache_dir or "0"
    out = subprocess.run([sys.executable, __file__, "--one", f"{material}/{env}/{method}", "--resolution",
                          str(args.resolution), "--truth-limit", str(args.truth_limit), "--overrides",
                          json.dumps(overrides), "--preset-values", args.preset_values] + (["--log"] if args.log else []) + (["--dense"] if args.dense else []),
                         stdout=subprocess.PIPE, stderr=None if args.log else subprocess.PIPE, text=True, check=True,
                         env=child)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _row(material: str, env: str, method: str, args, overrides: dict, warm: bool = False) -> dict:
    """A row as a user's first run (no caches), or with ``warm`` as the second run of a user who changed
    the material: the compilation cache filled by a fit of :data:`WARM_FIRST` (same environment, method
    and overrides), the sample cache empty."""
    with tempfile.TemporaryDirectory(prefix="homofac-presets-") as fresh, \
            tempfile.TemporaryDirectory(prefix="homofac-jax-") as jax_dir:  # cold caches: a first run
        if warm:
            first = _child(args, WARM_FIRST, env, method, fresh + "/first", jax_dir, overrides)
        before = os.getloadavg()[0]
        row = _child(args, material, env, method, fresh, jax_dir if warm else None, overrides)
    row["load"] = [before, os.getloadavg()[0]]
    row["warm"] = warm
    if warm:
        row["warm_first"] = {"material": WARM_FIRST, "wall_s": first["wall_s"], "cpu_s": first["cpu_s"]}
    print(f"{material}/{env} {method}{' (warm)' if warm else ''}: {row['wall_s']:.1f} s ({row['cpu_s']:.0f} s CPU), "
          f"nrmse {row['nrmse']:.4f}, {row['lookups']} lookups, {row['structure']} ({row['tried']} tried), "
          f"load {before:.1f}", flush=True)
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", default=",".join(PRESETS))
    ap.add_argument("--cases", default="metal/forest")
    ap.add_argument("--resolution", type=int, default=32, help="light resolution of the fitted environment")
    ap.add_argument("--json", default=str(HERE / "presets.json"))
    ap.add_argument("--truth-limit", type=int, default=512,
                    help="highest light resolution of the ground truth (its last doubling's change is recorded)")
    ap.add_argument("--overrides", default="{}",
                    help="JSON of factorize keywords replacing the presets' values (a variant under study)")
    ap.add_argument("--no-split-sum", action="store_true", help="no split-sum row (no ratio)")
    ap.add_argument("--warm", action="store_true",
                    help="also a second row per preset with a warm compilation cache: after a first fit of "
                         f"another material ({WARM_FIRST}) under the same environment filled it, as a user who "
                         "changes a material re-runs")
    ap.add_argument("--log", action="store_true", help="each fit's log on stderr (wall and CPU s per stage)")
    ap.add_argument("--dense", action="store_true", help="also the nrmse on the 270 000 dense pairs of 9000 normals")
    ap.add_argument("--preset-values", default="{}",
                    help="JSON replacing the preset's own values (Preset fields; a variant under study)")
    ap.add_argument("--one", help=argparse.SUPPRESS)  # material/env/method: one row in this process
    args = ap.parse_args(argv)
    overrides = json.loads(args.overrides)
    if args.one:
        material, env, method = args.one.split("/")
        print(json.dumps(one(material, env, method, args.resolution, args.truth_limit, overrides, args.log, args.dense,
                             json.loads(args.preset_values))))
        return 0
    rows = []
    for case in args.cases.split(","):
        material, env = case.split("/")
        for method in ([] if args.no_split_sum else ["split_sum"]) + [p for p in args.presets.split(",") if p]:
            row = _row(material, env, method, args, overrides)
            rows.append(row)
            if args.warm and method != "split_sum":
                rows.append(_row(material, env, method, args, overrides, warm=True))
    ss = {(r["material"], r["environment"]): r["nrmse"] for r in rows if r["method"] == "split_sum"}
    for r in rows:
        if (r["material"], r["environment"]) in ss:
            r["ratio"] = r["nrmse"] / ss[(r["material"], r["environment"])]
    Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
