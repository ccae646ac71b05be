"""Writes notebooks/inverse_rendering.ipynb (outputs stripped) from the cells below:
python notebooks/make_inverse_rendering.py (``--run``: execute the cells as a script instead)

The notebook is generated so its source stays reviewable as plain Python; tests/test_inverse.py checks
that the committed notebook matches this generator and executes it (HOMOFAC_NOTEBOOK_QUICK=1).
"""

from pathlib import Path

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

CELLS = [
    ("md", """# Inverse rendering through a differentiable refit

A Cook-Torrance sphere is rendered with the exact lighting (`hf.light.lighting`) under the bundled
forest map at its true roughness and F0. Starting from a wrong guess, we recover both by minimizing
an image loss through the factorized model: every step re-solves the NR factorization
L(v, n) ≈ t1(n) · t2(r) (Latta & Kolb 2002) on a fixed layout in pure JAX
(`homofac.fit.differentiable.refit_model`), renders the sphere through it and compares with the
reference, and `jax.grad` flows back through the solve to the BRDF parameters (docs/differentiable.md).

`QUICK` shrinks every size so the test suite can run the notebook in seconds
(`HOMOFAC_NOTEBOOK_QUICK=1`)."""),
    ("code", """import os
import time
import jax
jax.config.update("jax_enable_x64", True)   # float64: gradients and the optimizer's line search
import jax.numpy as jnp
import numpy as np
import equinox as eqx
import optimistix as optx
import matplotlib.pyplot as plt
import homofac as hf
from homofac.fit import differentiable as dr

QUICK = os.environ.get("HOMOFAC_NOTEBOOK_QUICK") == "1"
LIGHT_RES = 4 if QUICK else 8        # cube face size of the light samples (6 x LIGHT_RES^2 lights)
TEX = 8 if QUICK else 16             # texture size S of the factorization
FIT_PIXELS = 24 if QUICK else 64     # the camera image whose (n, v) pairs the layout is fitted on
IMAGE = 16 if QUICK else 48          # the image the loss compares
MAX_STEPS = 60 if QUICK else 200     # BFGS iterations"""),
    ("md", """## 1. The scene and the reference image

A unit sphere seen by a perspective camera at distance 3 (`sphere_pixels` gives each pixel's normal
and view). The reference is the exact lighting of the true material, the ground truth of every metric."""),
    ("code", """env = hf.light.load_environment("forest", resolution=LIGHT_RES)
env = eqx.tree_at(lambda e: e.radiance, env, jnp.asarray(env.radiance, jnp.float64))
KD = (0.05, 0.04, 0.02)                          # known diffuse colour; ks = 1


def material(roughness, f0):
    return hf.brdf.cook_torrance(kd=KD, ks=1.0, roughness=roughness, f0=f0)


TRUE_ROUGHNESS, TRUE_F0 = 0.3, np.array([0.9, 0.65, 0.3])
truth = material(TRUE_ROUGHNESS, TRUE_F0)
pixels = dr.sphere_pixels(IMAGE, camera="perspective")
reference = dr.render_sphere(lambda n, v: hf.light.lighting(truth, env, n, v), pixels)
print(int(pixels.mask.sum()), "sphere pixels,", env.directions.shape[0], "lights")"""),
    ("md", """## 2. One fit fixes the layout

The layout (NR on dual-paraboloid textures, its Laplacian, its sample pairs) is fitted once, for the
*initial guess*, on the (n, v) pairs a camera image of the sphere shows (`pixel_samples`: sampling
from the scene that will be rendered). Its refit state keeps the system matrix; only the right-hand
side depends on the material."""),
    ("code", """GUESS_ROUGHNESS, GUESS_F0 = 0.6, np.array([0.5, 0.5, 0.5])
guess_target = hf.light.lighting_target(material(GUESS_ROUGHNESS, GUESS_F0), env)
fit_pixels = dr.sphere_pixels(FIT_PIXELS, camera="perspective")
samples = dr.pixel_samples(guess_target, fit_pixels, validation=pixels)
fac = hf.fit.factorize(guess_target, "NR", mapper="dual_paraboloid", texture_size=TEX, samples=samples)
print(f"layout: {len(fac.state.train)} pairs, validation nrmse {fac.metrics['validation']['float']['nrmse']:.4f}")"""),
    ("md", """## 3. The loss and its gradient

Parameters live in an unconstrained vector `x`: roughness = sigmoid(x0), F0 = sigmoid(x1..3). The
residual is the image difference over the sphere's pixels, scaled by the reference's norm."""),
    ("code", """def unpack(x):
    return jax.nn.sigmoid(x[0]), jax.nn.sigmoid(x[1:])


def residuals(x, args=None):
    roughness, f0 = unpack(x)
    model = dr.refit_model(fac, brdf=material(roughness, f0))   # pure-JAX re-solve on the layout
    image = dr.render_sphere(model, pixels)
    m = pixels.mask
    return (image[m] - reference[m]).ravel() / jnp.sqrt(jnp.sum(reference[m] ** 2))


def loss(x, args=None):
    return jnp.sum(residuals(x) ** 2)


x0 = jnp.concatenate([jax.scipy.special.logit(jnp.array([GUESS_ROUGHNESS])), jax.scipy.special.logit(GUESS_F0)])
value_and_grad = jax.jit(jax.value_and_grad(loss))
jax.block_until_ready(value_and_grad(x0))       # compile
t0 = time.perf_counter()
value, grad = jax.block_until_ready(value_and_grad(x0))
grad_s = time.perf_counter() - t0
x_true = jnp.concatenate([jax.scipy.special.logit(jnp.array([TRUE_ROUGHNESS])), jax.scipy.special.logit(TRUE_F0)])
print(f"loss at the guess {float(value):.4g}, at the truth {float(loss(x_true)):.3g}")
print(f"gradient evaluation: {grad_s:.3f} s; gradient {np.asarray(grad)}")"""),
    ("md", """## 4. Minimize

BFGS from optimistix on the loss; each iteration evaluates the loss and its gradient through the
re-solve."""),
    ("code", """t0 = time.perf_counter()
solution = optx.minimise(loss, optx.BFGS(rtol=1e-7, atol=1e-9), x0, max_steps=MAX_STEPS, throw=False)
jax.block_until_ready(solution.value)
fit_s = time.perf_counter() - t0
roughness, f0 = (np.asarray(p) for p in unpack(solution.value))
print(f"inverse fit: {fit_s:.1f} s, {int(solution.stats['num_steps'])} steps, loss {float(loss(solution.value)):.3g}")
print(f"roughness: recovered {float(roughness):.4f}, true {TRUE_ROUGHNESS}, guess {GUESS_ROUGHNESS}")
print(f"F0: recovered {np.round(f0, 4)}, true {TRUE_F0}, guess {GUESS_F0}")
print(f"errors: roughness {abs(float(roughness) - TRUE_ROUGHNESS):.4f}, F0 {np.round(np.abs(f0 - TRUE_F0), 4)}")"""),
    ("md", """## 5. The images

Reference (exact lighting), the initial guess and the recovered material through the factorized
model, tone-mapped the same way."""),
    ("code", """images = {"reference (exact)": reference,
          "guess (factorized)": dr.render_sphere(dr.refit_model(fac, brdf=material(GUESS_ROUGHNESS, GUESS_F0)), pixels),
          "recovered (factorized)": dr.render_sphere(dr.refit_model(fac, brdf=material(roughness, f0)), pixels)}
scale = float(np.max(np.asarray(reference)))
fig, axes = plt.subplots(1, 3, figsize=(12, 4))
for ax, (name, img) in zip(axes, images.items()):
    ax.imshow(np.clip(np.asarray(img) / scale, 0, 1) ** (1 / 2.2))
    ax.set_title(name); ax.axis("off")"""),
]


def build() -> nbformat.NotebookNode:
    nb = new_notebook()
    nb.cells = [new_markdown_cell(s) if k == "md" else new_code_cell(s) for k, s in CELLS]
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    nb.metadata["language_info"] = {"name": "python"}
    return nb


def run() -> None:
    """Executes the code cells in order as a script (the measurement of docs/differentiable.md):
    python notebooks/make_inverse_rendering.py --run (HOMOFAC_NOTEBOOK_QUICK=1 for the small sizes)."""
    import matplotlib

    matplotlib.use("Agg")
    ns: dict = {}
    for kind, src in CELLS:
        if kind == "code":
            exec(compile(src, "inverse_rendering.ipynb", "exec"), ns)


if __name__ == "__main__":
    import sys

    if "--run" in sys.argv[1:]:
        run()
        sys.exit(0)
    path = Path(__file__).with_name("inverse_rendering.ipynb")
    nbformat.write(build(), path)
    print("wrote", path)
