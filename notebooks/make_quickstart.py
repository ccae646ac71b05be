"""Writes notebooks/quickstart.ipynb (outputs stripped) from the cells below: python notebooks/make_quickstart.py

The notebook is generated so its source stays reviewable as plain Python; tests/test_notebook.py executes it.
"""

from pathlib import Path

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

CELLS = [
    ("md", """# homofac quickstart: a material under an environment, in a few textures

This notebook factors the whole lighting of a Cook-Torrance gold material under a real environment
map with the recommended preset, `balanced` (8 texture lookups a pixel), prints split-sum's error
(Karis 2013, what engines ship) beside it, looks at the textures, at an OpenGL render beside the exact
lighting, and at the error metrics. A short BRDF factorization (McCool et al. 2001, PQP) closes it.

`QUICK` shrinks every size so the test suite can run the notebook in seconds
(`HOMOFAC_NOTEBOOK_QUICK=1`)."""),
    ("code", """import os
import numpy as np
import matplotlib.pyplot as plt
import homofac as hf

QUICK = os.environ.get("HOMOFAC_NOTEBOOK_QUICK") == "1"
LIGHT_RES = 8 if QUICK else 32       # cube face size of the light samples (6 x LIGHT_RES^2 lights)
TEX = 16 if QUICK else 32            # texture size S
SAMPLES = 10 if QUICK else 20        # texel sampling grid per paraboloid half
VALIDATION = 2000 if QUICK else 20000"""),
    ("md", """## 1. The environment

`load_environment` reads a lat-long EXR/HDR or a cube map (or a bundled CC0 map by name) and resamples
it to cube-texel lights, preserving the total energy (thesis §5.2). `env.info` reports what happened."""),
    ("code", """env = hf.light.load_environment("forest", resolution=LIGHT_RES)
print(env.directions.shape[0], "lights")
{k: env.info[k] for k in ("source", "energy_before", "energy_after", "negative_pixels") if k in env.info}"""),
    ("md", """## 2. The material and the exact lighting L(v, n)

The lighting computation (thesis eq. 61) sums f(l, v) L_i(l) max(n·l, 0) Δω over every light. It is the
ground truth of every metric and of the preview; `target(n, v)` evaluates it at any pairs."""),
    ("code", """brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
target = hf.light.lighting_target(brdf, env)
n = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], np.float32)
v = np.array([[0.0, 0.6, 0.8], [0.6, 0.0, 0.8]], np.float32)
np.asarray(target(n, v))"""),
    ("md", """## 3. Factor it with a preset, and split-sum beside it

A preset is a lookup budget: `fast` (4 lookups a pixel), `balanced` (8) or `best` (16). homofac fits
the sums of products that fit the budget, `L(v, n) ≈ kd/π E'(n) + Σ p(n) q(r) w(n·v) + ...`, in linear
space and keeps the one with the lowest error on held-out pairs. Split-sum is computed into the same
kind of result, so the two errors compare directly."""),
    ("code", """fac = hf.fit.factorize(target, preset="balanced", texture_size=TEX)
split = hf.fit.factorize(target, "split_sum", texture_size=TEX)
val = fac.metrics["validation"]["float"]
sval = split.metrics["validation"]["float"]
print(f"validation nrmse {val['nrmse']:.4f} (balanced, {fac.model.lookups} lookups, "
      f"{fac.timings['total_s']:.1f} s)")
print(f"split-sum validation nrmse {sval['nrmse']:.4f} ({split.model.lookups} lookups)")"""),
    ("md", """## 4. The textures

Each texture by its name in `factorization.json`: 2D maps of a direction (dual-paraboloid: the front
and back half side by side) and 1D lines (of n·v, or of a light's highlight coordinate), each
tone-mapped to its own maximum for display."""),
    ("code", """cols = min(4, len(fac.textures))
rows = -(-len(fac.textures) // cols)
fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 2.6 * rows), squeeze=False)
for ax in axes.flat:
    ax.axis("off")
for ax, tex, name in zip(axes.flat, fac.textures, fac.texture_names):
    t = np.abs(np.asarray(tex))
    ax.imshow(np.clip(t / max(t.max(), 1e-12), 0, 1) ** (1 / 2.2), aspect="auto")
    ax.set_title(name)"""),
    ("md", """## 5. The preview: OpenGL beside the exact lighting

`hf.gl.preview` renders the textures with the exported shader (`fac.shader("glsl")`, traced from the
same mapper and projection records the solver uses), computes the exact lighting in JAX for the same pixels, and shows the relative
error. It needs an OpenGL context (headless EGL); without one it raises a one-line error."""),
    ("code", """try:
    img, pdata = hf.gl.preview(fac, target, size=96 if QUICK else 256, return_data=True)
    plt.figure(figsize=(12, 4)); plt.imshow(img); plt.axis("off")
    print(f"preview pixels: nrmse {pdata['nrmse']:.4f}")
except hf.HomofacError as e:
    img, pdata = None, None
    print("no preview:", e)"""),
    ("md", """## 6. The metrics, saving and loading

The pinned metric names (docs/format.md) on training and validation pairs, for the float textures and
the 8-bit ones (the thesis' RMS II). `save` writes the pinned output directory atomically; `hf.load`
reads it back and evaluates the factorization at arbitrary pairs."""),
    ("code", """import tempfile
rows = [(split, kind, m["nrmse"], m["avg_rel"], m["max_rel"]) for split in fac.metrics
        for kind, m in fac.metrics[split].items()]
for r in rows:
    print("{:<10} {:<9} nrmse {:.4f}  avg_rel {:.4f}  max_rel {:.3f}".format(*r))
out = tempfile.mkdtemp()
fac.save(out)
loaded = hf.load(out)
again = np.asarray(loaded.evaluate(n, v))
print("reloaded == in memory:", np.allclose(again, np.asarray(fac.evaluate(n, v)), rtol=1e-5))"""),
    ("md", """## 7. A BRDF factorization: f(wi, wo) ≈ p(wi) q(h) p(wo)

McCool et al.'s homomorphic factorization of the BRDF itself (thesis §4.1), on parabolic maps."""),
    ("code", """bfac = hf.fit.factorize(hf.fit.brdf_target(brdf), "PQP", mapper="parabolic", texture_size=TEX,
                        sampling={"kind": "texels", "size": SAMPLES, "validation": VALIDATION})
bval = bfac.metrics["validation"]["float"]
print(f"PQP validation nrmse {bval['nrmse']:.4f}, avg_rel {bval['avg_rel']:.4f}")"""),
]


def build() -> nbformat.NotebookNode:
    nb = new_notebook()
    nb.cells = [new_markdown_cell(s) if k == "md" else new_code_cell(s) for k, s in CELLS]
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    nb.metadata["language_info"] = {"name": "python"}
    return nb


if __name__ == "__main__":
    path = Path(__file__).with_name("quickstart.ipynb")
    nbformat.write(build(), path)
    print("wrote", path)
