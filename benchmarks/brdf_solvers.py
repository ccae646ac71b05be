"""The solvers on one BRDF factorization (issue 2's report). python benchmarks/brdf_solvers.py

Cook-Torrance (kd 0.1, ks 1, roughness 0.3, F0 (1.0, 0.78, 0.34)), PQP on parabolic textures of
S = 32, the default texel sampling (24^2 per hemisphere) and 20,000 validation pairs. The samples are
drawn once and shared; each solver runs twice and the second (warm) run's seconds are reported, so
compile time is not counted (it is printed apart as first - warm). Prints one JSON record per solver.
"""

from __future__ import annotations

import json
import sys

import homofac as hf
from homofac.fit import pipeline
from homofac.fit.target import brdf_target


def main(size: int = 32, sampling: int = 24) -> list[dict]:
    brdf = hf.brdf.cook_torrance(kd=0.1, ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    target = brdf_target(brdf)
    samples = pipeline.draw_samples(target, "PQP", {"kind": "texels", "size": sampling, "validation": 20000},
                                    log=lambda m: None)
    out = []
    for method in ("direct", "lsmr", "qmr", "cg", "optimistix"):
        runs = []
        for _ in range(2):
            fac = pipeline.factorize(
                target, "PQP", mapper="parabolic", texture_size=size, samples=samples,
                solver={"method": method, "tolerance": 1e-6, "max_iterations": 20000},
            )
            runs.append(fac)
        fac = runs[-1]
        val = fac.metrics["validation"]["float"]
        out.append({
            "method": method, "train_pairs": len(samples.a), "unknowns": fac.counts["unknowns"],
            "val_avg_rel": val["avg_rel"], "val_nrmse": val["nrmse"],
            "train_nrmse": fac.metrics["train"]["float"]["nrmse"],
            "iterations": fac.solver["iterations"], "converged": fac.solver["converged"],
            "objective": fac.solver["objective"], "solve_s": fac.timings["solve_s"],
            "compile_s": runs[0].timings["solve_s"] - fac.timings["solve_s"],
        })
        print(json.dumps(out[-1]), flush=True)
    return out


if __name__ == "__main__":
    main(*[int(a) for a in sys.argv[1:]])
