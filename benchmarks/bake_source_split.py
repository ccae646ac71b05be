"""Each light as one Gaussian or as its core and halo (homofac.bake.sources.core_and_halo) at several SPLIT and CORE,
on saved cells, against their reference, with the bakes' own maps.

The lights are taken as the bake takes them (``build._Lights.take_source`` at the 64 face with the sharp block's
256 lights, up to MAX_SOURCES); their finer texels are recorded, and each light's power is re-shaped: one
Gaussian of all its texels (``one``, the nineteenth session's rule) or two of the same total power split at
1/SPLIT of the brightest texel. Splitting moves nothing in the maps (the same texels leave them), so the maps are
the saved bake's terms minus its own analytic term, and only the analytic term is re-read. Cells: the format of
``bake_source_floor.py --cache DIR`` (NAME-BAND-PAIRS-SAMPLES.npz) or ``bake_accuracy.py --save-pairs DIR``.

    PYTHONPATH=src python benchmarks/bake_source_split.py PAIRS_DIR BAKE_DIR --envs forest city --bands 0 1
        --split 4 6 8 --core 1.15 1.2
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

import homofac as hf
from homofac.bake import build, sources
from homofac.bake.sources import Source, core_and_halo, source_terms

sys.path.insert(0, str(Path(__file__).parent))
from bake_source_aniso import cell  # noqa: E402
from bake_source_floor import radiance  # noqa: E402


def lights_with_texels(name: str) -> list[tuple[Source, np.ndarray, np.ndarray]]:
    """The bake's lights of bundled ``name`` (balanced's 64 face, 256 finer lights): ``(one Gaussian, texel
    directions, texel weights)`` each, as ``take_source`` hands them to :func:`core_and_halo`."""
    seen = []
    original = build.core_and_halo
    build.core_and_halo = lambda source, d, w: (seen.append((source, np.array(d), np.array(w))), (source,))[1]
    try:
        lights = build._Lights(name)
        while len(seen) < sources.MAX_SOURCES and lights.take_source(64, 256)[0]:
            pass
    finally:
        build.core_and_halo = original
    return seen


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("pairs", help="bake_source_floor.py --cache DIR or bake_accuracy.py --save-pairs DIR")
    ap.add_argument("bakes", help="DIR holding NAME-balanced bakes (their maps are read)")
    ap.add_argument("--envs", nargs="+", default=list(hf.light.BUNDLED))
    ap.add_argument("--bands", nargs="+", type=int, default=[0, 1])
    ap.add_argument("--split", nargs="+", type=float, default=[sources.SPLIT])
    ap.add_argument("--core", nargs="+", type=float, default=[sources.CORE])
    args = ap.parse_args(argv)
    built = sources.CORE
    try:
        for name in args.envs:
            found = lights_with_texels(name)
            b = hf.load(Path(args.bakes) / f"{name}-balanced")
            for band in args.bands:
                z = cell(Path(args.pairs), name, band)
                if z is None:
                    continue
                n, v, c, m, rho, w, L = (z[k] for k in ("n", "v", "c", "m", "rho", "w", "L"))
                maps = np.asarray(b.terms(n, v, rho), np.float64) - np.asarray(source_terms(b.sources, n, v, rho), np.float64)
                den = np.sum(w * np.sum(L * L, 1))

                def err(srcs):
                    e = radiance(maps + np.asarray(source_terms(srcs, n, v, rho), np.float64), c, m) - L
                    return round(float(np.sqrt(np.sum(w * np.sum(e * e, 1)) / den)), 4)

                row = {"env": name, "band": band, "pairs": len(w), "lights": len(found)}
                for core in args.core:
                    sources.CORE = core
                    row[f"one CORE {core:g}"] = err([s for s, _, _ in found])
                    for q in args.split:
                        row[f"SPLIT {q:g} CORE {core:g}"] = err([p for s, d, wt in found for p in core_and_halo(s, d, wt, q)])
                sources.CORE = built
                print(json.dumps(row), flush=True)
    finally:
        sources.CORE = built


if __name__ == "__main__":
    main()
