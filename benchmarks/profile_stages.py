"""Where a preset fit's CPU time goes, by homofac call path: a stack sampler over one fit of gold / forest.

    HOMOFAC_JAX_CACHE=0 PYTHONPATH=src python benchmarks/profile_stages.py fast [DEPTH]   # docs/notes/speed.md

Every 50 ms the main thread's stack is read; the wall and process CPU seconds since the last sample go to
its homofac frames (the DEPTH outermost below ``factorize``, default 5), so compiled programs running on
XLA's threads are counted where the Python code waits for them. Prints the fit's log (wall, CPU s) and
the paths by CPU seconds. The sample cache is off (``sampling.cache: false``): every run draws its pairs.
"""
import collections
import sys
import threading
import time
import traceback

t_import, c_import = time.perf_counter(), time.process_time()
import homofac as hf  # noqa: E402

print(f"import homofac: {time.perf_counter() - t_import:.2f} s wall {time.process_time() - c_import:.2f} s CPU", flush=True)
preset = sys.argv[1] if len(sys.argv) > 1 else "fast"
depth = int(sys.argv[2]) if len(sys.argv) > 2 else 5
main = threading.main_thread().ident
by_path = collections.defaultdict(lambda: [0.0, 0.0])
done = threading.Event()


def sample():
    last_w, last_c = time.perf_counter(), time.process_time()
    while not done.wait(0.05):
        frames = traceback.extract_stack(sys._current_frames()[main])
        w, c = time.perf_counter(), time.process_time()
        ours = [f for f in frames if "/homofac/" in f.filename]
        key = " > ".join(f"{f.filename.split('/homofac/')[1]}:{f.lineno}" for f in ours[1:1 + depth]) or "(outside homofac)"
        by_path[key][0] += w - last_w
        by_path[key][1] += c - last_c
        last_w, last_c = w, c


threading.Thread(target=sample, daemon=True).start()
t0, c0 = time.perf_counter(), time.process_time()


def log(m):
    print(f"{time.perf_counter() - t0:7.2f} {time.process_time() - c0:7.2f} {m}", flush=True)


brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
target = hf.light.lighting_target(brdf, hf.light.load_environment("forest", 32))
log("environment")
fac = hf.fit.factorize(target, preset=preset, log=log, sampling={"cache": False})
log(f"done: {fac.parametrization}, validation nrmse {fac.metrics['validation']['float']['nrmse']:.8f}")
done.set()
print(f"{'wall s':>7} {'CPU s':>7} call path")
for k, (w, c) in sorted(by_path.items(), key=lambda kv: -kv[1][1]):
    if c > 0.1 or w > 0.2:
        print(f"{w:7.2f} {c:7.2f} {k}")
