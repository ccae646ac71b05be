"""Programs compiled by the fixed work before the grid (gold / forest: the environment, the target, ``build_plan``'s
validation-lighting decision), each op-by-op one with the innermost homofac line that made it.

    HOMOFAC_JAX_CACHE=0 PYTHONPATH=src python benchmarks/fixed_compiles.py   # docs/notes/speed.md, "fast, twenty-second session"
"""
import collections, time, traceback
from jax._src import compiler
import homofac as hf
names = collections.Counter(); cpu = [0.0]
orig = compiler.backend_compile_and_load
def rec(b, m, *a, **k):
    c = time.process_time(); r = orig(b, m, *a, **k); cpu[0] += time.process_time() - c
    n = str(m.operation.attributes["sym_name"]).strip('"'); names[n] += 1
    fr = [f for f in traceback.extract_stack() if "/homofac/" in f.filename]
    if fr and not n.startswith("jit__"): print("  ", n, fr[-1].filename.split("homofac/")[-1], fr[-1].lineno, fr[-1].line)
    return r
compiler.backend_compile_and_load = rec
c0 = time.process_time()
env = hf.light.load_environment("forest", 32)
t = hf.light.lighting_target(hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34)), env)
p = hf.fit.plan.build_plan(t, "fast")
print(f"{sum(names.values())} programs, compile {cpu[0]:.2f} s CPU, stage {time.process_time() - c0:.2f} s CPU")
print(sorted(names.items(), key=lambda x: -x[1]))
print(p.validation_light.describe())
