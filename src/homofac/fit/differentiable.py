"""A pure-JAX factorization, end to end, for gradients.

:func:`fit_error` maps (target parameters) -> samples -> log system -> LSMR solve (lineax) ->
linear textures -> factorized values -> a pinned metric, with no NumPy in between, so
``jax.grad`` flows from the error back to BRDF parameters and environment pixels. The sample
*directions* are fixed inputs (they do not depend on the parameters); their values are recomputed
from the target inside the function. The solve starts from zero (the §3.1.2 start is a
preconditioning device and does not change the least-squares minimum the gradient is taken at).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import lineax as lx

from ..factorization import Factorization
from ..param import parametrizations as pz
from . import precision
from .metrics import metric_arrays
from .product import unpack
from .system import apply, augmented_rhs, build_system, parametrization_layout


def solve_model(target, parametrization: str, mapper: str, size: int, a, b, *, laplacian=1.0, eps=1e-5,
                tolerance=1e-8, max_steps=2000) -> Factorization:
    """The one-term model of a factorization of ``target`` on pairs (a, b), in pure JAX (differentiable)."""
    p = pz.get(parametrization)
    layout = parametrization_layout(p, mapper, size)
    y = target(a, b)
    sys, alpha = build_system(p, layout, a, b, y, eps=eps, context=target.context)
    lam = jnp.asarray(laplacian, a.dtype)
    x0 = jnp.zeros((layout.n_unknowns, 3), a.dtype)
    op = lx.FunctionLinearOperator(lambda x: apply(sys, lam, x), jax.ShapeDtypeStruct(x0.shape, x0.dtype))
    sol = lx.linear_solve(op, augmented_rhs(sys), lx.LSMR(rtol=tolerance, atol=tolerance, max_steps=max_steps),
                          throw=False)
    textures = precision.exponentiate(unpack(sol.value, layout), alpha, p.J)
    main = next((t for t in layout.textures if t.mapper != "line"), layout.textures[0])
    return Factorization.product(target.kind, target.quantity if target.kind == "brdf" else "lighting", p.name,
                                 main.mapper, main.size, textures, jnp.ones((3,), a.dtype), dict(target.context))


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


__all__ = ["fit_error", "solve_model", "solve_textures"]
