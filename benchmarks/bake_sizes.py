"""Layer face sizes against accuracy: the bake with lobe-sized layers (``homofac.bake.build.layer_size``, texel
about alpha / 2) beside the same bake with each layer at the face an engines' mip chain reads at its roughness
(level 0 at the largest face, levels down to 4, lod = rho (levels - 1); ``bake_accuracy.chain_face``), on
the benchmark's bands against the converged reference (docs/notes/bake.md, "Memory at the same sharpness").

    PYTHONPATH=src python benchmarks/bake_sizes.py [--envs city studio] [--presets fast balanced] [--pairs 150]

The pairs are drawn as benchmarks/bake_accuracy.py draws them, in the order of ``--envs`` (so the first
environment's are the benchmark's when it is city). Prints one line per bake (warm wall time, memory, sizes)
and one per band (nrmse per rule and preset).
"""

from __future__ import annotations

import argparse
import json
import time

import jax.numpy as jnp
import numpy as np

import bake_accuracy as ba
import homofac as hf
from homofac.bake import build
from homofac.io.exr import read_exr
from homofac.light.integrals import material_radiance
from homofac.light.reference import source_map


def chain_layer_size(rho: float, max_size: int) -> int:
    """The engines' chain face at ``rho`` (level 0 ``max_size``), at least the bake's smallest face."""
    return max(build.MIN_SIZE, min(max_size, ba.chain_face(rho, max_size)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--envs", nargs="+", default=["city", "studio"])
    ap.add_argument("--presets", nargs="+", default=["fast", "balanced"])
    ap.add_argument("--pairs", type=int, default=150)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    lobe = build.layer_size
    for name in args.envs:
        src = source_map(read_exr(hf.light.bundled(name)), name)
        bakes = {}
        for rule, fn in (("lobe", lobe), ("chain", chain_layer_size)):
            build.layer_size = fn
            try:
                for p in args.presets:
                    t = time.perf_counter()
                    b = hf.bake(name, preset=p)
                    bakes[(rule, p)] = b
                    print(name, rule, p, f"{time.perf_counter() - t:.1f} s", f"{b.texture_bytes() / 1e6:.3f} MB",
                          [int(x.shape[0]) for x in b.P], flush=True)
            finally:
                build.layer_size = lobe
        for band in ba.BANDS:
            n, v = ba.pairs(args.pairs, rng)
            c, m, rho = ba.materials(args.pairs, band, rng)
            parts, _, _, _ = ba.reference(src, n, v, rho, c, m)
            L = np.asarray(material_radiance(jnp.asarray(parts), c, m))
            out = {f"{r} {p}": round(ba.nrmse(np.asarray(b.evaluate(n, v, c, m, rho)), L), 4) for (r, p), b in bakes.items()}
            print(name, band, json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
