"""``best``'s kept fit sweep by sweep: where does its figure stop moving, on the validation estimate and on the
converged truth? (docs/notes/speed.md, "best, twentieth session")

    python benchmarks/kept_sweeps.py metal/forest "E'+NROW x4+HFT x1" [30] > /tmp/kept_forest.jsonl

The structure is fitted as ``best``'s race and kept fit fit it (the plan's samples, linear options and ALS slots
of its candidates): the race's strided fit (every ``race_stride``-th pair, ``race[-1]`` sweeps), then the fit on
every pair continued from it (``race_continue``), one ALS sweep at a time up to SWEEPS (default: the plan's
``linear.iterations``) or the 1e-3 stop. One JSON line per state (sweep 0: the race fit): the ALS objective, the
validation nrmse with the ridge stratum (``ridge``: the figure every vote of ``best`` reads), the plain validation
nrmse (``val``) and the nrmse against the accuracy benchmark's converged ground truth (``truth``, at most
resolution 256), and the CPU seconds of the sweeps so far (``sweep_cpu``; the figures' own cost excluded).
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
from homofac.fit import plan as fplan  # noqa: E402
from homofac.fit import polish, sums  # noqa: E402
from homofac.fit.draw import draw_samples  # noqa: E402
from homofac.fit.pipeline import drawn_for, resolve_sampling  # noqa: E402
from homofac.fit.structures import Structure  # noqa: E402
from homofac.fit.validation import lighting_at  # noqa: E402
from homofac.light import with_context  # noqa: E402


def main(argv: list[str]) -> int:
    case, label = argv[0], argv[1]
    material, env = case.split("/")
    target = hf.light.lighting_target(acc.MATERIALS[material](), hf.light.load_environment(env, 32))
    the_plan = fplan.build_plan(target, "best")
    opts, mapper, lin = the_plan.options, the_plan.mapper, the_plan.linear
    budget = int(argv[2]) if len(argv) > 2 else int(lin.iterations)
    resolved = resolve_sampling(opts, target.kind, mapper)
    first = drawn_for(the_plan)
    vl = the_plan.validation_light
    vtarget = lighting_at(target, vl.resolution, vl.light_sum) if vl is not None else target
    samples = draw_samples(with_context(target, first), first, resolved, lambda m: None, validation_target=vtarget,
                           validation_light=vl and vl.resolution)
    rv = polish.ridge_validation(vtarget, samples, the_plan.ridge, opts.sampling.seed + 1)
    structure = Structure.parse(label)
    tgt = with_context(target, structure.parametrization)
    size, line = opts.texture_size, the_plan.line_sizes[0]
    slots = sums.als_slots(target, the_plan.candidates, mapper, size, line)
    groups = acc.validation_pairs()
    val = groups.flatten()
    nv = np.sum(val.a * val.b, axis=1)
    gt, _, _ = acc.ground_truth(material, env, groups, log=lambda m: None, limit=256)

    def row(sf: sums.SumFit, sweeps: int, cpu: float, stage: str) -> dict:
        model = sf.model
        approx = np.asarray(model.evaluate(np.asarray(samples.val_a, np.float32),
                                           np.asarray(samples.val_b, np.float32)), np.float64)
        y = np.asarray(samples.val_y, np.float64)
        plain = float(np.sqrt(np.mean((approx - y) ** 2)) / np.sqrt(np.mean(y ** 2)))
        truth = acc.errors(np.asarray(model.evaluate(val.a, val.b), np.float64), gt, nv)["nrmse"]
        return {"case": case, "label": label, "stage": stage, "sweeps": sweeps, "objective": sf.solver.get("objective"),
                "ridge": float(polish.ridge_nrmse(model, samples, rv)), "val": plain, "truth": float(truth),
                "sweep_cpu": cpu}

    k, n = the_plan.race_stride, the_plan.race[-1]
    c0 = time.process_time()
    run = sums.begin(tgt, structure, mapper, size, sums.strided(samples, k), lin.model_copy(update={"iterations": n}),
                     None, line_size=line, slots=slots)
    run = sums.advance(run, n)
    head = sums.finish(run)
    print(json.dumps({**row(head, run.sweeps, time.process_time() - c0, "race"), "ran": run.sweeps}), flush=True)
    c0 = time.process_time()
    full = sums.begin(tgt, structure, mapper, size, samples, lin.model_copy(update={"iterations": budget}), None,
                      previous=head.model, line_size=line, slots=slots)
    cpu = time.process_time() - c0
    print(json.dumps(row(sums.finish(full), 0, cpu, "kept")), flush=True)
    while full.sweeps < budget and not full.converged:
        c0 = time.process_time()
        full = sums.advance(full, 1)
        cpu += time.process_time() - c0
        print(json.dumps({**row(sums.finish(full), full.sweeps, cpu, "kept"), "converged": bool(full.converged)}),
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
