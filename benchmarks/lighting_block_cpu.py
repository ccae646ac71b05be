"""CPU s of 8 calls of the grid's (256, 64) lighting program and of the (256, 8) one, after a warm call.

    HOMOFAC_JAX_CACHE=0 PYTHONPATH=src python benchmarks/lighting_block_cpu.py   # docs/notes/speed.md, "fast, twenty-second session"
"""
import time, numpy as np
import homofac as hf
from homofac.fit import samples as S
from homofac.fit.draw import draw_pairs
from homofac.fit.options import SamplingOptions
from homofac.fit.plan import FAST_GRID_COUNT
brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
fn = hf.light.lighting_target(brdf, hf.light.load_environment("forest", 32)).fn
print("env arrays:", {k: (type(getattr(fn.env, k)).__name__, getattr(fn.env, k).unsafe_buffer_pointer() % 64) for k in ("directions", "radiance", "solid_angle")})
_, _, grid, val = draw_pairs("lighting", "NR", SamplingOptions(kind="grid", size=32, count=FAST_GRID_COUNT))
out = []
for g in (grid, val):
    p = S.packed(g)
    n, v = np.asarray(p.normals)[:256], np.asarray(p.views)[:256]
    prog = S._eval_groups_quick if v.shape[1] <= S.QUICK_WIDTH else S._eval_groups
    prog(fn, n, v).block_until_ready()
    c = time.process_time()
    for _ in range(8): prog(fn, n, v).block_until_ready()
    out.append(f"width {v.shape[1]}: {(time.process_time() - c) / 8:.3f} s CPU a block")
print("; ".join(out))
