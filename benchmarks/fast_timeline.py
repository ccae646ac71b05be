"""Stage timeline of one gold / forest fit from process start: wall and process CPU s at each import and each line
of the fit's log, with the CPU spent byte-compiling modules (``SourceLoader.source_to_code``) and the modules loaded.

    HOMOFAC_JAX_CACHE=0 HOMOFAC_CACHE_DIR=$(mktemp -d) PYTHONPATH=src python benchmarks/fast_timeline.py fast
    HOMOFAC_JAX_CACHE=0 HOMOFAC_CACHE_DIR=$(mktemp -d) PYTHONPATH=src python benchmarks/fast_timeline.py split_sum

(docs/notes/speed.md, "fast, twenty-second session")
"""
import time, sys, os
T0, C0 = time.perf_counter(), time.process_time()
import importlib._bootstrap_external as _be
BC = [0.0, 0]
_orig = _be.SourceLoader.source_to_code
def _s2c(self, data, path, *a, **k):
    c = time.process_time(); r = _orig(self, data, path, *a, **k); BC[0] += time.process_time() - c; BC[1] += 1; return r
_be.SourceLoader.source_to_code = _s2c
def st(msg):
    print(f"{time.perf_counter()-T0:8.2f} {time.process_time()-C0:8.2f} [bc {BC[0]:5.2f} s, {BC[1]:4d} mods, {len(sys.modules)} loaded] {msg}", file=sys.stderr, flush=True)
import numpy as np
st("numpy")
import jax, jax.numpy as jnp
st("jax")
sys.path.insert(0, "benchmarks")
import homofac as hf
st("homofac")
import accuracy as acc
st("accuracy")
method = sys.argv[1] if len(sys.argv) > 1 else "fast"
env = hf.light.load_environment("forest", 32)
st("environment")
target = hf.light.lighting_target(acc.MATERIALS["metal"](), env)
st("target")
if method == "split_sum":
    fac = hf.fit.factorize(target, "split_sum")
else:
    fac = hf.fit.factorize(target, preset=method, log=st)
st("fit done")
