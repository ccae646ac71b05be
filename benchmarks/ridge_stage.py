"""A third polish stage on a saved fit of a preset (default ``best``, "the quality mode"): N more
Levenberg-Marquardt steps with the ridge pairs (the run's own grid, texel and ridge pairs, rebuilt from its
seeds; the grid and ridge counts are the preset's plan's), and the dense nrmse before and after.

    python benchmarks/ridge_stage.py plastic city DIR/plastic_city_max_lookups_16 8 [best]

DIR: the ``--fits`` directory of ``benchmarks/accuracy.py``; the ground truth comes from its cache.
docs/notes/sums-research.md, "Tables of (n.i, n.v) in the fit": plastic / city 0.052 -> 0.049 with 8 steps.
"""
import sys
import time
from pathlib import Path

import numpy as np

import homofac as hf
from homofac.fit import plan, polish, sums
from homofac.fit.options import LinearOptions
from homofac.fit.structures import Structure

sys.path.insert(0, str(Path(__file__).parent))
import accuracy as A  # noqa: E402  (the benchmark's materials, dense pairs and ground-truth cache)

mat, env, d, steps = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
preset = sys.argv[5] if len(sys.argv) > 5 else "best"
fac = hf.load(d)
st = Structure.of(fac.solver["structure"])
tgt = hf.light.lighting_target(A.MATERIALS[mat](), hf.light.load_environment(env, 64), parametrization=st.parametrization)
tgt = sums.with_highlight_context(tgt, st)
tgt = hf.target.Target(tgt.kind, tgt.fn, tgt.quantity, {**tgt.context, **fac.model.context})
the_plan = plan.build_plan(tgt, preset)  # the counts the preset's fit ran with
print(f"preset {preset}: {the_plan.grid_count} grid pairs, {the_plan.ridge} ridge pairs")
cfg = {"kind": "grid", "size": 32, "mapper": "dual_paraboloid", "count": the_plan.grid_count, "validation": 0, "seed": 0, "cache": True}
t0 = time.time()
smp = hf.fit.draw_samples(tgt, st.parametrization, cfg)
lin = LinearOptions(polish=steps, ridge=the_plan.ridge)
pairs = polish.polish_pairs(tgt, st.parametrization, lin, 0, True, print)
print("sampled", time.time() - t0)
sf = sums.SumFit(fac.model, dict(fac.solver), 0.0, 0.0, (), 0)
out = polish.polish_stage(tgt, st, "dual_paraboloid", 32, sf, smp, pairs, lin, print, 0)
dense = A.dense_pairs(); dval = dense.flatten()
dgt, dr, _ = A.ground_truth(mat, env, dense, print)
for name, m in (("saved", fac.model), (f"+{steps} ridge", out.model)):
    e = A.dense_errors(np.asarray(m.evaluate(dval.a, dval.b), np.float64), dgt, dense)
    print(name, round(e["nrmse_dense"], 4), round(e["nrmse_dense_frontal"], 4), [round(x, 3) for x in e["nrmse_dense_parts"]])
print("took", time.time() - t0)
