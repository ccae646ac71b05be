"""Which threads an XLA compile of the grid's lighting program runs on (per-thread CPU s).

    HOMOFAC_JAX_CACHE=0 PYTHONPATH=src python benchmarks/compile_threads.py   # docs/notes/speed.md, "fast, twenty-second session"
"""
import os, time
import numpy as np
import homofac as hf
from homofac.fit import samples as S
from homofac.fit.draw import draw_pairs
from homofac.fit.options import SamplingOptions
from homofac.fit.plan import FAST_GRID_COUNT
def per_thread():
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            f = open(f"/proc/self/task/{tid}/stat").read().rsplit(")", 1)[1].split()
            out[tid] = (open(f"/proc/self/task/{tid}/comm").read().strip(), (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK"))
        except FileNotFoundError: pass
    return out
brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
fn = hf.light.lighting_target(brdf, hf.light.load_environment("forest", 32)).fn
_, _, grid, _ = draw_pairs("lighting", "NR", SamplingOptions(kind="grid", size=32, count=FAST_GRID_COUNT))
p = S.packed(grid)
n, v = np.asarray(p.normals)[:256], np.asarray(p.views)[:256]
for what, f in (("lower", lambda: S._eval_groups.lower(fn, n, v)),):
    a = per_thread(); c = time.process_time(); low = f(); print(what, f"{time.process_time() - c:.2f} CPU")
a = per_thread(); c = time.process_time(); low.compile(); b = per_thread()
print(f"compile {time.process_time() - c:.2f} s CPU; per thread:")
for tid, (name, t) in b.items():
    d = t - a.get(tid, (name, 0))[1]
    if d > 0.02: print("  ", tid, "main" if int(tid) == os.getpid() else name, f"{d:.2f}")
