"""Benchmark scenes and quality levels (issue 5), and one measured case as a plain function.

Scenes: Cook-Torrance gold in forest, Phong exponent 400 in studio (the thesis' mirror-like case),
rough GGX in city, Lambert in interior (the bundled CC0 maps). Quality levels: ``preview``,
``default`` (the CLI's default sizes) and ``high`` (the thesis' high-quality run: NRV, 32^2 per
paraboloid half, 24^2 sampling grids per half, 20^2 x 6 lights).

:func:`run_case` measures one (scene, quality, solver): sampling (first call and warm call: their
difference is the compile time), the solve (JAX solvers twice, first and warm), iterations, and the
validation metrics, against the ``direct`` optimum of the same system.
"""

from __future__ import annotations

import functools
import os
import platform
import time

import jax
import numpy as np

import homofac as hf
from baseline_numpy import lighting, numpy_brdf
from homofac.fit import pipeline

SCENES = {
    "gold_forest": (lambda: hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34)),
                    "forest"),
    "phong400_studio": (lambda: hf.brdf.phong(kd=0.05, ks=0.9, exponent=400.0), "studio"),
    "rough_ggx_city": (lambda: hf.brdf.ggx(kd=0.2, ks=0.8, roughness=0.6, f0=(0.04, 0.04, 0.04)), "city"),
    "lambert_interior": (lambda: hf.brdf.lambert(kd=0.8), "interior"),
}
QUALITY = {
    "preview": {"lights": 8, "parametrization": "NR", "texture_size": 16, "sampling": 12, "validation": 5000},
    "default": {"lights": 16, "parametrization": "NR", "texture_size": 32, "sampling": 16, "validation": 20000},
    "high": {"lights": 20, "parametrization": "NRV", "texture_size": 32, "sampling": 24, "validation": 20000},
}
SOLVERS = ("direct", "lsmr", "qmr", "cg", "optimistix")
JAX_SOLVERS = ("lsmr", "optimistix")
#: Iteration cap of the reference solvers (qmr, cg); a run that hits it is reported as not converged.
REFERENCE_MAX_ITERATIONS = 3000


@functools.lru_cache(maxsize=None)
def samples(scene: str, quality: str):
    """(target, samples, timings) of a scene at a quality level; sampled twice (first, warm), cache off."""
    make_brdf, env_name = SCENES[scene]
    q = QUALITY[quality]
    env = hf.light.load_environment(env_name, resolution=q["lights"])
    target = hf.light.lighting_target(make_brdf(), env, parametrization=q["parametrization"])
    cfg = {"kind": "texels", "size": q["sampling"], "validation": q["validation"], "cache": False}
    times = []
    for _ in range(2):
        t0 = time.perf_counter()
        s = pipeline.draw_samples(target, q["parametrization"], cfg, log=lambda m: None)
        times.append(time.perf_counter() - t0)
    return target, s, {"sample_s": times[1], "sample_compile_s": max(0.0, times[0] - times[1]),
                       "lights": int(env.directions.shape[0])}


def _fit(target, s, q, method):
    return pipeline.factorize(
        target, q["parametrization"], mapper="dual_paraboloid", texture_size=q["texture_size"], samples=s,
        solver={"method": method, "tolerance": 1e-6,
                "max_iterations": REFERENCE_MAX_ITERATIONS if method in ("qmr", "cg") else 1000},
    )


@functools.lru_cache(maxsize=None)
def optimum(scene: str, quality: str) -> dict:
    target, s, _ = samples(scene, quality)
    fac = _fit(target, s, QUALITY[quality], "direct")
    return {"objective": fac.solver["objective"], "nrmse": fac.metrics["validation"]["float"]["nrmse"]}


def run_case(scene: str, quality: str, solver: str) -> dict:
    """One measured benchmark record (plain dict, JSON-friendly)."""
    q = QUALITY[quality]
    target, s, st = samples(scene, quality)
    runs = [_fit(target, s, q, solver)]
    if solver in JAX_SOLVERS:
        runs.append(_fit(target, s, q, solver))  # warm
    fac = runs[-1]
    opt = optimum(scene, quality)
    val = fac.metrics["validation"]["float"]
    return {
        "scene": scene, "quality": quality, "solver": solver, "parametrization": q["parametrization"],
        "texture_size": q["texture_size"], "pairs": len(s.a), "lights": st["lights"],
        "unknowns": fac.counts["unknowns"], "sample_s": st["sample_s"], "sample_compile_s": st["sample_compile_s"],
        "solve_s": fac.timings["solve_s"], "assemble_s": fac.timings["assemble_s"],
        "solve_compile_s": max(0.0, runs[0].timings["solve_s"] - fac.timings["solve_s"]) if len(runs) > 1 else 0.0,
        "iterations": fac.solver["iterations"], "converged": bool(fac.solver["converged"]),
        "objective": fac.solver["objective"], "objective_gap": (fac.solver["objective"] - opt["objective"]) / opt["objective"],
        "val_nrmse": val["nrmse"], "val_avg_rel": val["avg_rel"], "direct_val_nrmse": opt["nrmse"],
        "within_1pct_of_direct": bool(val["nrmse"] <= 1.01 * opt["nrmse"]),
        "quantized_val_nrmse": fac.metrics["validation"]["quantized"]["nrmse"],
        "machine": machine(),
    }


@functools.lru_cache(maxsize=1)
def machine() -> str:
    return f"{platform.machine()} {os.cpu_count()} cores, {platform.python_version()}, jax {jax.__version__}, {jax.default_backend()}"


def numpy_baseline(scene: str = "gold_forest", quality: str = "default", slice_pairs: int = 2048) -> dict:
    """The plain NumPy lighting on a slice of the scene's training pairs, extrapolated to all of them."""
    target, s, st = samples(scene, quality)
    env = target.fn.env
    dirs = np.asarray(env.directions, np.float64)
    power = np.asarray(env.radiance * env.solid_angle[:, None], np.float64)
    idx = np.random.default_rng(0).choice(len(s.a), size=min(slice_pairs, len(s.a)), replace=False)
    t0 = time.perf_counter()
    lighting(numpy_brdf(target.fn.brdf), dirs, power, s.a[idx].astype(np.float64), s.b[idx].astype(np.float64))
    numpy_s = (time.perf_counter() - t0) * len(s.a) / len(idx)
    return {"scene": scene, "quality": quality, "pairs": len(s.a), "slice": len(idx), "numpy_s_extrapolated": numpy_s,
            "homofac_train_sample_s": st["sample_s"] * len(s.a) / (len(s.a) + len(s.val_a)),
            "machine": machine()}
