"""How a preset's candidates' validation figures move with the ALS sweeps (the plan's race, docs/notes/speed.md).

    PYTHONPATH=src python benchmarks/race_study.py fast metal/forest,plastic/city --json /tmp/r.json
    PYTHONPATH=src python benchmarks/race_study.py balanced all --stride 4 --json /tmp/r.json   # the 16 cases
    PYTHONPATH=src python benchmarks/race_study.py balanced metal/forest --continue-from /tmp/r.json --json /tmp/c.json

For each case, every candidate of the preset is started (:func:`homofac.fit.sums.begin`) and swept
(:func:`~homofac.fit.sums.advance`) on the preset's grid pairs to its full budget, its validation nrmse
measured (on the plan's validation lighting, as the votes read it) after each of ``--at`` sweeps, with
the objective after every sweep and the CPU seconds of the start and of each stretch of sweeps. A race
(every candidate k sweeps, the lowest continued) is good where its lowest after k sweeps is the lowest
after all of them, or within a few percent of it; a convergence stop is good where the figure stops
moving before the budget. ``--stride k`` sweeps on every k-th grid pair (the race's first round of ``balanced``
and ``best``, ``race_stride``: short fits of their own); ``all`` as cases: the accuracy benchmark's 16.
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
from homofac.fit import pipeline, sums  # noqa: E402
from homofac.fit.draw import draw_samples  # noqa: E402
from homofac.fit.metrics import measure  # noqa: E402
from homofac.fit.plan import build_plan  # noqa: E402
from homofac.fit.result import Result  # noqa: E402
from homofac.fit.validation import lighting_at  # noqa: E402
from homofac.light import with_context  # noqa: E402

AT = "1,2,3,4,5,6,8,10,12,15,20,25,30"


def _setup(material: str, env: str, preset: str, resolution: int, overrides: dict):
    """The case's target, the preset's plan, its samples (grid and validation pairs, as the pipeline draws
    them) and the ALS slots its candidates share."""
    target = hf.light.lighting_target(acc.MATERIALS[material](), hf.light.load_environment(env, resolution))
    pl = build_plan(target, preset, overrides)
    opts = pl.options
    resolved = pipeline.resolve_sampling(opts, "lighting", pl.mapper)
    first = pipeline.drawn_for(pl)
    vl = pl.validation_light
    vtarget = lighting_at(target, vl.resolution) if vl is not None else target
    smp = draw_samples(with_context(target, first), first, resolved, lambda m: None, validation_target=vtarget,
                       validation_light=vl and vl.resolution)
    slots = sums.als_slots(target, pl.candidates, pl.mapper, opts.texture_size, pl.line_sizes[0])
    return target, pl, smp, slots


def _figure(run: sums.Running, tgt, structure, smp, eps: float) -> float:
    """The validation nrmse (float textures) of a fit under way, as the votes read it."""
    m = measure(Result(sums.finish(run).model), sums.with_highlight_context(tgt, structure), smp, eps=eps,
                splits=("validation",), kinds=("float",))
    return float(m["validation"]["float"]["nrmse"])


def study(material: str, env: str, preset: str, resolution: int, at: list[int], overrides: dict,
          stride: int = 1) -> list[dict]:
    target, pl, smp, slots = _setup(material, env, preset, resolution, overrides)
    opts, lin = pl.options, pl.linear
    fit_smp = sums.strided(smp, stride)
    rows = []
    for c in pl.candidates:
        tgt = with_context(target, c.parametrization)
        c0 = time.process_time()
        run = sums.begin(tgt, c, pl.mapper, opts.texture_size, fit_smp, lin, line_size=pl.line_sizes[0], slots=slots)
        row = {"material": material, "environment": env, "preset": preset, "label": c.label(),
               "stride": int(stride), "begin_cpu": time.process_time() - c0, "nrmse": {}, "cpu": {}, "measure_cpu": {}}
        for k in [k for k in at if k <= run.budget]:
            c0 = time.process_time()
            run = sums.advance(run, k - run.sweeps)
            row["cpu"][k] = time.process_time() - c0
            c0 = time.process_time()
            row["nrmse"][k] = _figure(run, tgt, c, smp, float(opts.solver.epsilon))
            row["measure_cpu"][k] = time.process_time() - c0
        row["objective"] = [float(h) for h in run.hist]
        row["converged"] = bool(run.converged)
        print(json.dumps(row), flush=True)
        rows.append(row)
    return rows


def continued_study(material: str, env: str, preset: str, resolution: int, at: list[int], overrides: dict,
                    label: str) -> dict:
    """The kept fit of ``balanced`` (``race_continue``): candidate ``label``'s short fit (the plan's first
    round: ``race[0]`` sweeps on every ``race_stride``-th pair), then sweeps on every pair from its model to
    the full budget with no convergence stop, the validation nrmse after each of ``at`` and the objective
    after every sweep (where a stop at tolerance t would end: the first sweep lowering it by less than t)."""
    target, pl, smp, slots = _setup(material, env, preset, resolution, overrides)
    opts, lin = pl.options, pl.linear
    c = next(c for c in pl.candidates if c.label() == label)
    tgt = with_context(target, c.parametrization)
    eps = float(opts.solver.epsilon)
    c0 = time.process_time()
    head = sums.fit_sum(tgt, c, pl.mapper, opts.texture_size, sums.strided(smp, pl.race_stride),
                        lin.model_copy(update={"iterations": pl.race[0]}), line_size=pl.line_sizes[0], slots=slots)
    run = sums.begin(tgt, c, pl.mapper, opts.texture_size, smp, lin.model_copy(update={"tolerance": 0.0}),
                     previous=head.model, line_size=pl.line_sizes[0], slots=slots)
    row = {"material": material, "environment": env, "preset": preset, "label": label, "continued": True,
           "head_cpu": time.process_time() - c0, "nrmse": {0: _figure(run, tgt, c, smp, eps)}, "cpu": {}}
    for k in [k for k in at if k <= run.budget]:
        c0 = time.process_time()
        run = sums.advance(run, k - run.sweeps)
        row["cpu"][k] = time.process_time() - c0
        row["nrmse"][k] = _figure(run, tgt, c, smp, eps)
    row["objective"] = [float(h) for h in run.hist]
    print(json.dumps(row), flush=True)
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("preset")
    ap.add_argument("cases")
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--json", required=True)
    ap.add_argument("--at", default=AT, help="sweep counts after which the validation figure is measured")
    ap.add_argument("--overrides", default="{}", help="JSON of factorize keywords replacing the preset's values")
    ap.add_argument("--stride", type=int, default=1, help="sweep on every k-th grid pair (the race's first round)")
    ap.add_argument("--continue-from", default=None,
                    help="a study's JSON (--stride as the race's): each case's lowest candidate after the plan's first "
                         "round continued on every pair (continued_study)")
    args = ap.parse_args(argv)
    at = [int(x) for x in args.at.split(",")]
    rows = []
    cases = ([f"{m}/{e}" for m in acc.MATERIALS for e in acc.ENVIRONMENTS] if args.cases == "all"
             else args.cases.split(","))
    raced = json.loads(Path(args.continue_from).read_text()) if args.continue_from else None
    for case in cases:
        material, env = case.split("/")
        if raced is None:
            rows += study(material, env, args.preset, args.resolution, at, json.loads(args.overrides), args.stride)
        else:
            mine = [r for r in raced if (r["material"], r["environment"]) == (material, env)]
            sweeps = str(build_plan(hf.light.lighting_target(acc.MATERIALS[material](), hf.light.load_environment(
                env, args.resolution)), args.preset, json.loads(args.overrides)).race[0])
            label = min(mine, key=lambda r: r["nrmse"][sweeps])["label"]
            rows.append(continued_study(material, env, args.preset, args.resolution, at, json.loads(args.overrides),
                                        label))
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
