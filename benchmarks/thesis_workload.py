"""The thesis' high-quality lighting run (Latta 2001 §5.7), timed: python benchmarks/thesis_workload.py

NRV, dual-paraboloid textures of 32 per half, sampling grids of 24^2 per half (~400,000 valid (n, v)
pairs), 20^2 x 6 = 2,400 light texels, Cook-Torrance gold in the bundled forest. The thesis took
20 minutes to sample and 15 to solve (1.4 GHz Athlon, 2001). Prints compile (first call minus warm
call) and warm times for sampling and solving.
"""

from __future__ import annotations

import json
import sys
import time

import jax

import homofac as hf
from homofac.fit import pipeline, sampling
from homofac.fit.solvers import solve
from homofac.fit.start import starting_solution
from homofac.fit.system import build_system, make_layout
from homofac.fit.target import evaluate_grouped
from homofac.param import parametrizations as pz


def main(size: int = 24, texture: int = 32, lights: int = 20, param: str = "NRV") -> dict:
    env = hf.light.load_environment("forest", resolution=lights)
    brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    target = hf.light.lighting_target(brdf, env)
    groups = sampling.grouped_pairs("texels", size, mapper="dual_paraboloid")
    pairs = groups.flatten()
    times = {}
    for run in ("first", "warm"):
        t0 = time.perf_counter()
        y = jax.block_until_ready(evaluate_grouped(target, groups))
        times[f"sample_{run}_s"] = time.perf_counter() - t0
    p = pz.get(param)
    layout = make_layout("dual_paraboloid", texture, p.T)
    for run in ("first", "warm"):
        t0 = time.perf_counter()
        sys_, alpha = build_system(p, layout, pairs.a, pairs.b, y, eps=1e-5)
        x0 = starting_solution(sys_, layout, p.J)
        times[f"assemble_{run}_s"] = time.perf_counter() - t0
        res = solve(sys_, x0, method="lsmr", tolerance=1e-6, max_iterations=1000)
        times[f"solve_{run}_s"] = res.seconds
    out = {
        "pairs": len(pairs), "lights": int(env.directions.shape[0]), "unknowns": layout.n_unknowns,
        "iterations": res.iterations, "converged": res.converged, **times,
        "sample_compile_s": times["sample_first_s"] - times["sample_warm_s"],
        "solve_compile_s": times["solve_first_s"] - times["solve_warm_s"],
    }
    return out


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:]]
    print(json.dumps(main(*args), indent=2))
