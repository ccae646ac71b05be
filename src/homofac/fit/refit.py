"""Refits: the factorization of a new environment or material on the layout of a previous fit (issue 15).

Once a layout is fixed (parametrization or sum structure, mappers, sizes, sample directions,
Laplacian), the least-squares matrix of a product is fixed too: thesis eq. 37's data rows hold the
bilinear weights of the projected directions, which do not depend on the target. A new environment
(time of day, a moving light) or a new material changes only the right-hand side
``log((y + eps alpha) / alpha)`` (eq. 26). :func:`refit` therefore

1. recomputes only the target values at the stored directions: through the light transport
   (:mod:`homofac.fit.transport`, ``y = kd/pi W L + sum_m c_m T_m L``: two matrix products, no BRDF
   evaluation) when only the environment's radiance or the material's colours change, else through
   the per-normal fast path of sampling (:func:`homofac.fit.samples.evaluate_grouped`, with lobe culling
   when the target asks for it);
2. solves with what the first refit derived and kept in ``Result.state`` (:mod:`homofac.fit.state`):
   the Cholesky factor of the normal equations ``(A^T A + lambda^2 L^T L) x = A^T b`` (float64; the
   least-squares optimum, to which the full run's LSMR converges to ~1e-7), so each refit is one sparse
   product and two triangular solves; above :data:`CHOLESKY_MAX_UNKNOWNS` a warm-started LSMR from the
   previous solution; sums of products re-run their ALS / Levenberg-Marquardt from the previous terms
   (``fit_sum(previous=...)``); baselines are computed again;
3. measures the pinned metrics on the same training and validation directions.

The first refit of a state is *cold* (it builds the system rows, the factor and the transport, and
compiles); later ones are *warm*. A refit keeps the target's context (NRHD's dominant direction) so
the matrix stays the one of the layout.
"""

from __future__ import annotations

import time
from typing import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from .. import baselines
from ..brdf import BRDF
from ..errors import HomofacError
from ..factorization import Factorization
from ..light import Environment, Lighting
from ..options import validate
from ..param import mappers
from ..param import parametrizations as pz
from ..target import Target, evaluate
from . import footprints, precision, programs, solvers, sums, transport, validation
from .draw import default_mapper
from .options import FitOptions, LinearOptions, recorded_fit_options
from .pipeline import quality_warnings, resolve_sampling
from .polish import polish, polish_pairs, recorded_direct, recorded_linear, recorded_stride
from .product import unpack, zeros_rule
from .result import Result
from .samples import check_values, evaluate_grouped, row_width_of
from .state import RefitState, from_options
from .system import Layout, System, build_system, parametrization_layout

#: Largest number of unknowns whose normal equations a refit factors densely (float64: 512 MB at 8000).
CHOLESKY_MAX_UNKNOWNS = 8000
#: Up to this many unknowns the factored normal equations are kept as their float32 inverse (one
#: matrix-vector product per refit; well conditioned once the gauge is fixed, see :func:`gauge_basis`).
#: The float32 inverse is used only when the Cholesky factor's diagonal ratio squared (a cheap estimate
#: of the reciprocal condition number) is above this; else the float64 Cholesky solve.
INVERSE_MIN_RCOND = 1e-6
INVERSE_MAX_UNKNOWNS = 4096
#: Largest light transport (training + validation) a refit keeps in its state, bytes.
TRANSPORT_BYTES = 1 << 30


# ------------------------------------------------------------------------------------------------
# the new target


