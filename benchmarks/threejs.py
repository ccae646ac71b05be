"""three.js PMREM beside homofac's drop-in, in the real three.js (headless Chromium), on the bundled
environments: nrmse of each render against the exact lighting of the pinned glTF BRDF at the covered pixels
of the bundled material asset (tests/threejs/scene.py), per roughness band, with texture memory and
fetches per pixel. Writes benchmarks/threejs.json and docs/benchmarks/threejs.md.

    python benchmarks/threejs.py [--envs forest city] [--preset balanced] [--size 128] [--exact 64]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent / "tests"), str(HERE.parent / "tests" / "threejs")]

import homofac as hf  # noqa: E402
from pages import BANDS, threejs_page  # noqa: E402
from scene import nrmse, render  # noqa: E402

#: Texture fetches of three's MeshStandardMaterial under PMREM (r187): getIBLRadiance reads two mips of the
#: cube-UV atlas, getIBLIrradiance two, and the DFG table one.
PMREM_FETCHES = 5



def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--envs", nargs="+", default=["forest", "city", "interior", "studio"])
    ap.add_argument("--preset", default="balanced")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--exact", type=int, default=64, help="light resolution of the exact lighting")
    ap.add_argument("--json", default=str(HERE / "threejs.json"))
    ap.add_argument("--page", default=str(HERE.parent / "docs" / "benchmarks" / "threejs.md"))
    a = ap.parse_args()
    rows = []
    for env in a.envs:
        t = time.perf_counter()
        bake = hf.bake(env, preset=a.preset)
        bake_s = time.perf_counter() - t
        with tempfile.TemporaryDirectory() as work:
            out = render(env, bake, Path(work), a.size, a.exact)
        r = out["roughness"]
        row = {"environment": env, "preset": a.preset, "pixels": int(out["mask"].sum()), "bake_s": round(bake_s, 1),
               "lookups": {"homofac": bake.lookups, "pmrem": PMREM_FETCHES},
               "texture_bytes": {"homofac": int(bake.texture_bytes()), "pmrem": out["pmrem_bytes"]},
               "nrmse": {k: nrmse(out, k) for k in ("pmrem", "homofac")}, "bands": []}
        for lo, hi in BANDS:
            sel = (r >= lo) & (r < hi)
            if sel.sum():
                row["bands"].append({"roughness": [lo, min(hi, 1.0)], "pixels": int(sel.sum()),
                                     **{k: nrmse(out, k, sel) for k in ("pmrem", "homofac")}})
        rows.append(row)
        print(json.dumps(row))
    doc = {"size": a.size, "exact_resolution": a.exact, "preset": a.preset, "rows": rows}
    Path(a.json).write_text(json.dumps(doc, indent=1) + "\n")
    Path(a.page).write_text(threejs_page(doc))


if __name__ == "__main__":
    main()
