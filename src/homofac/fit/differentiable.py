"""A pure-JAX factorization, end to end, for gradients; differentiable refits and sphere renders.

:func:`fit_error` maps (target parameters) -> samples -> log system -> LSMR solve (lineax) ->
linear textures -> factorized values -> a pinned metric, with no NumPy in between, so
``jax.grad`` flows from the error back to BRDF parameters and environment pixels. The sample
*directions* are fixed inputs (they do not depend on the parameters); their values are recomputed
from the target inside the function. The solve starts from zero (the §3.1.2 start is a
preconditioning device and does not change the least-squares minimum the gradient is taken at).

:func:`refit_model` is the differentiable counterpart of :func:`homofac.fit.refit` (issue 15, part 4):
it re-solves a product on the layout and sample directions of a fit's refit state
(:class:`~homofac.fit.state.RefitState`) in pure JAX, so an image-space loss of the refitted model
(:func:`sphere_pixels`, :func:`render_sphere`, :func:`image_loss`) has gradients with respect to the
BRDF parameters (roughness, F0, colours) and the environment's pixels. Only the right-hand side of
eq. 37 depends on them; the matrix is the layout's, fixed. Two solves:

* ``method="normal"`` (the default): the gauge-fixed normal equations of the layout, Cholesky-factored
  once in float64 (:func:`homofac.fit.refit.normal_equations`, kept in the state) and applied in JAX
  (``jax.scipy.linalg.cho_solve``): exact, one sparse product and two triangular solves per call, and
  its gradient is the same two solves transposed;
* ``method="lsmr"``: :func:`solve_model` (lineax LSMR from zero, implicit differentiation of the
  solve), for layouts too large to factor densely.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np

from ..errors import HomofacError
from ..factorization import Factorization
from ..param import mappers
from ..param import parametrizations as pz
from ..target import evaluate
from . import precision
from .metrics import metric_arrays
from .product import unpack, zeros_rule
from .refit import CHOLESKY_MAX_UNKNOWNS, layout_of, new_target, normal_equations, system_rows
from .samples import Samples
from .state import RefitState
from .system import apply, augmented_rhs, build_system, log_transform, parametrization_layout


def _model(target, p: pz.Parametrization, layout, x, alpha, dtype) -> Factorization:
    textures = precision.exponentiate(unpack(x, layout), alpha, p.J)
    main = next((t for t in layout.textures if not mappers.get(t.mapper).scalar), layout.textures[0])
    line = next((t.size for t in layout.textures if mappers.get(t.mapper).scalar), None)
    return Factorization.product(target.kind, target.quantity if target.kind == "brdf" else "lighting", p.name,
                                 main.mapper, main.size, textures, jnp.ones((3,), dtype), dict(target.context),
                                 line_size=line)


def solve_model(target, parametrization: str, mapper: str, size: int, a, b, *, y=None, laplacian=1.0, eps=1e-5,
                tolerance=1e-8, max_steps=2000) -> Factorization:
    """The one-term model of a factorization of ``target`` on pairs (a, b), in pure JAX (differentiable).

    ``y``: the target's values at the pairs when computed already (default: ``target(a, b)``).
    """
    p = pz.get(parametrization)
    layout = parametrization_layout(p, mapper, size)
    y = target(a, b) if y is None else y
    sys, alpha = build_system(p, layout, a, b, y, eps=eps, context=target.context)
    lam = jnp.asarray(laplacian, a.dtype)
    x0 = jnp.zeros((layout.n_unknowns, 3), a.dtype)
    op = lx.FunctionLinearOperator(lambda x: apply(sys, lam, x), jax.ShapeDtypeStruct(x0.shape, x0.dtype))
    sol = lx.linear_solve(op, augmented_rhs(sys), lx.LSMR(rtol=tolerance, atol=tolerance, max_steps=max_steps),
                          throw=False)
    return _model(target, p, layout, sol.value, alpha, a.dtype)


def solve_textures(target, parametrization: str, mapper: str, size: int, a, b, **solve_kw):
    """Linear textures and correction (ones) of :func:`solve_model`."""
    model = solve_model(target, parametrization, mapper, size, a, b, **solve_kw)
    return tuple(t.data for t in model.textures), model.terms[0].correction


def fit_error(target, parametrization: str, mapper: str, size: int, a, b, val_a, val_b, *, metric: str = "rms",
              **solve_kw):
    """A pinned metric of the factorization of ``target`` on validation pairs: differentiable."""
    model = solve_model(target, parametrization, mapper, size, a, b, **solve_kw)
    approx = model.evaluate(val_a, val_b)
    exact = target(val_a, val_b)
    return metric_arrays(target.shown(val_a, approx), target.shown(val_a, exact))[metric]


# ------------------------------------------------------------------------------------------------
# differentiable refits


def _float_dtype(dtype):
    return jnp.dtype(dtype) if dtype is not None else jnp.result_type(float)


def state_values(state: RefitState, target, dtype=None):
    """The target's values at the state's training directions, in pure JAX (differentiable): through the
    lighting's per-normal path (:meth:`homofac.light.Lighting.grouped`) when the state groups its pairs
    by normal, else at the flat pairs. Same order as ``state.train``."""
    dtype = _float_dtype(dtype)
    fn = target.fn
    if state.groups is not None and hasattr(fn, "grouped") and not getattr(fn, "culls_lobes", False):
        g = state.groups
        out = fn.grouped(*_opaque(jnp.asarray(g.normals, dtype), jnp.asarray(g.views, dtype)))
        return out[np.asarray(g.mask)]
    return target(*_opaque(jnp.asarray(state.train.a, dtype), jnp.asarray(state.train.b, dtype)))


def _opaque(*arrays):
    """The arrays behind an optimization barrier: inside ``jax.jit`` the state's directions and factor
    are constants, and XLA would otherwise constant-fold everything computed from them alone (the
    lights' cosine weights of every normal, ...) at compile time -- minutes at the sizes of
    docs/differentiable.md."""
    return jax.lax.optimization_barrier(arrays)


def _factor(state: RefitState, target, lam: float, dtype):
    """The layout's system rows and the lower Cholesky factor of its gauge-fixed normal equations, as
    JAX arrays of ``dtype`` (built once, kept in the state's memo; they do not depend on the target's
    values, so a first call inside ``jax.jit`` builds them eagerly)."""
    key = ("differentiable", float(lam), jnp.dtype(dtype).name)
    if key not in state.cache:
        p, layout = layout_of(state)
        with jax.ensure_compile_time_eval():  # concrete even when the first call is inside a jit trace
            sys = system_rows(state, target)
        (how, factor), _, _ = normal_equations(state, sys, lam, layout, p, prefer="cholesky")
        chol = np.tril(np.asarray(factor[0], np.float64)) if factor[1] else np.triu(np.asarray(factor[0])).T
        state.cache[key] = (np.asarray(sys.cols), np.asarray(sys.w, np.float64), chol)  # NumPy: never a tracer
    cols, w, chol = state.cache[key]
    return _opaque(jnp.asarray(cols), jnp.asarray(w, dtype), jnp.asarray(chol, dtype))


def refit_model(fac, environment=None, brdf=None, *, target=None, method: str = "normal", dtype=None,
                tolerance: float = 1e-10, max_steps: int = 5000) -> Factorization:
    """The factorization of a new environment and / or BRDF on ``fac``'s layout, in pure JAX: the
    differentiable counterpart of :func:`homofac.fit.refit` (see the module doc).

    Call it inside the function you differentiate, with the traced BRDF (``hf.brdf.cook_torrance(...,
    roughness=r)``) and / or environment (``eqx.tree_at(lambda e: e.radiance, env, pixels)``).

    Args:
        fac: a :class:`~homofac.fit.result.Result` of a one-product fit (``hf.fit.factorize``, a refit,
            or one read from disk and prepared with :func:`homofac.fit.prepare_refit`).
        environment: the new environment (lighting targets); the previous one when None.
        brdf: the new BRDF; the previous one when None.
        target: the whole new target instead (same kind).
        method: ``normal`` (the layout's factored normal equations, exact; up to
            :data:`~homofac.fit.refit.CHOLESKY_MAX_UNKNOWNS` unknowns) or ``lsmr`` (:func:`solve_model`).
        dtype: float type of the solve (default: JAX's default float, float64 under ``jax_enable_x64``).
        tolerance: LSMR's relative and absolute tolerance (``lsmr`` only).
        max_steps: LSMR's iteration limit (``lsmr`` only).

    Returns the one-term :class:`~homofac.factorization.Factorization` (linear textures, correction one,
    not normalised: its values equal those of the normalised model of :func:`homofac.fit.refit`).
    """
    state = getattr(fac, "state", None)
    if not isinstance(state, RefitState):
        raise HomofacError("refit_model: the result has no refit state (use hf.fit.prepare_refit(fac))")
    if state.mode != "product":
        raise HomofacError(f"refit_model: differentiable refits are for one-product fits, not {state.mode}s")
    if method not in ("normal", "lsmr"):
        raise HomofacError(f"refit_model: method must be normal or lsmr, got {method!r}")
    tgt = new_target(fac, environment, brdf, target)
    opts = state.options.solver
    if zeros_rule(tgt, opts) == "ignore":
        raise HomofacError("refit_model: solver.zeros: ignore (a data-dependent row set) is not differentiable")
    dtype = _float_dtype(dtype)
    lam, eps = float(opts.laplacian), float(opts.epsilon)
    y = state_values(state, tgt, dtype)
    p, layout = layout_of(state)
    if method == "lsmr":
        return solve_model(tgt, p.name, state.mapper, state.texture_size, jnp.asarray(state.train.a, dtype),
                           jnp.asarray(state.train.b, dtype), y=y, laplacian=lam, eps=eps, tolerance=tolerance,
                           max_steps=max_steps)
    if layout.n_unknowns > CHOLESKY_MAX_UNKNOWNS:
        raise HomofacError(f"refit_model: {layout.n_unknowns} unknowns are too many to factor; use method='lsmr'")
    cols, w, chol = _factor(state, tgt, lam, dtype)
    alpha = jnp.mean(jnp.maximum(y, 0.0), axis=0)
    alpha = jnp.where(alpha > 0, alpha, 1.0)
    rhs = log_transform(y, alpha, eps)
    atb = jax.ops.segment_sum((w[:, :, None] * rhs[:, None, :]).reshape(-1, 3), cols.reshape(-1),
                              num_segments=layout.n_unknowns)
    x = jax.scipy.linalg.cho_solve((chol, True), atb)
    return _model(tgt, p, layout, x, alpha, dtype)


# ------------------------------------------------------------------------------------------------
# image space: a sphere under a camera


class SpherePixels(NamedTuple):
    """The pixels of a unit sphere at the origin seen by a camera on the +z axis: per pixel the normal
    and the direction to the eye (world frame, ``(H, W, 3)``; zero outside the sphere) and the mask."""

    normals: jax.Array
    views: jax.Array
    mask: np.ndarray


def sphere_pixels(size: int, *, camera: str = "orthographic", distance: float = 3.0, dtype=None) -> SpherePixels:
    """The normals and views of a ``size`` x ``size`` image of the unit sphere (pure JAX).

    ``orthographic``: the image spans [-1, 1]^2, every view is +z. ``perspective``: a pinhole eye at
    ``(0, 0, distance)`` whose square image just contains the sphere; each pixel's ray is intersected
    with the sphere, the view is the direction from the hit point to the eye. Pixel (row 0, col 0) is the
    top left (+y up, +x right). Pixels with ``n . v`` below 1e-3 (the silhouette) are left out.
    """
    if camera not in ("orthographic", "perspective"):
        raise HomofacError(f"sphere_pixels: camera must be orthographic or perspective, got {camera!r}")
    if not (isinstance(size, (int, np.integer)) and size >= 2):
        raise HomofacError(f"sphere_pixels: size must be an integer >= 2, got {size!r}")
    if camera == "perspective" and not distance > 1.0:
        raise HomofacError(f"sphere_pixels: the eye must be outside the sphere (distance > 1), got {distance}")
    dtype = _float_dtype(dtype)
    s = (jnp.arange(size, dtype=dtype) + 0.5) / size * 2.0 - 1.0
    x, y = jnp.meshgrid(s, -s)
    if camera == "orthographic":
        r2 = x * x + y * y
        z = jnp.sqrt(jnp.maximum(1.0 - r2, 0.0))
        n = jnp.stack([x, y, z], axis=-1)
        v = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 1.0], dtype), n.shape)
    else:
        d = jnp.asarray(distance, dtype)
        half = 1.0 / jnp.sqrt(d * d - 1.0)  # tan of the half angle under which the sphere is seen
        ray = jnp.stack([x * half, y * half, -jnp.ones_like(x)], axis=-1)
        ray = ray / jnp.linalg.norm(ray, axis=-1, keepdims=True)
        eye = jnp.asarray([0.0, 0.0, 1.0], dtype) * d
        bq = jnp.sum(ray * eye, axis=-1)
        disc = bq * bq - (d * d - 1.0)
        t = -bq - jnp.sqrt(jnp.maximum(disc, 0.0))
        n = eye + t[..., None] * ray
        n = n / jnp.linalg.norm(n, axis=-1, keepdims=True)
        v = eye - n
        v = v / jnp.linalg.norm(v, axis=-1, keepdims=True)
    mask = np.asarray(jnp.sum(n * v, axis=-1) > 1e-3) & (np.asarray(x * x + y * y) < 1.0)
    m = jnp.asarray(mask)[..., None]
    return SpherePixels(jnp.where(m, n, 0.0), jnp.where(m, v, 0.0), mask)


def render_sphere(fn, pixels: SpherePixels) -> jax.Array:
    """The image ``(H, W, 3)`` of ``fn(n, v)`` (a :class:`~homofac.factorization.Factorization`, a target,
    or ``lambda n, v: hf.light.lighting(brdf, env, n, v)``) on the sphere's pixels; zero outside."""
    mask = np.asarray(pixels.mask)
    vals = fn(pixels.normals[mask], pixels.views[mask])
    out = jnp.zeros(mask.shape + (3,), vals.dtype)
    return out.at[mask].set(vals)


def pixel_samples(target, pixels: SpherePixels, validation: SpherePixels | None = None) -> Samples:
    """Samples whose training pairs are the (n, v) of ``pixels`` (and validation pairs those of
    ``validation``, default the same), with the target's exact values: sampling from the scene that
    will be rendered. A fit on them (``hf.fit.factorize(target, "NR", samples=...)``) spends its whole
    least-squares budget on the pairs the image shows; its refit state then carries exactly those pairs,
    so :func:`refit_model` re-solves on them (what makes the inverse rendering of docs/differentiable.md
    unbiased: a fit on texel-sampled pairs leaves an image error of ~30 % at the true parameters, which
    the optimizer trades for wrong ones)."""
    validation = pixels if validation is None else validation
    pairs = []
    for px in (pixels, validation):
        m = np.asarray(px.mask)
        a = np.asarray(px.normals, np.float32)[m]
        b = np.asarray(px.views, np.float32)[m]
        pairs.append((a, b, np.asarray(evaluate(target, a, b), np.float32)))
    (a, b, y), (va, vb, vy) = pairs
    return Samples(a, b, y, va, vb, vy)


def image_loss(image, reference, mask=None) -> jax.Array:
    """Relative squared image error ``sum (image - reference)^2 / sum reference^2`` over the mask's
    pixels (all pixels when None): differentiable."""
    if mask is not None:
        m = np.asarray(mask)
        image, reference = image[m], reference[m]
    return jnp.sum((image - reference) ** 2) / jnp.maximum(jnp.sum(reference ** 2), 1e-30)


__all__ = ["SpherePixels", "fit_error", "image_loss", "pixel_samples", "refit_model", "render_sphere", "solve_model", "solve_textures",
           "sphere_pixels", "state_values"]
