"""Scene-aware sampling (issue 15, part 3): the demo scene's image-space error with scene sampling
against texel and random sampling at the same sample count.

The bundled demo scene (a sphere, a torus and a ground plane seen by two 160 x 120 cameras,
``mesh: demo``) covers N pixels. Each case fits the default NR factorization (dual-paraboloid 32,
lsmr) three ways on N training pairs: ``scene`` (every covered pixel once: ``count: 0``), ``random``
(``count: N`` uniform valid pairs) and ``texels`` at the grid size whose pair count is closest to N
(size 12: 25,088 pairs, 5 % more than N); for gold in forest also ``texels`` at the CLI's default size
16 (86,528 pairs, 3.6 N). Every fit is measured on the same scene pixels (``Scene.metrics``: the
factorization against the exact lighting at every covered pixel of both cameras). With ``count: 0``
those pixels are scene sampling's own training pairs, so the benchmark also measures every fit on a
held-out view of the same mesh: the two cameras at twice the resolution (pixel centres the training
never saw) and a third camera from a viewpoint the training did not use (:data:`HELD_OUT`).

    .venv/bin/pytest benchmarks/test_scene.py --benchmark-json=/tmp/scene.json -p no:cacheprovider
    .venv/bin/python benchmarks/report.py /tmp/scene.json

Each record's ``extra_info`` has ``kind: scene``; ``benchmarks/report.py`` writes the table into
docs/benchmarks/scene.md.
"""

from __future__ import annotations

import functools
import time

import pytest

import homofac as hf
from homofac.fit import scene
from scenes import SCENES, machine

CASES = ("gold_forest", "rough_ggx_city")
#: (label, sampling) per row; ``N`` is replaced by the scene's covered pixel count.
SAMPLINGS = {
    "scene": {"kind": "scene", "mesh": "demo", "count": 0},
    "random": {"kind": "random", "count": "N"},
    "texels 12": {"kind": "texels", "size": 12},
    "texels 16 (default)": {"kind": "texels", "size": 16},
}
ROWS = [(c, s) for c in CASES for s in SAMPLINGS if not (s == "texels 16 (default)" and c != "gold_forest")]


#: Held-out views of the demo mesh: its two cameras at 320 x 240, and a third, low viewpoint.
HELD_OUT = [{**c.model_dump(), "width": 320, "height": 240} for c in scene.bundled_cameras("demo")] + [
    {"position": [-2.6, 2.4, 0.9], "look_at": [0.0, 0.0, 0.3], "up": [0.0, 0.0, 1.0], "fov": 45.0,
     "width": 200, "height": 150}]


@functools.lru_cache(maxsize=None)
def held_out() -> scene.Scene:
    return scene.load({"kind": "scene", "mesh": "demo", "cameras": HELD_OUT})


@functools.lru_cache(maxsize=None)
def target(case: str):
    make_brdf, env_name = SCENES[case]
    return hf.light.lighting_target(make_brdf(), hf.light.load_environment(env_name, resolution=16))


@functools.lru_cache(maxsize=None)
def demo() -> scene.Scene:
    return scene.load({"kind": "scene", "mesh": "demo"})


@pytest.mark.parametrize("case, sampling", ROWS)
def test_scene_error(benchmark, case, sampling):
    sc = demo()
    s = {k: (len(sc) if v == "N" else v) for k, v in SAMPLINGS[sampling].items()}
    tgt = target(case)
    t0 = time.perf_counter()
    fac = hf.fit.factorize(tgt, "NR", mapper="dual_paraboloid", texture_size=32,
                           sampling={**s, "validation": 20000, "seed": 0, "cache": False},
                           solver={"method": "lsmr", "tolerance": 1e-6, "max_iterations": 1000, "laplacian": 1.0})
    fit_s = time.perf_counter() - t0
    m = fac.metrics["scene"] if "scene" in fac.metrics else sc.metrics(fac, tgt)
    h = held_out().metrics(fac, tgt)["float"]
    record = {"kind": "scene", "case": case, "sampling": sampling, "pairs": int(fac.counts["train"]),
              "scene_pixels": len(sc), "scene_nrmse": m["float"]["nrmse"], "scene_avg_rel": m["float"]["avg_rel"],
              "scene_nrmse_8bit": m["quantized"]["nrmse"], "own_val_nrmse": fac.metrics["validation"]["float"]["nrmse"],
              "held_out_nrmse": h["nrmse"], "held_out_pixels": len(held_out()),
              "fit_s": fit_s, "sample_s": fac.timings["sample_s"], "machine": machine()}
    benchmark.pedantic(lambda: None, rounds=1, iterations=1)
    benchmark.extra_info.update(record)
    assert 0 < record["scene_nrmse"] < 10
