"""Profile one preset fit on gold / forest: the log's stage timestamps (wall and CPU s) and cProfile's
cumulative top 45.

    PYTHONPATH=src python benchmarks/profile_preset.py fast      # (docs/notes/speed.md)
"""
import sys, time, cProfile, pstats
import homofac as hf
preset = sys.argv[1]
t0 = time.perf_counter()
brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
target = hf.light.lighting_target(brdf, hf.light.load_environment("forest", 32))
c0 = time.process_time()
def log(m): print(f"{time.perf_counter()-t0:7.2f} {time.process_time()-c0:7.2f} {m}", flush=True)  # wall, CPU
pr = cProfile.Profile(); pr.enable()
fac = hf.fit.factorize(target, preset=preset, log=log)
pr.disable()
print("total", time.perf_counter()-t0, fac.parametrization, fac.metrics["validation"]["float"]["nrmse"])
st = pstats.Stats(pr); st.sort_stats("cumulative").print_stats(45)
