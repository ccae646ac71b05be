"""Run time against error (issue 5): every scene x quality level x solver, recorded by pytest-benchmark.

Levels from ``HOMOFAC_BENCH_LEVELS`` (default ``preview,default``; add ``high`` for the thesis run),
scenes from ``HOMOFAC_BENCH_SCENES`` (default all), solvers from ``HOMOFAC_BENCH_SOLVERS`` (default all).
Each benchmark's ``extra_info`` holds the record of :func:`scenes.run_case`; ``benchmarks/report.py``
turns the JSON into the table and the Pareto plot.
"""

from __future__ import annotations

import os

import pytest

import scenes

LEVELS = [x for x in os.environ.get("HOMOFAC_BENCH_LEVELS", "preview,default").split(",") if x]
SCENE_NAMES = [x for x in os.environ.get("HOMOFAC_BENCH_SCENES", ",".join(scenes.SCENES)).split(",") if x]
SOLVER_NAMES = [x for x in os.environ.get("HOMOFAC_BENCH_SOLVERS", ",".join(scenes.SOLVERS)).split(",") if x]


@pytest.mark.parametrize("solver", SOLVER_NAMES)
@pytest.mark.parametrize("quality", LEVELS)
@pytest.mark.parametrize("scene", SCENE_NAMES)
def test_factorization(benchmark, scene, quality, solver):
    scenes.samples(scene, quality)  # sample outside the timed call (its times are recorded apart)
    record = {}

    def run():
        record.update(scenes.run_case(scene, quality, solver))

    benchmark.pedantic(run, rounds=1, iterations=1)
    benchmark.extra_info.update(record)
    assert record["val_nrmse"] == record["val_nrmse"]  # finite


@pytest.mark.parametrize("quality", LEVELS)
def test_numpy_baseline(benchmark, quality):
    record = {}
    benchmark.pedantic(lambda: record.update(scenes.numpy_baseline("gold_forest", quality)), rounds=1, iterations=1)
    benchmark.extra_info.update({**record, "solver": "numpy-baseline"})
    assert record["numpy_s_extrapolated"] > 0