def new_target(fac: Result, environment=None, brdf=None, target: Target | None = None) -> Target:
    """The target of a refit: ``target`` itself, or the previous target with its environment and / or
    BRDF replaced (its clamp, culling, horizon rule and context kept)."""
    if target is not None:
        if environment is not None or brdf is not None:
            raise HomofacError("refit: give target=, or environment= and / or brdf=, not both")
        if not isinstance(target, Target):
            raise HomofacError(f"refit: target must be a homofac Target, got {type(target).__name__}")
        if target.kind != fac.kind:
            raise HomofacError(f"refit: the target is a {target.kind} target, the factorization a {fac.kind} one")
        return target
    old = fac.target
    if old is None:
        raise HomofacError("refit: the result does not carry its target (read from disk?); pass target=")
    if environment is None and brdf is None:
        raise HomofacError("refit: nothing changes; give environment=, brdf= or target=")
    if environment is not None and not isinstance(environment, Environment):
        raise HomofacError(f"refit: environment must be a homofac Environment, got {type(environment).__name__}")
    if brdf is not None and not callable(brdf):
        raise HomofacError(f"refit: brdf must be a BRDF (hf.brdf.cook_torrance(...) ...), got {type(brdf).__name__}")
    if old.kind == "brdf":
        if environment is not None:
            raise HomofacError("refit: a BRDF factorization has no environment; give brdf=")
        return Target("brdf", brdf, old.quantity, dict(old.context))
    fn = old.fn
    if not isinstance(fn, Lighting):
        raise HomofacError("refit: environment= and brdf= replace parts of a homofac Lighting target; pass target=")
    new = Lighting(brdf if brdf is not None else fn.brdf, environment if environment is not None else fn.env,
                   clamp=fn.clamp, chunk=fn.chunk, lobe_tolerance=fn.lobe_tolerance, horizon=fn.horizon)
    return Target("lighting", new, old.quantity, dict(old.context))


# ------------------------------------------------------------------------------------------------
# values at the stored directions


def _transport_key(fn: Lighting) -> tuple:
    return ("transport", transport.geometry_key(fn.env), transport.shape_key(fn.brdf), fn.horizon)


def _use_transport(state: RefitState, target: Target, previous: Target | None, want: bool | None) -> bool:
    if want is False or state.groups is None:
        return False
    ok = transport.supported(target.fn)
    if want is True:
        if not ok:
            raise HomofacError("refit: transport=True needs a lighting target of a BRDF in lobe form (not lobe-culled)")
        return True
    if not ok:
        return False
    if _transport_key(target.fn) in state.cache:
        return True
    # auto: build it when this refit keeps the BRDF's shape (environment or colours change): the
    # next refits of the same kind then cost two matrix products
    prev = previous.fn if previous is not None else None
    if not (transport.supported(prev) and transport.shape_key(prev.brdf) == transport.shape_key(target.fn.brdf)):
        return False
    lobes = transport.lobe_count(target.fn.brdf)
    size = sum(transport.transport_bytes(g.normals.shape[0], g.views.shape[1], target.fn.env, lobes)
               for g in (state.groups, state.val_groups))
    return size <= TRANSPORT_BYTES


def _transported(state: RefitState, fn: Lighting, log) -> tuple[np.ndarray, np.ndarray]:
    key = _transport_key(fn)
    if key not in state.cache:
        for k in [k for k in state.cache if isinstance(k, tuple) and k[0] == "transport"]:
            del state.cache[k]  # one transport at a time
        log("building the light transport of the sample directions")
        state.cache[key] = tuple(transport.build_transport(fn, g.normals, g.views) if g.mask.any() else None
                                 for g in (state.groups, state.val_groups))
    out = []
    for g, tr in zip((state.groups, state.val_groups), state.cache[key]):
        if tr is None:
            out.append(np.zeros((0, 3), np.float32))
            continue
        flat = _flat_index(state, g)
        out.append(np.asarray(transport.transported_values(tr, fn, g.normals, g.views, flat)))
    return out[0], out[1]


def _flat_index(state: RefitState, g) -> np.ndarray:
    key = ("flat", id(g))
    if key not in state.cache:
        state.cache[key] = np.flatnonzero(g.mask.reshape(-1)).astype(np.int32)
    return state.cache[key]


