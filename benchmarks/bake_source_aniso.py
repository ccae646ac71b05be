"""The analytic source's lobe (homofac.bake.sources: core and tail, widened per axis of the plane of incidence) at
several SPREAD c, on saved cells, against their reference.

The source's extent in half vectors is (c t)^2 / 4 in the plane of incidence and (c t)^2 / (4 (n.v)^2) across it
(dh = dl / 2 in the plane, dl / (2 n.v) across, at the peak); the tail is the anisotropic GGX of those widths
added to alpha^2, the core the source's Gaussian widened by the lobe's 4 alpha^2 in the plane and 4 (n.v)^2
alpha^2 across (module docstring of homofac.bake.sources). Only the source term depends on c (the maps do not),
so each bake is read once per c at the cells' saved pairs:

* ``bake_accuracy.py --save-pairs DIR`` cells (NAME-BAND.npz, converged, ``reference`` the radiance);
* ``bake_source_floor.py --cache DIR`` cells (NAME-BAND-PAIRS-SAMPLES.npz, the first weighted pairs of a cell,
  ``ref`` the reference's (d, A, B)).

    PYTHONPATH=src python benchmarks/bake_source_aniso.py PAIRS_DIR BAKE_DIR --envs city forest --bands 0 1 2
        --spread 0.75 1 1.25 1.5

The previous (isotropic) rule's figures: the same command with PYTHONPATH at an export of commit 93eaded's src.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import homofac as hf
from homofac.bake import sources

from bake_pairs import weighted_nrmse
from bake_source_floor import radiance


def cell(pairs: Path, name: str, band: int) -> dict | None:
    """The saved cell's ``n, v, c, m, rho, w`` and reference radiance ``L`` (either format), or None."""
    f = pairs / f"{name}-{band}.npz"
    if f.exists():
        z = np.load(f)
        return {k: z[k] for k in ("n", "v", "c", "m", "rho", "w")} | {"L": z["reference"]}
    found = sorted(pairs.glob(f"{name}-{band}-*-*.npz"))
    if not found:
        return None
    z = np.load(found[0])
    return {k: z[k] for k in ("n", "v", "c", "m", "rho", "w")} | {"L": radiance(z["ref"], z["c"], z["m"])}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("pairs", help="bake_accuracy.py --save-pairs DIR or bake_source_floor.py --cache DIR")
    ap.add_argument("bakes", help="bake_accuracy.py --bake-dir DIR (NAME-PRESET)")
    ap.add_argument("--envs", nargs="+", default=list(hf.light.BUNDLED))
    ap.add_argument("--bands", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--presets", nargs="+", default=["balanced"])
    ap.add_argument("--spread", nargs="+", type=float, default=[sources.SPREAD], help="SPREAD values c read")
    args = ap.parse_args(argv)
    built = sources.SPREAD
    try:
        for name in args.envs:
            for preset in args.presets:
                b = hf.load(Path(args.bakes) / f"{name}-{preset}")
                for bi in args.bands:
                    z = cell(Path(args.pairs), name, bi)
                    if z is None:
                        continue
                    for c in args.spread:
                        sources.SPREAD = c
                        a = np.asarray(b.evaluate(z["n"], z["v"], z["c"], z["m"], z["rho"]), np.float64)
                        print(json.dumps({"spread": c, "environment": name, "preset": preset, "band": bi,
                                          "pairs": len(a), "nrmse": round(weighted_nrmse(a, z["L"], z["w"]), 4),
                                          "source": bool(b.sources)}), flush=True)
    finally:
        sources.SPREAD = built


if __name__ == "__main__":
    main()
