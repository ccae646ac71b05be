"""How well a short fit ranks a preset's candidates (the plan's screen, docs/notes/speed.md).

    PYTHONPATH=src python benchmarks/screen_study.py balanced metal/forest,plastic/city --json /tmp/s.json

For each case, every candidate of the preset is fitted with each screen variant (ALS sweeps, every
k-th grid pair) and in full (the linear fit's sweeps on every pair), all on the same grid and
validation pairs (the preset's), and its validation nrmse recorded: a screen is good where its lowest
candidate is the full fits' lowest, or within a few percent of it.
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
from homofac.fit import pipeline, sums  # noqa: E402
from homofac.fit.draw import draw_samples  # noqa: E402
from homofac.fit.metrics import measure  # noqa: E402
from homofac.fit.plan import build_plan  # noqa: E402
from homofac.fit.result import Result  # noqa: E402
from homofac.fit.samples import Samples  # noqa: E402
from homofac.light import with_context  # noqa: E402

VARIANTS = "6x1,10x4,0x1"  # sweeps x every k-th pair; 0 sweeps: the full fit


def study(material: str, env: str, preset: str, resolution: int, variants: str = VARIANTS) -> list[dict]:
    target = hf.light.lighting_target(acc.MATERIALS[material](), hf.light.load_environment(env, resolution))
    pl = build_plan(target, preset)
    opts, lin = pl.options, pl.linear
    resolved = pipeline.resolve_sampling(opts, "lighting", pl.mapper)
    first = pipeline.drawn_for(pl)
    smp = draw_samples(with_context(target, first), first, resolved, lambda m: None)
    rows = []
    for c in pl.candidates:
        tgt = with_context(target, c.parametrization)
        row = {"material": material, "environment": env, "preset": preset, "label": c.label()}
        for sweeps, k in (tuple(int(x) for x in v.split("x")) for v in variants.split(",")):
            sub = smp if k == 1 else Samples(smp.a[::k], smp.b[::k], smp.y[::k], smp.val_a, smp.val_b, smp.val_y)
            t0 = time.process_time()
            sf = sums.fit_sum(tgt, c, pl.mapper, opts.texture_size, sub,
                              lin.model_copy(update={"iterations": sweeps or lin.iterations}), line_size=pl.line_sizes[0])
            m = measure(Result(sf.model), tgt, smp, eps=float(opts.solver.epsilon), splits=("validation",),
                        kinds=("float",))
            key = f"{sweeps or lin.iterations}x{k}"
            row[key] = float(m["validation"]["float"]["nrmse"])
            row[key + "_cpu"] = time.process_time() - t0
        print(json.dumps(row), flush=True)
        rows.append(row)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("preset")
    ap.add_argument("cases")
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--json", required=True)
    ap.add_argument("--variants", default=VARIANTS, help="sweeps x every k-th grid pair, comma-separated")
    args = ap.parse_args(argv)
    rows = []
    for case in args.cases.split(","):
        rows += study(*case.split("/"), args.preset, args.resolution, args.variants)
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