def values(state: RefitState, target: Target, *, previous: Target | None = None, use_transport: bool | None = None,
           log: Callable[[str], None] | None = None, validation: Target | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The target's values at the state's training and validation directions (see the module doc, 1.);
    the validation values of ``validation`` where given (the full run's validation lighting,
    :func:`validation_target`)."""
    log = log or (lambda msg: None)
    vt = target if validation is None else validation
    none = np.zeros((0, 3))
    if _use_transport(state, target, previous, use_transport):
        y, val = _transported(state, target.fn, log)
        if vt is not target and len(state.validation):
            val = np.asarray(evaluate_grouped(vt, state.val_groups))
        return y, val
    if state.groups is not None:
        y = np.asarray(evaluate_grouped(target, state.groups))
        val = np.asarray(evaluate_grouped(vt, state.val_groups)) if len(state.validation) else none
        return y, val
    y = np.asarray(evaluate(target, state.train.a, state.train.b))
    val = np.asarray(evaluate(vt, state.validation.a, state.validation.b)) if len(state.validation) else none
    return y, val


def validation_target(fac: Result, target: Target) -> Target:
    """The lighting a refit's validation values read: the full run's validation lighting
    (``selection.validation_light``, :func:`homofac.fit.validation.lighting_at`) where it refined lights at
    the resolution ``target``'s environment has, so the refit's figures are the full run's on the same
    target; ``target`` itself otherwise (no recorded refinement, or an environment of another resolution)."""
    light = (fac.selection or {}).get("validation_light") or {}
    env = validation.environment(target)
    if not light or env is None or int(light["start"]) != int(env.info["resolution"]):
        return target
    return validation.lighting_at(target, int(light["resolution"]))


# ------------------------------------------------------------------------------------------------
# products: the fixed system, its factored normal equations


def layout_of(state: RefitState) -> tuple[pz.Parametrization, Layout]:
    p = pz.get(state.parametrization, state.kind)
    return p, parametrization_layout(p, state.mapper, state.texture_size)


def system_rows(state: RefitState, target: Target) -> System:
    """The ELL rows of eq. 37 at the state's training directions (built once, kept in the state)."""
    if "system" not in state.cache:
        p, layout = layout_of(state)
        ones = np.ones((len(state.train), 3), np.float32)
        sys, _ = build_system(p, layout, state.train.a, state.train.b, ones, eps=1e-5, context=target.context)
        state.cache["system"] = sys
    return state.cache["system"]


def data_matrix(sys: System, n: int) -> sp.csr_matrix:
    """The data rows of eq. 37 as a scipy CSR matrix (float64)."""
    cols = np.asarray(sys.cols)
    m, k = cols.shape
    return sp.csr_matrix((np.asarray(sys.w, np.float64).ravel(), (np.repeat(np.arange(m), k), cols.ravel())),
                         shape=(m, n))


def laplacian_matrix(sys: System, lam: float, n: int) -> sp.csr_matrix:
    """The lambda-weighted Laplacian rows of eq. 37 as a scipy CSR matrix (float64)."""
    lc, lw = np.asarray(sys.lap_cols), np.asarray(sys.lap_w, np.float64) * lam
    return sp.csr_matrix((lw.ravel(), (np.repeat(np.arange(lc.shape[0]), lc.shape[1]), lc.ravel())),
                         shape=(lc.shape[0], n))


def gauge_basis(layout: Layout, p: pz.Parametrization) -> np.ndarray:
    """Orthonormal basis (n, T - 1) of the gauge directions of a log-space product: constant shifts
    ``sum_k c_k 1_k`` of the textures with ``sum_k c_k uses_k = 0`` leave every data row (each row's
    bilinear weights of a texture sum to one) and every Laplacian row unchanged."""
    n = layout.n_unknowns
    uses = [max(len(p.uses(k)), 1) for k in range(p.T)]
    ones = np.zeros((n, p.T))
    for k, t in enumerate(layout.textures):
        ones[t.offset:t.offset + t.n_valid, k] = 1.0
    d = np.stack([ones[:, k] / uses[k] - ones[:, 0] / uses[0] for k in range(1, p.T)], axis=1) if p.T > 1 else \
        np.zeros((n, 0))
    return np.linalg.qr(d)[0] if d.shape[1] else d


def normal_equations(state: RefitState, sys: System, lam: float, layout: Layout, p: pz.Parametrization,
                     prefer: str = "inverse"):
    """The normal equations of eq. 37, ``A^T A + lambda^2 L^T L``, made definite by a penalty on the gauge
    directions (:func:`gauge_basis`; it picks the solution without gauge component and leaves the
    model unchanged), inverted (float32, up to :data:`INVERSE_MAX_UNKNOWNS`: one matrix-vector product
    per refit) or Cholesky-factored (float64; ``prefer="cholesky"``: cheaper to build, best for many
    right-hand sides at once) once and kept in the state."""
    n = layout.n_unknowns
    how = "inverse" if prefer == "inverse" and n <= INVERSE_MAX_UNKNOWNS else "cholesky"
    key = ("normal", float(lam), how)
    if key not in state.cache:
        a_data = data_matrix(sys, n)
        lap = laplacian_matrix(sys, lam, n)
        ata = (a_data.T @ a_data + lap.T @ lap).toarray()
        g = gauge_basis(layout, p)
        ata += max(float(np.mean(np.diag(ata))), 1e-30) * (g @ g.T)
        ata[np.diag_indices_from(ata)] += 1e-12 * max(float(np.mean(np.diag(ata))), 1e-30)
        c, info = sla.lapack.dpotrf(ata, lower=True)
        if info != 0:
            raise HomofacError("refit: the normal equations are not positive definite; try a larger solver.laplacian")
        d = np.abs(np.diag(c))
        if how == "inverse" and (d.min() / d.max()) ** 2 < INVERSE_MIN_RCOND:
            # near-singular (unknowns that no sample and no smoothing row reaches, e.g. a paraboloid half
            # no pixel shows): a float32 inverse amplifies round-off along those directions into
            # non-finite textures, while the float64 Cholesky solve keeps them at ~0 (A^T b has no
            # component there)
            how = "cholesky"
        if how == "inverse":
            inv, info2 = sla.lapack.dpotri(c, lower=True)
            if info2 != 0:
                raise HomofacError("refit: the normal equations are not positive definite; try a larger solver.laplacian")
            inv = np.tril(inv) + np.tril(inv, -1).T
            factor = ("inverse", jnp.asarray(inv, jnp.float32))
        else:
            factor = ("cholesky", (c, True))
        state.cache[key] = (factor, a_data.T.tocsr(), lap)
    return state.cache[key]


@jax.jit
def _inverse_solve(inv, cols, w, y, keep, eps):
    """alpha, the log right-hand side (eq. 26) and ``x = (A^T A)^-1 A^T b`` in one program."""
    y = jnp.where(keep[:, None], jnp.maximum(y, 0.0), 0.0)
    alpha = jnp.sum(y, axis=0) / jnp.maximum(jnp.sum(keep), 1)
    alpha = jnp.where(alpha > 0, alpha, 1.0)
    rhs = jnp.where(keep[:, None], jnp.log((y + eps * alpha) / alpha), 0.0)
    atb = jax.ops.segment_sum((w[:, :, None] * rhs[:, None, :]).reshape(-1, 3), cols.reshape(-1),
                              num_segments=inv.shape[0])
    return inv @ atb, alpha, rhs


def log_start(model: Factorization, layout: Layout, p: pz.Parametrization, alpha) -> np.ndarray:
    """A warm start in log space from a model: ``x_k = log t_k`` with ``log(correction / alpha)`` spread
    over the J factors (the textures' product then reproduces the model at every sample)."""
    out = []
    c = np.log(np.maximum(np.asarray(model.terms[0].correction, np.float64), 1e-30) / np.asarray(alpha, np.float64))
    for tex in layout.textures:
        data = np.asarray(model.texture(tex.name).data, np.float64).reshape(-1, 3)[tex.texel_of_unknown]
        out.append(np.log(np.maximum(data, 1e-30)) + c / p.J)
    return np.concatenate(out, axis=0)


def _product(kind: str, quantity: str, context: dict, p: pz.Parametrization, layout: Layout, x, alpha) -> Factorization:
    """The normalized one-product model of log texels ``x`` (n, 3) and the log-space scale ``alpha``."""
    textures = precision.exponentiate(unpack(jnp.asarray(x, jnp.float32), layout), jnp.asarray(alpha), p.J)
    main = next((t for t in layout.textures if not mappers.get(t.mapper).scalar), layout.textures[0])
    line = next((t.size for t in layout.textures if mappers.get(t.mapper).scalar), None)
    model = Factorization.product(kind, quantity, p.name, main.mapper, main.size, textures, jnp.ones((3,), jnp.float32),
                                  context=context, line_size=line)
    return precision.normalize(model)


@eqx.filter_jit
def _product_batch(kind: str, quantity: str, context: dict, p: pz.Parametrization, layout: Layout, xs, alphas):
    batch = eqx.filter_vmap(lambda x, a: _product(kind, quantity, context, p, layout, x, a))(xs, alphas)
    return [jax.tree_util.tree_map(lambda leaf, i=i: leaf[i], batch) for i in range(xs.shape[0])]


def product_models(target: Target, p: pz.Parametrization, layout: Layout, xs, alphas) -> list[Factorization]:
    """The one-product models of T solutions ``xs`` (T, n, 3) with scales ``alphas`` (T, 3) of one layout:
    exponentiated, normalized and dilated in one compiled program (op by op, 16 models took 0.13 s)."""
    quantity = target.quantity if target.kind == "brdf" else "lighting"
    return _product_batch(target.kind, quantity, dict(target.context), p, layout,
                          jnp.asarray(xs, jnp.float32), jnp.asarray(alphas, jnp.float32))


def product_model(target: Target, p: pz.Parametrization, layout: Layout, x, alpha) -> Factorization:
    """The model of one solution (op by op: a refit of a new layout then compiles no program for it)."""
    quantity = target.quantity if target.kind == "brdf" else "lighting"
    return _product(target.kind, quantity, dict(target.context), p, layout, x, alpha)


def refit_product(state: RefitState, fac: Result, target: Target, y: np.ndarray, log,
                  solve: str = "auto") -> tuple[Factorization, dict, float]:
    """The log-space product of the state's layout for values ``y`` (see the module doc, 2.); ``solve``
    as in :func:`refit`."""
    p, layout = layout_of(state)
    opts = state.options.solver
    sys = system_rows(state, target)
    n = layout.n_unknowns
    lam = float(opts.laplacian)
    eps = float(opts.epsilon)
    keep = np.all(y > 0, axis=1) if zeros_rule(target, opts) == "ignore" else np.ones(len(y), bool)
    if not keep.any():
        raise HomofacError("solver.zeros: ignore left no training sample with all channels > 0")
    t0 = time.perf_counter()
    if solve != "lsmr" and keep.all() and n <= CHOLESKY_MAX_UNKNOWNS:
        (how, factor), a_t, lap = normal_equations(state, sys, lam, layout, p)
        if how == "inverse":
            x, alpha, rhs = _inverse_solve(factor, sys.cols, sys.w, jnp.asarray(y, jnp.float32), jnp.asarray(keep),
                                           jnp.float32(eps))
            x, alpha, rhs = np.asarray(x, np.float64), np.asarray(alpha, np.float64), np.asarray(rhs, np.float64)
        else:
            alpha, rhs = _log_rhs(y, keep, eps)
            x = sla.cho_solve(factor, a_t @ rhs, check_finite=False)
        method, iterations, converged = f"normal equations ({how})", 1, True
        resid = (a_t.T @ x - rhs, lap @ x)
    else:
        alpha, rhs = _log_rhs(y, keep, eps)
        sys_k = sys._replace(w=jnp.where(jnp.asarray(keep)[:, None], sys.w, 0.0), rhs=jnp.asarray(rhs, sys.w.dtype))
        x0 = state.cache.get("x")
        if x0 is None or x0.shape != (n, 3):
            x0 = log_start(fac.model, layout, p, alpha)
        log(f"solving with {opts.method} from the previous solution ({n} unknowns x 3 channels)")
        res = solvers.solve(sys_k, jnp.asarray(x0, jnp.float32), opts)
        x, method, iterations, converged = np.asarray(res.x, np.float64), res.method, res.iterations, res.converged
        resid = (np.sqrt(max(res.objective, 0.0)),)
    solve_s = time.perf_counter() - t0
    if not np.all(np.isfinite(x)):
        raise HomofacError("refit produced non-finite texture values; try a larger solver.laplacian")
    state.cache["x"] = x
    obj = float(sum(np.sum(np.asarray(r, np.float64) ** 2) for r in resid))
    bnorm2 = float(np.sum(rhs ** 2))
    record = {**{k: v for k, v in (fac.solver or {}).items() if k in ("tolerance", "max_iterations", "laplacian",
                                                                      "epsilon", "levels", "zeros")},
              "method": method, "iterations": int(iterations), "converged": bool(converged), "refit": True,
              "objective": obj, "residual": float(np.sqrt(obj / bnorm2)) if bnorm2 > 0 else float(np.sqrt(obj)),
              "ignored_samples": int(np.size(keep) - np.count_nonzero(keep))}
    return product_model(target, p, layout, x, alpha), record, solve_s


def _log_rhs(y, keep, eps):
    yk = np.maximum(np.where(keep[:, None], y, 0.0), 0.0).astype(np.float64)
    alpha = np.mean(yk[keep], axis=0)
    alpha = np.where(alpha > 0, alpha, 1.0)
    return alpha, np.where(keep[:, None], np.log((yk + eps * alpha) / alpha), 0.0)


# ------------------------------------------------------------------------------------------------
# the refit


def refit(fac: Result, environment: Environment | None = None, brdf: BRDF | None = None, *,
          target: Target | None = None, transport: bool | None = None, linear: dict | None = None,
          start: str = "previous", solve: str = "auto", samples=None,
          config: dict | None = None, target_info: dict | None = None, keep_samples: bool | None = None,
          log: Callable[[str], None] | None = None) -> Result:
    """The factorization of a new environment and / or BRDF on ``fac``'s layout, with its metrics.

    Args:
        fac: a :class:`~homofac.fit.result.Result` of :func:`homofac.fit.factorize` (or of a refit, or one
            read from disk and prepared with :func:`prepare`): its ``state`` holds the layout.
        environment: the new environment (lighting targets); the previous one when None.
        brdf: the new BRDF; the previous one when None.
        target: the whole new target instead (same kind; e.g. what a config describes).
        transport: use the light transport of :mod:`homofac.fit.transport` (``True``), never (``False``),
            or ``None`` (auto: when the refit keeps the BRDF's lobe shape -- an environment or colour
            change -- and it fits in :data:`TRANSPORT_BYTES`, or when the state holds it already).
        linear: options of a sum's linear-space refit (e.g. ``{"iterations": 10}``), merged into the fit's.
        solve: how a product's refit solves: ``auto`` (the normal equations factored once and kept in
            the state, up to :data:`CHOLESKY_MAX_UNKNOWNS` unknowns: best when the state is refitted
            again) or ``lsmr`` (the configured solver from the previous solution: best for one refit
            of a fresh state, e.g. the CLI's ``--refit``, where factoring would not pay).
        start: where a sum's refit starts: ``previous`` (the previous terms, a warm start) or ``fresh``
            (the start rule of a full run, on the new target: the full run's result on the same samples; a full run
            that continued from a strided short fit, ``solver.head``, does so again).
            ALS and Levenberg-Marquardt find local minima, so a warm start may end in another one than
            a full run (often a lower training objective; docs/refit.md).
        config: the configuration to record in the result (default: the previous one).
        target_info: the target description to record in the result (default: the previous one).
        keep_samples: keep the new samples on the result (default: when ``fac`` kept them).
        samples: the new target's values at the state's directions, computed already
            (:class:`~homofac.fit.samples.Samples`; :func:`homofac.fit.many.factorize_many` shares them).
        log: progress callback.

    Returns a new :class:`Result` (model, metrics, solver record, timings ``sample_s``, ``solve_s``,
    ``measure_s``, ``total_s``) whose ``state`` is the same layout, so refits chain cheaply.
    """
    log = log or (lambda msg: None)
    state = fac.state
    if not isinstance(state, RefitState):
        raise HomofacError("refit: the result has no refit state (a factorization of this process has one; "
                           "for one read from disk use hf.fit.prepare_refit(fac))")
    programs.bound_compiled_programs()
    programs.enable_compilation_cache()
    t_start = time.perf_counter()
    tgt = new_target(fac, environment, brdf, target)
    if solve not in ("auto", "lsmr"):
        raise HomofacError(f"refit: solve must be auto or lsmr, got {solve!r}")
    if start not in ("previous", "fresh"):
        raise HomofacError(f"refit: start must be previous or fresh, got {start!r}")
    opts = state.options
    t0 = time.perf_counter()
    if samples is None:
        y, val_y = values(state, tgt, previous=fac.target, use_transport=transport, log=log,
                          validation=validation_target(fac, tgt))
        samples = state.samples(y, val_y)
    elif len(samples.a) != len(state.train) or len(samples.val_a) != len(state.validation):
        raise HomofacError("refit: samples= must hold values at the state's training and validation directions")
    y, val_y = np.asarray(samples.y), np.asarray(samples.val_y)
    check_values(y, "training")
    sample_s = time.perf_counter() - t0
    log(f"refitting {state.mode} {state.parametrization} on {len(y)} training pairs")
    if state.mode == "product":
        model, record, solve_s = refit_product(state, fac, tgt, y, log, solve)
        warnings: tuple = ()
    elif state.mode == "sum":
        lin = recorded_linear(opts.advanced.linear or LinearOptions(), fac.solver)  # what the full run used
        if linear:
            lin = validate(LinearOptions, {**lin.model_dump(), **linear}, "linear")
        head = sums.recorded_head(fac.solver)
        if start == "fresh" and head is not None:  # the full run continued from a strided short fit: so does this
            sf = sums.continued(tgt, state.structure, state.mapper, state.texture_size, samples, lin, log,
                                stride=head["stride"], sweeps=head["sweeps"], line_size=sums.line_size_of(fac.model))
        else:
            sf = sums.fit_sum(tgt, state.structure, state.mapper, state.texture_size, samples, lin, log,
                              previous=fac.model if start == "previous" else None,
                              line_size=sums.line_size_of(fac.model))
        if lin.polish > 0:  # the same off-grid pairs as the full run (deterministic), the new target's values
            k = recorded_stride(fac.solver)  # in rows of the grid's width, as the full run evaluated them
            pairs = polish_pairs(tgt, opts.parametrization, lin, opts.sampling.seed, opts.sampling.cache, log,
                                 stride=k, width=row_width_of(samples.a))
            sf = polish(tgt, state.structure, state.mapper, state.texture_size, sf, samples, pairs, lin, log,
                        seed=opts.sampling.seed, direct=recorded_direct(fac.solver), stride=k)
        model, record, solve_s, warnings = sf.model, {**sf.solver, "refit": True}, sf.solve_s, sf.warnings
    else:
        t1 = time.perf_counter()
        model = baselines.build(opts.parametrization, tgt, state.mapper, state.texture_size, opts.advanced.baseline)
        record, solve_s, warnings = {**(fac.solver or {}), "refit": True}, time.perf_counter() - t1, ()
    t1 = time.perf_counter()
    result = Result(model, solver=record, config=fac.config if config is None else config,
                    target_info=fac.target_info if target_info is None else target_info, encoding=fac.encoding,
                    state=state, target=tgt,
                    samples=samples if (fac.samples is not None if keep_samples is None else keep_samples) else None)
    mets = measure_on(state, result, tgt, samples, eps=float(opts.solver.epsilon))
    if state.scene is not None:
        mets = {**mets, "scene": state.scene.metrics(result, tgt, float(opts.solver.epsilon))}
    measure_s = time.perf_counter() - t1
    counts = {**(fac.counts or {}), "train": int(len(y)), "validation": int(len(val_y)),
              "lights": int(getattr(tgt.fn, "n_lights", 0))}
    return result.replace(
        metrics=mets, warnings=tuple(warnings) + tuple(quality_warnings(mets)), counts=counts,
        timings={"sample_s": sample_s, "solve_s": solve_s, "measure_s": measure_s,
                 "total_s": time.perf_counter() - t_start},
    )


def _state_footprints(state: RefitState, result: Result, samples):
    """The footprints of ``result``'s lookups at the training and validation pairs, kept in the state."""
    keys = footprints.lookup_keys(result.model)
    key = ("footprints", keys, tuple(sorted((k, np.asarray(v).tobytes()) for k, v in result.model.context.items())))
    if key not in state.cache:
        state.cache[key] = (footprints.footprints(result.model, samples.a, samples.b),
                            footprints.footprints(result.model, samples.val_a, samples.val_b) if len(samples.val_a)
                            else None)
    return state.cache[key]


def measure_on(state: RefitState, result: Result, target: Target, samples, eps: float) -> dict:
    """The pinned metrics (:func:`homofac.fit.metrics.measure`) from footprints kept in the state."""
    fp_train, fp_val = _state_footprints(state, result, samples)
    return footprints.measure(result, target, samples, fp_train, fp_val, eps=eps)


def measure_all(state: RefitState, results: list[Result], targets: list[Target], samples: list, eps: float) -> list[dict]:
    """:func:`measure_on` of many results of the state's layout at its pairs, in one vmapped program
    (:func:`homofac.fit.footprints.measure_many`): what a material library measures."""
    fp_train, fp_val = _state_footprints(state, results[0], samples[0])
    return footprints.measure_many(results, targets, samples, fp_train, fp_val, eps=eps)


def prepare(fac: Result, options: FitOptions | dict | None = None) -> Result:
    """``fac`` with a refit state: for a result read from disk (:func:`homofac.output.load`), its layout
    and directions rebuilt from ``options`` (default: its recorded config's fit options)."""
    if isinstance(fac.state, RefitState):
        return fac
    if options is None:
        if not fac.config:
            raise HomofacError("refit: the result records no config to rebuild its layout from")
        options = recorded_fit_options(fac.config)
    opts = options if isinstance(options, FitOptions) else validate(FitOptions, options, "")
    mapper = opts.mapper or default_mapper(fac.kind)
    state = from_options(opts, fac.kind, fac, mapper, resolve_sampling(opts, fac.kind, mapper))
    return fac.replace(state=state)


__all__ = ["CHOLESKY_MAX_UNKNOWNS", "INVERSE_MAX_UNKNOWNS", "TRANSPORT_BYTES", "data_matrix", "gauge_basis", "laplacian_matrix", "layout_of", "log_start",
           "measure_all", "measure_on", "new_target", "normal_equations", "product_model", "product_models",
           "prepare", "refit", "refit_product", "system_rows", "values"]
