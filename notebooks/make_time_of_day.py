"""Writes notebooks/time_of_day.ipynb (outputs stripped) from the cells below: python notebooks/make_time_of_day.py

The notebook is generated so its source stays reviewable as plain Python; tests/test_notebook.py executes it.
"""

from pathlib import Path

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

CELLS = [
    ("md", """# A day in 24 refits: solve once, reuse the layout

A dynamic scene re-lights its materials every frame; homofac's factorization of the lighting (the
**NR** textures of Latta & Kolb 2002) costs a full run each time the environment changes. But once a
layout is fixed -- parametrization, mappers, sizes, sample directions, Laplacian -- the least-squares
matrix is fixed too: only the right-hand side changes (docs/refit.md). This notebook builds 24
environments of a moving sun from the bundled Preetham 1999 daylight sky, fits one hour fully, and
**refits** every hour on that layout: the validation error and the refit time per hour, two hours
checked against full runs, and the first and last hour rendered beside the exact lighting.

`QUICK` shrinks every size so the test suite can run the notebook in seconds
(`HOMOFAC_NOTEBOOK_QUICK=1`)."""),
    ("code", """import os
import time
import numpy as np
import matplotlib.pyplot as plt
import homofac as hf

QUICK = os.environ.get("HOMOFAC_NOTEBOOK_QUICK") == "1"
LIGHT_RES = 8 if QUICK else 16       # cube face size of the light samples (6 x LIGHT_RES^2 lights)
TEX = 16 if QUICK else 32            # texture size S
SAMPLES = 8 if QUICK else 16         # texel sampling grid per paraboloid half
VALIDATION = 2000 if QUICK else 20000
HOURS = np.arange(24) + 0.5          # solar time, the middle of every hour"""),
    ("md", """## 1. 24 skies of a moving sun

`hf.light.sky.time_of_day` gives one Preetham sky (turbidity 3, a Lambertian ground, the sun's disc
with its exact power) per solar hour on midsummer's day at latitude 45°; every sky lies on the same
cube texels, so only the lights' radiance changes from hour to hour. Below the horizon the sky fades
through a twilight to a night floor."""),
    ("code", """envs = hf.light.sky.time_of_day(HOURS, resolution=LIGHT_RES, latitude=45.0, day=172)
elevation = np.array([90.0 - e.info["sun_zenith_deg"] for e in envs])
print(f"{len(envs)} skies of {envs[0].directions.shape[0]} lights; sun elevation "
      f"{elevation.min():.0f} ... {elevation.max():.0f} degrees; daylight hours "
      f"{int(np.sum(elevation > 0))}")"""),
    ("md", """## 2. One full fit at noon

The usual `hf.fit.factorize`: sampling on reverse-projected texel grids, the log-space least-squares
system with its Laplacian (thesis eq. 37), LSMR. Its result keeps a refit state (`fac.state`): the
layout and the sample directions."""),
    ("code", """brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
KW = dict(mapper="dual_paraboloid", texture_size=TEX,
          sampling={"kind": "texels", "size": SAMPLES, "validation": VALIDATION, "cache": False})
NOON = 12
t0 = time.perf_counter()
fac = hf.fit.factorize(hf.light.lighting_target(brdf, envs[NOON]), "NR", **KW)
full_s = time.perf_counter() - t0
print(f"full fit at {HOURS[NOON]:.1f} h: validation nrmse {fac.metrics['validation']['float']['nrmse']:.4f}, "
      f"{full_s:.2f} s")"""),
    ("md", """## 3. A refit per hour

`hf.fit.refit(fac, environment=...)` keeps the layout: the new lighting values at the stored directions
come from the light transport of the sample directions (built by the first refit, then two matrix
products per environment), the solve from the factored normal equations kept in the state (one
matrix-vector product), the metrics from cached footprints. The first refit is *cold* (it derives all
that and compiles), the others are *warm*."""),
    ("code", """refits, seconds = [], []
for env in envs:
    t0 = time.perf_counter()
    refits.append(hf.fit.refit(fac, environment=env))
    seconds.append(time.perf_counter() - t0)
seconds = np.array(seconds)
nrmse = np.array([r.metrics["validation"]["float"]["nrmse"] for r in refits])
print(f"first refit (cold) {seconds[0]:.3f} s; warm refit median {np.median(seconds[1:]):.3f} s "
      f"(full fit {full_s:.2f} s)")
print(f"validation nrmse per hour {nrmse.min():.4f} ... {nrmse.max():.4f}")"""),
    ("code", """fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 3.4))
day = elevation > 0
ax1.plot(HOURS, nrmse, "o-", ms=4)
ax1.fill_between(HOURS, 0, 1, where=~day, color="0.85", transform=ax1.get_xaxis_transform(), label="sun below horizon")
ax1.set_xlabel("solar hour"); ax1.set_ylabel("validation nrmse"); ax1.set_title("error per hour"); ax1.legend()
ax2.bar(HOURS, seconds * 1000, width=0.8)
ax2.axhline(full_s * 1000, color="C3", ls="--", label=f"full fit {full_s:.1f} s")
ax2.set_yscale("log"); ax2.set_xlabel("solar hour"); ax2.set_ylabel("refit ms (log)")
ax2.set_title("refit time per hour (first one cold)"); ax2.legend()
fig.tight_layout()"""),
    ("md", """## 4. A refit is the full run

The refit solves the same least-squares problem a full run of that hour solves, on the same samples,
so the metrics agree (to the solver's tolerance; docs/refit.md says when a refit is exact)."""),
    ("code", """for h in (6, 18):
    full = hf.fit.factorize(hf.light.lighting_target(brdf, envs[h]), "NR", **KW)
    a, b = refits[h].metrics["validation"]["float"]["nrmse"], full.metrics["validation"]["float"]["nrmse"]
    print(f"hour {HOURS[h]:.1f}: refit nrmse {a:.5f}, full run nrmse {b:.5f}, relative difference {abs(a - b) / b:.2e}")"""),
    ("md", """## 5. Sunrise and sunset: render beside the exact lighting

`hf.gl.preview` renders the refitted textures of the first and the last hour of daylight with the
exported shader beside the exact lighting of the same pixels and the relative error (it needs an
OpenGL context, headless EGL; without one it says so); the exposure is picked per picture."""),
    ("code", """for h in (int(np.argmax(day)), len(HOURS) - 1 - int(np.argmax(day[::-1]))):
    try:
        img, pdata = hf.gl.preview(refits[h], hf.light.lighting_target(brdf, envs[h]), size=96 if QUICK else 192,
                                   return_data=True)
        plt.figure(figsize=(10, 3.4)); plt.imshow(img); plt.axis("off"); plt.title(f"{HOURS[h]:.1f} h")
        print(f"preview {HOURS[h]:.1f} h: pixel nrmse {pdata['nrmse']:.4f}")
    except hf.HomofacError as e:
        print("no preview:", e)"""),
]


def build() -> nbformat.NotebookNode:
    nb = new_notebook()
    nb.cells = [new_markdown_cell(s) if k == "md" else new_code_cell(s) for k, s in CELLS]
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    nb.metadata["language_info"] = {"name": "python"}
    return nb


if __name__ == "__main__":
    path = Path(__file__).with_name("time_of_day.ipynb")
    nbformat.write(build(), path)
    print("wrote", path)
