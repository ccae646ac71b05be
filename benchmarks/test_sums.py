"""Sums of products (issue 13): fit time and validation error of the linear-space fits, and the two
LM backends (optimistix, jaxopt) on the same samples.

Scene: Cook-Torrance gold in the bundled forest at light resolution 32, grid sampling (300k texel-centre
(n, r) pairs of the dual-paraboloid 32 textures), 20000 validation pairs. Each record's ``extra_info``
has ``kind: sums`` and the fit's first (compile included) and warm seconds; ``benchmarks/report.py``
writes the table. The accuracy against a converged ground truth and split-sum is benchmarks/accuracy.py.
"""

from __future__ import annotations

import functools
import importlib.util
import os
import time

import numpy as np
import pytest

import homofac as hf
from scenes import machine
from homofac.fit import sums
from homofac.fit.options import LinearOptions
from homofac.fit.samples import Samples
from homofac.fit.structures import Structure

COUNT = int(os.environ.get("HOMOFAC_BENCH_GRID", 300_000))
CASES = {
    "E+NRW x1 (4)": (Structure("NR", 1, "exact", True), {}),
    "E'+NRW x2+R (8)": (Structure("NR", 2, "fitted", True, reflection=True), {}),
    "E+NRW x4 (13)": (Structure("NR", 4, "exact", True), {}),
    "E+NRW x5 (16)": (Structure("NR", 5, "exact", True), {}),
    "E+NRW x1 LM optimistix": (Structure("NR", 1, "exact", True), {"method": "levenberg_marquardt", "iterations": 20}),
    "E+NRW x1 GN optimistix": (Structure("NR", 1, "exact", True), {"method": "gauss_newton", "iterations": 20}),
    "E+NRW x1 GN optimistix (5k)": (Structure("NR", 1, "exact", True), {"method": "gauss_newton", "iterations": 20}),
    "E+NRW x1 GN jaxopt (5k)": (Structure("NR", 1, "exact", True),
                                {"method": "gauss_newton", "iterations": 20, "backend": "jaxopt"}),
    "E+NRW x1 LM optimistix (5k)": (Structure("NR", 1, "exact", True),
                                    {"method": "levenberg_marquardt", "iterations": 20}),
    "E+NRW x1 LM jaxopt (5k)": (Structure("NR", 1, "exact", True),
                                {"method": "levenberg_marquardt", "iterations": 20, "backend": "jaxopt"}),
}


@functools.lru_cache(maxsize=None)
def scene():
    env = hf.light.load_environment("forest", resolution=32)
    brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    target = hf.light.lighting_target(brdf, env)
    t0 = time.perf_counter()
    s = hf.fit.draw_samples(target, "NR", {"kind": "grid", "size": 32, "mapper": "dual_paraboloid", "count": COUNT,
                                           "validation": 20000, "cache": False})
    return target, s, time.perf_counter() - t0


@pytest.mark.parametrize("case", list(CASES))
def test_sum_fit(benchmark, case):
    structure, lin = CASES[case]
    if lin.get("backend") == "jaxopt" and importlib.util.find_spec("jaxopt") is None:
        pytest.skip("jaxopt (the optional extra) is not installed")
    target, s, sample_s = scene()
    if lin.get("method") in ("levenberg_marquardt", "gauss_newton"):  # the slow general path: a subset
        # jaxopt's LevenbergMarquardt forms diag(J^T J) column by column (unknowns x residuals memory):
        # only a small subset fits, so both backends are compared on 5k pairs as well
        k = 5_000 if "(5k)" in case else 100_000
        s = Samples(s.a[:k], s.b[:k], s.y[:k], s.val_a, s.val_b, s.val_y)
    opts = LinearOptions(**lin)
    times, fit = [], None
    for _ in range(2):  # first (compile included), then warm
        t0 = time.perf_counter()
        fit = sums.fit_sum(target, structure, "dual_paraboloid", 32, s, opts)
        times.append(time.perf_counter() - t0)
    pred = np.asarray(fit.model.evaluate(s.val_a, s.val_b), np.float64)
    nrmse = float(np.mean(np.linalg.norm(pred - s.val_y, axis=0) / np.linalg.norm(s.val_y, axis=0)))
    record = {"kind": "sums", "case": case, "structure": structure.label(), "lookups": fit.model.lookups,
              "method": fit.solver["method"], "backend": fit.solver["backend"], "iterations": fit.solver["iterations"],
              "samples": int(len(s.a)), "sample_s": sample_s, "fit_first_s": times[0], "fit_s": times[1],
              "solve_s": fit.solve_s, "val_nrmse": nrmse, "objective": fit.solver["objective"],
              "machine": machine()}
    benchmark.pedantic(lambda: None, rounds=1, iterations=1)
    benchmark.extra_info.update(record)
    assert np.isfinite(nrmse)
