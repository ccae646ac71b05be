"""three.js PMREM beside homofac's drop-in, in the real three.js (headless Chromium), on the bundled
environments: nrmse of each render against the exact lighting of the pinned glTF BRDF at the covered pixels
of the bundled material asset, per roughness band, with texture memory and fetches per pixel. The exact
lighting is the converged reference (:mod:`homofac.light.reference`: MIS, float64, samples doubled until the
image moves by < ``--tolerance``; tests/threejs/scene.py ``exact_lighting``). Writes benchmarks/threejs.json
and docs/benchmarks/threejs.md; ``python benchmarks/pages.py`` also puts the rows into docs/benchmarks/bake.md
as "three.js PMREM". ``--preset fast --json benchmarks/threejs_fast.json`` adds the fast bake's table to both pages.
Each row also has ``seams`` (tests/threejs/scene.py ``seams``): the render's error, against the CPU's
``Bake.evaluate`` and against the exact lighting, at the pixels whose reads lie within a texel of a cube face's
(and atlas block's) edge and on boundaries between texels, beside the interior and the texel centres; and
``layout``, the atlas blocks the page read.

    PYTHONPATH=src python benchmarks/threejs.py [--envs forest city] [--preset balanced] [--size 128]
        [--samples 4096] [--tolerance 0.005] [--save DIR] [--exact-from DIR]

``--exact-from DIR`` reads the exact lighting of an earlier ``--save DIR`` run instead of computing it again, for
each environment whose G-buffer is the same bit for bit (the reference is deterministic); the row's
``reference`` then says ``reused`` and where from.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent / "tests"), str(HERE.parent / "tests" / "threejs")]

import homofac as hf  # noqa: E402
from pages import BANDS, threejs_page, threejs_runs  # noqa: E402
from scene import nrmse, render, seams  # noqa: E402

#: Texture fetches of three's MeshStandardMaterial under PMREM (r187, counted as bake.lookups counts them: a
#: textureLod counts 1): getIBLRadiance one trilinear textureLod of the PMREM cube, getIBLIrradiance one (its
#: roughest level), EnvironmentBRDF one of the 16 x 16 DFG table (envmap_physical_pars_fragment,
#: lights_physical_pars_fragment). r187's PMREM is a cube render target with mips, not the older cube-UV atlas.
PMREM_FETCHES = 3



def saved(folder: str | None, env: str) -> dict | None:
    """A run's pixels saved with ``--save`` (``folder/<env>.npz``; ``reference``: how its exact lighting
    converged), or None when there is none."""
    path = Path(folder or "") / f"{env}.npz"
    if folder is None or not path.is_file():
        return None
    z = np.load(path)
    return {**{k: z[k] for k in z.files if k != "reference"}, "reference": {**json.loads(str(z["reference"])), "from": str(path)}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--envs", nargs="+", default=["forest", "city", "interior", "studio"])
    ap.add_argument("--preset", default="balanced")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--samples", type=int, default=4096, help="first sample count per strategy of the reference")
    ap.add_argument("--tolerance", type=float, default=0.005, help="image nrmse between doublings that ends the reference")
    ap.add_argument("--json", default=str(HERE / "threejs.json"))
    ap.add_argument("--page", default=str(HERE.parent / "docs" / "benchmarks" / "threejs.md"))
    ap.add_argument("--save", help="also write each environment's pixels (renders, G-buffer, exact) to SAVE/<env>.npz")
    ap.add_argument("--exact-from", help="reuse the exact lighting of a run saved with --save (DIR/<env>.npz) where its "
                                         "G-buffer equals this render's (tests/threejs/scene.py known_exact)")
    a = ap.parse_args()
    rows = []
    start = time.time()
    load = os.getloadavg()
    for env in a.envs:
        t = time.perf_counter()
        bake = hf.bake(env, preset=a.preset)
        bake_s = time.perf_counter() - t
        with tempfile.TemporaryDirectory() as work:
            t = time.perf_counter()
            out = render(env, bake, Path(work), a.size, a.samples, a.tolerance, known=saved(a.exact_from, env))
            render_s = time.perf_counter() - t
            seam = seams(out, hf.load(Path(work) / "bake"))  # the bake the page read
        if a.save:
            Path(a.save).mkdir(parents=True, exist_ok=True)
            np.savez(Path(a.save) / f"{env}.npz", reference=json.dumps(out["reference"]),
                     **{k: out[k] for k in ("pmrem", "homofac", "mask", "n", "v", "base", "metallic", "roughness",
                                            "bake", "exact")})
        r = out["roughness"]
        row = {"environment": env, "preset": a.preset, "pixels": int(out["mask"].sum()), "bake_s": round(bake_s, 1),
               "render_and_reference_s": round(render_s, 1), "reference": out["reference"],
               "lookups": {"homofac": bake.lookups, "pmrem": PMREM_FETCHES},
               "texture_bytes": {"homofac": int(bake.texture_bytes()), "homofac_rgba": int(bake.texture_bytes()) * 4 // 3,
                                 "pmrem": out["pmrem_bytes"]},
               "pmrem_cube": {"size": out["pmrem_size"], "levels": out["pmrem_levels"]},
               "nrmse": {k: nrmse(out, k) for k in ("pmrem", "homofac")}, "bands": [], "seams": seam,
               "layout": {"texture_bytes": int(bake.texture_bytes()),
                          "blocks": [list(map(int, atlas.sizes)) for atlas in bake.atlases],
                          "diffuse_size": int(np.shape(bake.E)[0])}}
        for lo, hi in BANDS:
            sel = (r >= lo) & (r < hi)
            if sel.sum():
                row["bands"].append({"roughness": [lo, min(hi, 1.0)], "pixels": int(sel.sum()),
                                     **{k: nrmse(out, k, sel) for k in ("pmrem", "homofac")}})
        rows.append(row)
        print(json.dumps(row))
    doc = {"size": a.size, "reference": "homofac.light.reference (MIS, float64)", "tolerance": a.tolerance,
           "preset": a.preset, "rows": rows, "command": "python benchmarks/threejs.py " + " ".join(sys.argv[1:]),
           "machine": {"date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime(start)), "wall_s": round(time.time() - start, 1),
                       "load_average_before": load[0], "load_average_after": os.getloadavg()[0], "cpus": os.cpu_count()}}
    Path(a.json).write_text(json.dumps(doc, indent=1) + "\n")
    # the default run's page also shows the other presets' runs (benchmarks/threejs_<preset>.json)
    Path(a.page).write_text(threejs_page(*threejs_runs()) if Path(a.json) == HERE / "threejs.json" else threejs_page(doc))


if __name__ == "__main__":
    main()
