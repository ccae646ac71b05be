"""How a preset's candidates' validation figures move with the ALS sweeps (the plan's race, docs/notes/speed.md).

    PYTHONPATH=src python benchmarks/race_study.py fast metal/forest,plastic/city --json /tmp/r.json

For each case, every candidate of the preset is started (:func:`homofac.fit.sums.begin`) and swept
(:func:`~homofac.fit.sums.advance`) on the preset's grid pairs to its full budget, its validation nrmse
measured (on the plan's validation lighting, as the votes read it) after each of ``--at`` sweeps, with
the objective after every sweep and the CPU seconds of the start and of each stretch of sweeps. A race
(every candidate k sweeps, the lowest continued) is good where its lowest after k sweeps is the lowest
after all of them, or within a few percent of it; a convergence stop is good where the figure stops
moving before the budget.
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


def study(material: str, env: str, preset: str, resolution: int, at: list[int], overrides: dict) -> list[dict]:
    target = hf.light.lighting_target(acc.MATERIALS[material](), hf.light.load_environment(env, resolution))
    pl = build_plan(target, preset, overrides)
    opts, lin = pl.options, pl.linear
    resolved = pipeline.resolve_sampling(opts, "lighting", pl.mapper)
    first = pipeline.drawn_for(pl)
    vl = pl.validation_light
    vtarget = lighting_at(target, vl.resolution) if vl is not None else target
    smp = draw_samples(with_context(target, first), first, resolved, lambda m: None, validation_target=vtarget,
                       validation_light=vl and vl.resolution)
    slots = sums.als_slots(target, pl.candidates, pl.mapper, opts.texture_size, pl.line_sizes[0])
    rows = []
    for c in pl.candidates:
        tgt = with_context(target, c.parametrization)
        c0 = time.process_time()
        run = sums.begin(tgt, c, pl.mapper, opts.texture_size, smp, lin, line_size=pl.line_sizes[0], slots=slots)
        row = {"material": material, "environment": env, "preset": preset, "label": c.label(),
               "begin_cpu": time.process_time() - c0, "nrmse": {}, "cpu": {}, "measure_cpu": {}}
        for k in [k for k in at if k <= run.budget]:
            c0 = time.process_time()
            run = sums.advance(run, k - run.sweeps)
            row["cpu"][k] = time.process_time() - c0
            c0 = time.process_time()
            sf = sums.finish(run)
            m = measure(Result(sf.model), sums.with_highlight_context(tgt, c), smp, eps=float(opts.solver.epsilon),
                        splits=("validation",), kinds=("float",))
            row["nrmse"][k] = float(m["validation"]["float"]["nrmse"])
            row["measure_cpu"][k] = time.process_time() - c0
        row["objective"] = [float(h) for h in run.hist]
        row["converged"] = bool(run.converged)
        print(json.dumps(row), flush=True)
        rows.append(row)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("preset")
    ap.add_argument("cases")
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--json", required=True)
    ap.add_argument("--at", default=AT, help="sweep counts after which the validation figure is measured")
    ap.add_argument("--overrides", default="{}", help="JSON of factorize keywords replacing the preset's values")
    args = ap.parse_args(argv)
    at = [int(x) for x in args.at.split(",")]
    rows = []
    for case in args.cases.split(","):
        rows += study(*case.split("/"), args.preset, args.resolution, at, json.loads(args.overrides))
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
