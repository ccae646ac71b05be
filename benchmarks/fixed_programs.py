"""The fixed work's two grouped lighting programs, measured alone: compile and run CPU per block.

    HOMOFAC_JAX_CACHE=0 PYTHONPATH=src python benchmarks/fixed_programs.py   # docs/notes/speed.md
    HOMOFAC_JAX_CACHE=0 PYTHONPATH=src python benchmarks/fixed_programs.py '{"xla_cpu_use_fusion_emitters": false}'

Gold / forest at light resolution 32, the pairs of a ``fast`` fit: the plan's decision (the first
:data:`~homofac.fit.validation.DECISION_NORMALS` normals of the validation pairs, 8 views each), the
training grid (175 000 pairs, packed into rows of 64 views) and the validation pairs (20 000, rows of 8).
Each is evaluated in blocks of :data:`~homofac.fit.samples.BLOCK_ROWS` rows by one compiled program per
row width (:func:`homofac.fit.samples.evaluate_grouped`; the program :func:`homofac.fit.samples._blocks` picks for
the width); printed per set: the width, rows and blocks, the program's compile CPU (``lower().compile()``, nothing
for a width already compiled), the first call after it (a second compile would show here) and one block's run.
An argument (JSON) compiles every program with those XLA compiler options instead (a variant under study).
"""
import json
import sys
import time

import jax.numpy as jnp
import numpy as np

import homofac as hf
from homofac.fit import samples as S
from homofac.fit import validation
from homofac.fit.draw import draw_pairs
from homofac.fit.options import SamplingOptions
from homofac.fit.plan import FAST_GRID_COUNT


def main() -> None:
    options = json.loads(sys.argv[1]) if len(sys.argv) > 1 else None
    brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    fn = hf.light.lighting_target(brdf, hf.light.load_environment("forest", 32)).fn
    decision = validation.decision_pairs(20000, 1)
    _, _, grid, val = draw_pairs("lighting", "NR", SamplingOptions(kind="grid", size=32, count=FAST_GRID_COUNT))
    for name, g in (("decision", decision), (f"grid {FAST_GRID_COUNT}", grid), ("validation 20000", val)):
        p = S.packed(g)
        rows = len(p.normals)
        normals = jnp.asarray(np.asarray(p.normals)[:S.BLOCK_ROWS])
        views = jnp.asarray(np.asarray(p.views)[:S.BLOCK_ROWS])
        program = S._eval_groups_quick if p.views.shape[1] <= S.QUICK_WIDTH else S._eval_groups
        c0, t0 = time.process_time(), time.perf_counter()
        compiled = program.lower(fn, normals, views).compile(**({"compiler_options": options} if options else {}))
        c1, t1 = time.process_time(), time.perf_counter()
        run = compiled if options else program
        run(fn, normals, views).block_until_ready()
        c2 = time.process_time()
        run(fn, normals, views).block_until_ready()
        c3, t3 = time.process_time(), time.perf_counter()
        print(f"{name}: width {p.views.shape[1]}, {rows} rows ({-(-rows // S.BLOCK_ROWS)} blocks), "
              f"{int(p.mask.sum())} pairs: compile {c1 - c0:.2f} s CPU ({t1 - t0:.2f} wall), first call {c2 - c1:.2f} "
              f"s CPU, one block {c3 - c2:.2f} s CPU", flush=True)


if __name__ == "__main__":
    main()
