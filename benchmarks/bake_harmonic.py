"""The bake with and without the second azimuthal harmonic in its rough layers, on the benchmark's pairs.

Bakes ``ENV`` in this process (``hf.bake(ENV, preset=..., harmonic=h)`` for each ``--harmonic`` value; 0 is
today's bake) and scores ``bake.terms`` against the converged reference (8192 samples per strategy, cached in
``--cache``) on the benchmark's pairs and materials (:mod:`bake_breakdown`'s draws, the same as
benchmarks/bake_accuracy.py's), beside the idealized split-sum: nrmse of L and its ratio to the idealized
split-sum, per band; the bake time and texture memory per bake.

    PYTHONPATH=src python benchmarks/bake_harmonic.py studio [--bands 1 2 3] [--presets fast] [--harmonic 0 0.3]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import homofac as hf
from homofac.io.exr import read_exr
from homofac.light.integrals import material_radiance
from homofac.light.reference import reference_integrals, source_map

sys.path.insert(0, str(Path(__file__).parent))
import bake_accuracy as ba  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("env")
    ap.add_argument("--bands", nargs="+", type=int, default=[1, 2, 3])
    ap.add_argument("--presets", nargs="+", default=["fast"])
    ap.add_argument("--harmonic", nargs="+", type=float, default=[0.0, 0.3])
    ap.add_argument("--pairs", type=int, default=150)
    ap.add_argument("--samples", type=int, default=8192)
    ap.add_argument("--cache", default="/tmp/bake_harmonic_ref")
    ap.add_argument("--option", nargs="*", default=[], help="more bake options, key=value (json values)")
    args = ap.parse_args(argv)
    name = args.env
    src = source_map(read_exr(hf.light.bundled(name)), name)
    uniform = source_map(np.ones((8, 16, 3)))
    extra = {k: json.loads(v) for k, v in (o.split("=", 1) for o in args.option)}
    bakes = {}
    for preset in args.presets:
        for h in args.harmonic:
            t = time.perf_counter()
            b = hf.bake(name, preset=preset, harmonic=h, **extra)
            bakes[f"{preset} h{h:g}"] = b
            print(json.dumps({"bake": f"{preset} h{h:g}", "seconds": round(time.perf_counter() - t, 1),
                              "lookups": b.lookups, "texture_bytes": b.texture_bytes(),
                              "harmonic_s": round(b.info["timings"].get("harmonic_s", 0.0), 1)}), flush=True)
    rng = np.random.default_rng(0)
    for _ in range(4 * list(hf.light.BUNDLED).index(name)):  # the benchmark's draws (bake_breakdown's)
        ba.pairs(args.pairs, rng), ba.materials(args.pairs, (0.0, 1.0), rng)
    draws = [(ba.pairs(args.pairs, rng), ba.materials(args.pairs, band, rng)) for band in ba.BANDS]
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    for bi in args.bands:
        (n, v), (c, m, rho) = draws[bi]
        f = cache / f"{name}_{bi}_{args.pairs}_{args.samples}.npz"
        if f.exists():
            z = np.load(f)
            ref, ideal = z["ref"], z["ideal"]
        else:
            ref = np.asarray(reference_integrals(src, n, v, rho, samples=args.samples), np.float64)
            ideal = ba.ideal_split_sum(src, uniform, name, n, v, rho, args.samples)
            np.savez(f, ref=ref, ideal=ideal)
        L = np.asarray(material_radiance(jnp.asarray(ref), c, m))
        err = lambda parts: float(np.linalg.norm(np.asarray(material_radiance(jnp.asarray(parts), c, m)) - L) / np.linalg.norm(L))  # noqa: E731
        row = {"env": name, "band": ba.BANDS[bi], "ideal": round(err(ideal), 4)}
        for label, b in bakes.items():
            e = err(np.asarray(b.terms(n, v, rho), np.float64))
            row[label] = [round(e, 4), round(e / row["ideal"], 2)]
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
