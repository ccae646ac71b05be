"""The disc of a highlight term's light (``advanced.highlights.disc``, projection ``nhs_dom``): its radius against
the error on the sun's grazing ridge and on uniform pairs.

A glossy metal under a synthetic sun (a disc of ``diameter`` degrees over a sky), the highlight structure
of the quality mode at a small scale (``E'+ROW x2+R+HFT x1``, S = 16, 64-texel lines, 100 000 grid pairs,
4 polish steps with 4000 ridge pairs); one fit with the point light (``nh_dom``) and one per radius scale
(the context's ``radius`` = scale x :func:`homofac.light.light_radii`). nrmse against the target lighting
at the fit's light resolution on 4000 ridge pairs (weighted as the uniform pairs they stand for,
:mod:`homofac.fit.ridge`) and on 20 000 uniform pairs; one JSON line per fit on stdout.

    python benchmarks/disc_radius.py 2 64 0.3 0,0.3,1 >> benchmarks/disc_radius.jsonl

docs/notes/sums-research.md, "The sun's disc at grazing views", has the table.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

import homofac as hf
from homofac.fit import ridge
from homofac.target import Target

SUN = np.array([0.5, -0.3, 0.81]) / np.linalg.norm([0.5, -0.3, 0.81])


def main(diameter: float, resolution: int, roughness: float, scales: list[float]) -> None:
    env = hf.light.sun_sky(SUN, sun_radiance=3.0e3, sun_angle_deg=diameter, sky=(0.3, 0.4, 0.6), resolution=resolution)
    brdf = hf.brdf.ggx(kd=0.0, ks=1.0, roughness=roughness, f0=(0.95, 0.93, 0.88))
    target = hf.light.lighting_target(brdf, env, parametrization="RO")
    grid = {"kind": "grid", "size": 16, "mapper": "dual_paraboloid", "count": 100000, "validation": 3000, "cache": False}
    samples = hf.fit.draw_samples(target, "RO", grid)
    light = hf.light.brightest_directions(env, 1)
    measured = float(hf.light.light_radii(env, light)[0])
    rp = ridge.ridge_pairs(light, 4000, seed=0)
    ridge_exact = np.asarray(hf.fit.evaluate(target, rp.a, rp.b), np.float64)
    rng = np.random.default_rng(5)
    n, v = rng.normal(size=(2, 20000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v = np.where(np.sum(n * v, 1, keepdims=True) < 0, -v, v)
    uniform_exact = np.asarray(hf.fit.evaluate(target, n, v), np.float64)
    for scale in scales:
        disc = scale > 0
        t = Target(target.kind, target.fn, target.quantity, {**target.context, "radius": scale * measured}) if disc else target
        t0 = time.perf_counter()
        fac = hf.fit.factorize(t, "RO", texture_size=16, samples=samples, terms=2, diffuse="fitted", nv_factor=True,
                               advanced={"reflection": True, "line_size": 64, "linear": {"polish": 4, "ridge": 4000},
                                         "highlights": {"terms": 1, "fresnel": True, "table": True, "disc": disc}})
        fit_s = time.perf_counter() - t0
        r = np.asarray(fac.model.evaluate(rp.a, rp.b), np.float64)
        u = np.asarray(fac.model.evaluate(n, v), np.float64)
        w = rp.weight[:, None]
        print(json.dumps({"diameter": diameter, "resolution": resolution, "roughness": roughness, "scale": scale,
                          "radius_deg": round(float(np.degrees(np.arcsin(scale * measured))), 3),
                          "ridge": round(float(np.sqrt(np.sum(w * (r - ridge_exact) ** 2) / np.sum(w * ridge_exact ** 2))), 4),
                          "uniform": round(float(np.sqrt(np.mean((u - uniform_exact) ** 2) / np.mean(uniform_exact ** 2))), 4),
                          "own": round(fac.metrics["validation"]["float"]["nrmse"], 4), "fit_s": round(fit_s, 1)}), flush=True)


if __name__ == "__main__":
    main(float(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), [float(x) for x in sys.argv[4].split(",")])
