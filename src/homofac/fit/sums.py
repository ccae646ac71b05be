"""Sums of products fitted in linear space: ``terms``, ``diffuse``, ``nv_factor`` (issue 13, schema 2).

One product p(n) q(r) cannot hold a sum such as diffuse + specular; a renderer evaluates

    L(v, n) ~ kd/pi E(n) + sum_t p_t(n) q_t(r) w_t(n.v)

just as cheaply (one lookup per factor). :func:`fit_sum` fits such a :class:`~homofac.fit.structures.Structure`
to the training samples in *linear* space (the objective the GPU sees, in units of the RMS sigma_c of
what the terms fit, with first-difference smoothing of every texture):

1. the fixed terms are computed, not fitted: ``diffuse: exact`` is kd/pi times the irradiance E(n) at
   the texel centres (:func:`homofac.baselines.base.irradiance_map`); the fitted terms approximate
   ``y - fixed``;
2. a start: term 1 = the split sum's P(r) W(n.v) (``start: split_sum``, microfacet lighting targets)
   or the log-space product of the parametrization (``start: product``, :func:`homofac.fit.product.fit_product`);
   further terms start at p = 1 + (a smooth function of n), q = 0, w = 1, which breaks their symmetry;
3. a refinement: exact block ALS on grid samples (:mod:`homofac.fit.als`, the default for lighting)
   or matrix-free Levenberg-Marquardt / Gauss-Newton (:mod:`homofac.fit.refine`, any parametrization
   and sampling, optimistix or jaxopt).

With ``terms: 1`` and no diffuse term this is the linear-space refinement of today's single product.
:func:`choose` fits the candidate structures of a lookup budget (``max_lookups``) or a ``target_error``
and keeps the best on the validation pairs.
"""

from __future__ import annotations

import functools
import time
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..baselines import split_sum as ss
from ..baselines.base import centres, irradiance_map
from ..brdf import BRDF, MODELS
from ..compiling import jit
from ..errors import HomofacError
from ..factorization import Factor, Factorization, Term, Texture
from ..light import Lighting, brightest_directions, light_radii
from ..param import mappers
from ..param import parametrizations as pz
from ..param import projections as pj
from ..param.projections import apply as project
from ..target import Target
from . import als, precision, refine, solvers, table
from .options import LinearOptions
from .product import fit_product
from .samples import Samples
from .structures import HIGHLIGHT_LINES, LINE_SIZE, TABLE_SIZE, Structure, TermSpec, TextureSpec, lined, skeleton
from .system import TextureLayout, texture_layout


#: The projections of highlight terms (``highlight_terms``), brightest light first: of a point light, then
#: of a light with a disc (``highlight_disc``).
HIGHLIGHT_PROJECTIONS = tuple(p for p, _ in pj.HIGHLIGHTS) + tuple(p for p, _, _ in pj.HIGHLIGHT_DISCS)

#: The extra lines a highlight term may read beside d(nh_dom) (:data:`~homofac.fit.structures.HIGHLIGHT_LINES`):
#: per kind its projections, brightest light first; the ALS fits each as a line block.
EXTRA_LINE_PROJECTIONS = tuple(line.projections for line in HIGHLIGHT_LINES)

#: Texture roles that are computed (not unknowns of the fit).
FIXED_ROLES = ("diffuse", "cos", "prefiltered", "dfg")


class SumFit(NamedTuple):
    """A fitted sum and how the fit went (the run record's ``solver`` entry and timings)."""

    model: Factorization
    solver: dict
    assemble_s: float
    solve_s: float
    warnings: tuple
    unknowns: int


# ------------------------------------------------------------------------------------------------
# the parts of the target a structure needs


def diffuse_albedo(target: Target) -> np.ndarray | None:
    """kd (3,) of the target's BRDF, or None when the model has no ``kd`` parameter."""
    brdf = target.fn.brdf if target.kind == "lighting" and isinstance(target.fn, Lighting) else target.fn
    if not isinstance(brdf, BRDF) or "kd" not in brdf.params:
        return None
    return np.broadcast_to(np.asarray(brdf.params["kd"], np.float64), (3,)).copy()


def has_diffuse(target: Target) -> bool:
    kd = diffuse_albedo(target)
    return kd is not None and bool(np.any(kd > 0))


def _quantity(target: Target) -> str:
    return target.quantity if target.kind == "brdf" else "lighting"


def _fixed_texture(spec: TextureSpec, target: Target) -> np.ndarray:
    """Texels of a computed texture: the exact irradiance E(n), or the identity line of cos_i."""
    if spec.role in ("diffuse", "diffuse_fitted"):
        if not isinstance(target.fn, Lighting) or target.fn.clamp is not None:
            raise HomofacError("diffuse: the irradiance term needs an unclamped lighting target")
        return _memo(target.fn.env, ("E", spec.mapper, spec.size),
                     lambda: irradiance_map(target.fn.env, spec.mapper, spec.size).astype(np.float32))
    if spec.role in ("prefiltered", "dfg"):
        return _split_sum_textures(target, spec)
    if spec.role == "cos":
        return ((np.arange(spec.size) + 0.5) / spec.size).reshape(1, spec.size, 1).repeat(3, -1).astype(np.float32)
    raise HomofacError(f"texture {spec.name} is fitted, not computed")


def _split_sum_textures(target: Target, spec: TextureSpec) -> np.ndarray:
    """The split sum's P (prefiltered environment) or W (ks (F0 A + B)) at the texel centres."""
    if not split_sum_possible(target, Structure("NR")):
        raise HomofacError("prefiltered: the split sum needs a lighting target of a microfacet model (cook_torrance, ggx)")
    brdf, env = target.fn.brdf, target.fn.env
    if spec.role == "prefiltered":
        d = centres(spec.mapper, spec.size)
        p = _memo(target.fn, ("P", spec.mapper, spec.size),
                  lambda: ss.prefilter(MODELS[brdf.model].microfacet.ndf, brdf.params, env, d))
        return p.reshape(mappers.texture_shape(spec.mapper, spec.size) + (3,)).astype(np.float32)
    a, b = _dfg(target, spec.size)
    ks, f0 = np.asarray(brdf.params["ks"], np.float64), np.asarray(brdf.params["f0"], np.float64)
    return (ks * (f0 * a + b)).reshape(1, spec.size, 3).astype(np.float32)


def _dfg(target: Target, size: int) -> np.ndarray:
    """The split sum's ``(A, B)`` of ``target``'s BRDF at the centres of a line of ``size`` texels
    (:func:`homofac.baselines.split_sum.dfg`), computed once per lighting (:func:`_memo`): every candidate of
    a chooser starts from it (two directional-albedo integrals: 1.2 s CPU the first, with their compilation,
    0.15 s each later one)."""
    x = (np.arange(size) + 0.5) / size
    return _memo(target.fn, ("DFG", int(size)), lambda: np.stack(ss.dfg(target.fn.brdf, x)))


#: Computed textures of the last few lightings (:func:`_memo`): the candidates of a chooser share them.
_MEMO: dict = {}
MEMO_ENTRIES = 16


def _memo(owner, key: tuple, compute: Callable[[], np.ndarray]) -> np.ndarray:
    """``compute()`` (a texture computed from ``owner``: the irradiance of an environment, the split sum's
    prefiltered map of a lighting), once per owner object and ``key`` while it is among the last
    :data:`MEMO_ENTRIES` computed; the entry holds ``owner`` so that its id is not reused meanwhile."""
    k = (id(owner),) + key
    hit = _MEMO.get(k)
    if hit is not None and hit[0] is owner:
        return hit[1]
    value = np.asarray(compute())
    while len(_MEMO) >= MEMO_ENTRIES:
        _MEMO.pop(next(iter(_MEMO)))
    _MEMO[k] = (owner, value)
    return value


def _fixed_correction(target: Target, term: TermSpec) -> np.ndarray:
    if term.kind == "prefiltered":
        return np.ones(3, np.float32)
    kd = diffuse_albedo(target)
    if kd is None:
        raise HomofacError("diffuse: the model has no kd parameter (measured and Phong-lobe-only models); "
                           "leave diffuse out")
    return (kd / np.pi).astype(np.float32)


# ------------------------------------------------------------------------------------------------
# starting solutions (in units of sigma)


def _basis(d: np.ndarray, t: int) -> np.ndarray:
    """A smooth, distinct start for the first factor of extra term t: 1 + (z, x, y, z^2 - 1/3, ...)."""
    if d.ndim == 1 or d.shape[-1] != 3:
        return np.ones(d.shape[0])
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    fs = [z, x, y, z * z - 1 / 3, x * z, y * z, x * y, x * x - y * y]
    return 1.0 + fs[(t - 1) % len(fs)]


def _directions(layout: TextureLayout) -> np.ndarray:
    """Texel-centre directions (n_valid, 3), or scalars (n_valid,) for a line texture."""
    d = np.asarray(mappers.texel_directions(layout.mapper, layout.size), np.float64)
    d = d.reshape(-1, 3) if d.ndim == 3 else d.reshape(-1)
    return d[layout.texel_of_unknown]


def _lookup_at(data, src_mapper: str, dst: TextureLayout) -> np.ndarray:
    """A texture's values at the texel centres of another layout (same mapper kind), (n_valid, 3)."""
    return np.asarray(mappers.lookup(src_mapper, jnp.asarray(data, jnp.float32),
                                     jnp.asarray(_directions(dst), jnp.float32)), np.float64)


def _split_sum_start(target, first: TermSpec, layouts, sigma) -> dict:
    """Term 1 = the split sum's P(r) W(n.v) / sigma (p = 1); a missing w is folded into q by its mean."""
    brdf, env = target.fn.brdf, target.fn.env
    micro = MODELS[brdf.model].microfacet
    line = next((name for proj, name in first.factors if proj == "nv"), None)
    size = layouts[line].size if line is not None else LINE_SIZE
    x = (np.arange(size) + 0.5) / size
    a, b = _dfg(target, size)
    ks, f0 = np.asarray(brdf.params["ks"], np.float64), np.asarray(brdf.params["f0"], np.float64)
    w_line = ks * (f0 * a + b)  # (S_w, 3)
    has_w = any(proj == "nv" for proj, _ in first.factors)
    out = {}
    for proj, name in first.factors:
        lay = layouts[name]
        if proj == "nv":
            out[name] = np.stack([np.interp(_directions(lay), x, w_line[:, c]) for c in range(3)], -1)
        elif proj == "r":
            p = _memo(target.fn, ("P", lay.mapper, lay.size, lay.n_valid), lambda: ss.prefilter(
                micro.ndf, brdf.params, env, _directions(lay).astype(np.float32)))
            out[name] = p * (1.0 if has_w else np.mean(w_line, axis=0)) / sigma
        else:
            out[name] = np.ones((lay.n_valid, 3))
    return out


def _product_start(target, structure, first: TermSpec, layouts, samples, y_fit, sigma, mapper, size, log) -> dict:
    """Term 1 = the log-space product of the parametrization fitted to max(y - fixed, 0), in sigma units."""
    sub = Samples(samples.a, samples.b, np.maximum(y_fit, 0.0).astype(np.float32), samples.val_a[:0],
                  samples.val_b[:0], samples.val_y[:0])
    m = fit_product(target, structure.parametrization, mapper, size, sub, _log_solver(), log).model
    own = m.terms[0]
    J = len(own.factors)
    c = np.asarray(own.correction, np.float64) / sigma
    rename = {}
    for (proj, tex), f in zip(first.factors, own.factors):
        rename.setdefault(f.texture, tex)
    out = {}
    for t in m.textures:
        name = rename[t.name]
        uses = m.uses(t.name)
        out[name] = _lookup_at(t.data, t.mapper, layouts[name]) * c ** (uses / J)
    for proj, tex in first.factors:  # the nv factor the parametrization lacks starts at 1
        out.setdefault(tex, np.ones((layouts[tex].n_valid, 3)))
    return out


def _log_solver():
    return solvers.options({"method": "lsmr", "zeros": "ignore"})


def start(target: Target, structure: Structure, terms, layouts, samples, y_fit, sigma, rule: str, mapper: str,
          size: int, log) -> tuple[dict, str]:
    """Starting texels (valid unknowns, sigma units) of every fitted texture, and the rule used."""
    if rule == "auto":
        rule = "split_sum" if split_sum_possible(target, structure) else "product"
    products = [t for t in terms if t.fitted and not _is_diffuse(t) and not _is_reflection(t)]
    if structure.prefiltered:  # the split sum is kept: every product is a correction, started as extra terms
        rule = "split_sum"
        out = {}
        extra = products
    elif rule == "split_sum":
        if not split_sum_possible(target, structure):
            raise HomofacError("linear.start: split_sum needs a lighting target of a microfacet model "
                               "(cook_torrance, ggx) and a parametrization with an r factor")
        out = _split_sum_start(target, products[0], layouts, sigma)
    else:
        out = _product_start(target, structure, products[0], layouts, samples, y_fit, sigma, mapper, size, log)
    if not structure.prefiltered:
        extra = products[1:]
    kd = diffuse_albedo(target)
    for t, term in enumerate(extra, start=1):
        # an extra term: the first texture smooth and distinct per term, the second 0, the rest 1
        for pos, name in enumerate(dict.fromkeys(tex for _, tex in term.factors)):
            lay = layouts[name]
            if term.factors[0][0] in HIGHLIGHT_PROJECTIONS:  # a highlight term d(x) w(n.v): d 0 (fitted first), w 1
                out[name] = np.zeros((lay.n_valid, 3)) if pos == 0 else np.ones((lay.n_valid, 3))
            elif pos == 0:
                out[name] = np.repeat(_basis(_directions(lay), t)[:, None], 3, -1)
            else:
                out[name] = np.zeros((lay.n_valid, 3)) if pos == 1 else np.ones((lay.n_valid, 3))
    for term in terms:
        if _is_reflection(term):  # the r-only term starts at 0: it fits what the products leave
            out[term.factors[0][1]] = np.zeros((layouts[term.factors[0][1]].n_valid, 3))
        if term.fitted and _is_diffuse(term):
            name = term.factors[0][1]
            spec = TextureSpec(name, layouts[name].mapper, layouts[name].size, "diffuse_fitted")
            out[name] = _fixed_texture(spec, target).reshape(-1, 3)[layouts[name].texel_of_unknown] * (kd / np.pi) / sigma
    return out, rule


def warm_start(previous: Factorization, terms, layouts, sigma) -> dict:
    """Starting texels (valid unknowns, sigma units) from a previous model of the same skeleton: each
    fitted texture's texels, with its term's correction / sigma folded into one texture of the term
    (one read once when there is one, else spread over the reads), so the start reproduces ``previous``."""
    prev = list(previous.terms)
    if len(prev) != len(terms) or any(tuple((f.projection, f.texture) for f in pt.factors) != t.factors
                                      for pt, t in zip(prev, terms)):
        raise HomofacError("refit: the previous model's terms are not those of this structure")
    out = {}
    for pt, term in zip(prev, terms):
        if not term.fitted:
            continue
        names = [tex for _, tex in term.factors]
        once = [n for n in dict.fromkeys(names) if names.count(n) == 1]
        scaled = once[0] if once else names[0]
        c = np.asarray(pt.correction, np.float64) / sigma
        for name in dict.fromkeys(names):
            lay = layouts[name]
            x = np.asarray(previous.texture(name).data, np.float64).reshape(-1, 3)[lay.texel_of_unknown]
            k = names.count(name)
            out[name] = x * (np.sign(c) * np.abs(c) ** (1.0 / k) if name == scaled else 1.0)
    return out


def line_size_of(model: Factorization) -> int:
    """Texels of a sum's ``line`` textures (every line of a sum has one size: :func:`fit_sum`'s
    ``line_size``), :data:`~homofac.fit.structures.LINE_SIZE` when it has none: what a polish or a refit
    of ``model`` keeps."""
    return next((t.size for t in model.textures if t.mapper == "line"), LINE_SIZE)


def with_highlight_context(target: Target, structure: Structure) -> Target:
    """``target`` with the context its highlight terms read (``dominant``, ``dominant1``, ... for the J
    brightest lights, :func:`~homofac.light.brightest_directions`; with ``highlight_disc`` also ``radius``,
    ``radius1``, ... of their discs, :func:`~homofac.light.light_radii`), keys the target already has kept."""
    J = structure.highlights.terms
    keys = [key for _, key in pj.HIGHLIGHTS[:J]]
    radii = [r for _, _, r in pj.HIGHLIGHT_DISCS[:J]] if structure.highlights.disc else []
    missing = [k for k in keys + radii if k not in target.context]
    if not missing:
        return target
    env = getattr(target.fn, "env", None)
    if env is None:
        raise HomofacError(f"highlight_terms read the brightest lights (context {', '.join(keys + radii)}): give "
                           f"the target those, or fit a lighting target of an environment")
    found = brightest_directions(env, len(keys))
    dirs = {k: np.asarray(target.context[k], np.float32) if k in target.context else found[i] for i, k in enumerate(keys)}
    add = {k: found[i] for i, k in enumerate(keys) if k in missing}
    if radii:
        sizes = light_radii(env, np.stack([dirs[k] for k in keys]))
        add.update({r: float(sizes[i]) for i, r in enumerate(radii) if r in missing})
    return Target(target.kind, target.fn, target.quantity, {**target.context, **add})


def _is_diffuse(term: TermSpec) -> bool:
    return len(term.factors) == 1 and term.factors[0] == ("n", "E")


def _is_reflection(term: TermSpec) -> bool:
    return len(term.factors) == 1 and term.factors[0] == ("r", "R")


def split_sum_possible(target, structure) -> bool:
    """Whether the split sum's P(r) W(n.v) (``prefiltered``, ``linear.start: split_sum``) can be computed for
    ``target`` on ``structure``'s parametrization: an unclamped lighting target of a registered microfacet model."""
    return (target.kind == "lighting" and isinstance(target.fn, Lighting) and isinstance(target.fn.brdf, BRDF)
            and MODELS[target.fn.brdf.model].microfacet is not None and target.fn.clamp is None
            and structure.parametrization in ("NR", "NRW", "NRV", "R", "NRO", "RO"))


# ------------------------------------------------------------------------------------------------
# the fit


class Running(NamedTuple):
    """A sum's fit under way (:func:`begin`, :func:`advance`, :func:`finish`): the ALS state in its slots after
    the sweeps run so far, so that a fit can stop after a few sweeps (the candidates' race,
    :func:`homofac.fit.pipeline.execute`) and continue later from where it stopped, with the same compiled
    sweep: ``advance(advance(r, k), m)`` is ``advance(r, k + m)``, sweep for sweep. A fit that is not ALS
    (Levenberg-Marquardt) is finished at :func:`begin` (``state`` None, ``done`` its :class:`SumFit`)."""

    structure: Structure
    state: als.Padded | None  # the padded ALS state (None: finished at begin)
    hist: np.ndarray  # the data objective after each sweep run so far
    converged: bool  # a sweep lowered the objective by less than ``tolerance`` of it: no further sweep runs
    budget: int  # sweeps of the whole fit (``linear.iterations``)
    tolerance: float
    lam: float
    done: Callable  # (state, sweeps run, converged, hist, solve_s) -> SumFit: the model of a state
    solve_s: float = 0.0  # seconds of the sweeps run so far

    @property
    def sweeps(self) -> int:
        """Sweeps run so far."""
        return len(self.hist)


def begin(target: Target, structure: Structure, mapper: str, size: int, samples: Samples,
          options: LinearOptions | None = None, log: Callable[[str], None] | None = None,
          previous: Factorization | None = None, line_size: int = LINE_SIZE,
          sample_weights: np.ndarray | None = None, chunk: int = 0, slots: als.Slots | None = None,
          block: int = 0) -> Running:
    """Steps 1-2 of :func:`fit_sum` (fixed terms, start; for highlight terms their own start) and no sweep
    of the ALS yet: a :class:`Running` fit that :func:`advance` continues and :func:`finish` reads. The
    arguments are :func:`fit_sum`'s."""
    log = log or (lambda msg: None)
    opts = (options or LinearOptions()).resolved()
    if opts.nv_balance > 0 and target.kind != "lighting":
        raise HomofacError(NV_BALANCE_NEEDS_LIGHTING)
    target = with_highlight_context(target, structure)
    t0 = time.perf_counter()
    quantity = _quantity(target)
    specs, terms = skeleton(structure, target.kind, quantity, mapper, size, line_size)
    if structure.diffuse is not None and diffuse_albedo(target) is None:
        _fixed_correction(target, terms[0])
    a, b, y = (np.asarray(v, np.float32) for v in (samples.a, samples.b, samples.y))
    fitted_specs = [s for s in specs if s.role not in FIXED_ROLES]
    layouts = {s.name: texture_layout(s.name, s.mapper, s.size) for s in fitted_specs}
    method = opts.method
    grid = _grid_indices(target, structure, specs, layouts, a, b) if method in ("auto", "als") else None
    if method == "als" and grid is None:
        raise HomofacError("linear.method: als needs lighting NR / NRW / R products on grid samples "
                           "(sampling.kind: grid on the textures' own mapper and size)")
    if method == "auto":
        method = "als" if grid is not None else "levenberg_marquardt"
    if opts.polish > 0 and method != "als":
        raise HomofacError(f"{POLISH_NEEDS_GRID}, not {method}")
    if method == "als" and structure.highlights.table:  # the ALS fits the lines; the table is their product
        prev = None if previous is None else table.separate(previous, line_size)
        run = begin(target, lined(structure), mapper, size, samples, opts, log, previous=prev, line_size=line_size,
                    sample_weights=sample_weights, slots=slots, block=block)
        n_unknowns = sum(lay.n_valid for lay in layouts.values())
        inner = run.done
        return run._replace(structure=structure,
                            done=lambda *args: tabulated(inner(*args), structure, n_unknowns))
    fixed_specs = [s for s in specs if s.role in FIXED_ROLES]
    fixed_data = {s.name: _fixed_texture(s, target) for s in fixed_specs}
    fixed_terms = [t for t in terms if not t.fitted]
    base = np.zeros_like(y)
    if fixed_terms:
        base = np.asarray(_model(target, structure, specs, terms, fixed_data, {}, sigma=np.ones(3), only_fixed=True)
                          .evaluate(a, b), np.float32)
    y_fit = y - base
    sigma = np.sqrt(np.mean(y_fit.astype(np.float64) ** 2, axis=0))
    sigma = np.where(sigma > 0, sigma, 1.0)
    if previous is not None:
        x0, rule = warm_start(previous, terms, layouts, sigma), "previous"
    else:
        x0, rule = start(target, structure, terms, layouts, samples, y_fit, sigma, opts.start, mapper, size, log)
    fitted_terms = [t for t in terms if t.fitted]
    log(f"fitting {structure.label()} in linear space with {method} ({sum(l.n_valid for l in layouts.values())} "
        f"unknowns x 3 channels, {len(a)} samples, start {rule})")
    weights = nv_weights(a, b, y, NV_BINS, opts.nv_balance)
    if sample_weights is not None:
        weights = np.asarray(weights, np.float64) * np.asarray(sample_weights, np.float64)
        weights = (weights / np.mean(weights)).astype(np.float32)
    n_unknowns = int(sum(l.n_valid for l in layouts.values()))

    def done(X, steps, converged, hist, backend, solve_s) -> SumFit:
        bad = [n for n, x in X.items() if not np.all(np.isfinite(x))]
        if bad:
            raise HomofacError(f"the linear-space fit produced non-finite texels in {', '.join(bad)}; "
                               "try a larger linear.laplacian")
        model = _model(target, structure, specs, terms, fixed_data, {n: X[n] for n in X}, sigma=sigma, layouts=layouts)
        warnings = [] if converged or method == "als" else [
            f"linear {method} stopped after {steps} steps without meeting its tolerance"]
        record = {
            "method": method, "backend": backend, "iterations": int(steps), "converged": bool(converged),
            "start": rule, "laplacian": float(opts.laplacian), "nv_balance": float(opts.nv_balance),
            "structure": structure.record(),
            "lookups": int(model.lookups), "objective": float(hist[-1]) if len(hist) else None,
            "objective_start": float(hist[0]) if len(hist) else None, "sigma": [float(s) for s in sigma],
        }
        return SumFit(model, record, assemble_s, solve_s, tuple(warnings), n_unknowns)

    if method != "als":
        assemble_s = time.perf_counter() - t0
        t1 = time.perf_counter()
        X, steps, converged, hist = _fit_lm(target, fitted_specs, fitted_terms, layouts, x0, a, b, y_fit / sigma, opts,
                                            method, weights, chunk)
        sf = done(X, steps, converged, hist, opts.backend, time.perf_counter() - t1)
        return Running(structure, None, np.asarray(hist, np.float32), bool(converged), int(opts.iterations),
                       float(opts.tolerance), float(opts.laplacian), lambda *_: sf)
    p, unpack = _als_start(structure, specs, fitted_terms, layouts, x0, grid, a, b, y_fit / sigma, opts, weights,
                           target.context, log, slots, warm=previous is not None, block=block)
    assemble_s = time.perf_counter() - t0

    def done_als(state, steps, converged, hist, solve_s) -> SumFit:
        return done(unpack(state), steps, converged, hist, "homofac", solve_s)

    return Running(structure, p, np.zeros(0, np.float32), False, int(opts.iterations), float(opts.tolerance),
                   float(opts.laplacian), done_als)


def advance(run: Running, sweeps: int | None = None, log=None) -> Running:
    """``run`` after at most ``sweeps`` more ALS sweeps (default: the rest of its budget), none past its
    budget or after it converged (:func:`als_sweeps`' rule, its objective history continued)."""
    left = run.budget - run.sweeps if sweeps is None else min(int(sweeps), run.budget - run.sweeps)
    if run.state is None or run.converged or left <= 0:
        return run
    t0 = time.perf_counter()
    p, _, converged, hist = als_sweeps(run.state, jnp.float32(run.lam), left, run.tolerance, log, run.hist,
                                       run.budget)
    return run._replace(state=p, hist=hist, converged=converged, solve_s=run.solve_s + time.perf_counter() - t0)


def finish(run: Running) -> SumFit:
    """The :class:`SumFit` of ``run`` at its current state (the model of the sweeps run so far)."""
    return run.done(run.state, run.sweeps, run.converged, run.hist, run.solve_s)


def fit_sum(target: Target, structure: Structure, mapper: str, size: int, samples: Samples,
            options: LinearOptions | None = None, log: Callable[[str], None] | None = None,
            previous: Factorization | None = None, line_size: int = LINE_SIZE,
            sample_weights: np.ndarray | None = None, chunk: int = 0, slots: als.Slots | None = None,
            block: int = 0) -> SumFit:
    """Fit ``structure`` to the training samples in linear space (see the module docstring): :func:`begin`,
    :func:`advance` through ``linear.iterations`` sweeps (or to convergence), :func:`finish`.

    ``sample_weights``: a weight per training sample (the polish's ridge pairs, :mod:`homofac.fit.ridge`),
    times the ``nv_balance`` weights, scaled to mean 1.

    ``line_size``: texels of the ``line`` textures (w(n.v), the highlight lines;
    :func:`homofac.fit.plan.line_sizes`).

    ``previous``: a model of the same structure (a refit, :mod:`homofac.fit.refit`; a race's short fit,
    :func:`continued`): the fitted textures start from its texels (:func:`warm_start`) instead of step 2's
    start, and the highlight terms keep theirs (no start of their own on the data alone).

    ``chunk``: Levenberg-Marquardt steps per compiled call (:func:`homofac.fit.refine.solve`; 0: one call).

    ``slots``: the ALS term slots to pad the structure's terms into (a group with fewer slots than the
    structure has terms: its own count; :func:`als_slots` of every structure a run fits on these samples):
    fits in the same slots share one set of compiled sweep programs; the same fit as without, to float rounding
    (default: the structure's own).

    ``block``: the ALS sums its normal equations over blocks of this many pairs (:func:`homofac.fit.als.blocks`;
    0: one block): its programs are compiled per block size, so a fit on a multiple of an earlier fit's pairs
    in blocks of that count reuses them (:func:`continued`); the same fit to float rounding.
    """
    log = log or (lambda msg: None)
    run = begin(target, structure, mapper, size, samples, options, log, previous, line_size, sample_weights, chunk,
                slots, block)
    return finish(advance(run, None, log))


def strided(samples: Samples, stride: int) -> Samples:
    """Every ``stride``-th training pair of ``samples`` (the validation pairs as they are): the race's short fits."""
    k = max(1, int(stride))
    return samples._replace(a=samples.a[::k], b=samples.b[::k], y=samples.y[::k])


def continued(target: Target, structure: Structure, mapper: str, size: int, samples: Samples,
              options: LinearOptions, log: Callable[[str], None] | None = None, *, stride: int, sweeps: int,
              line_size: int = LINE_SIZE, slots: als.Slots | None = None, head: SumFit | None = None) -> SumFit:
    """A fit on every training pair continued from a short fit on every ``stride``-th pair: ``head`` (default:
    :func:`fit_sum` of ``structure`` with ``sweeps`` ALS sweeps on :func:`strided` ``(samples, stride)``, the
    race's first round), then :func:`fit_sum` from its model (``previous``: no start of its own, the highlight
    terms' included) through ``options.iterations`` sweeps or to convergence. The record is the second fit's
    with the head's start rule and ``head`` (its stride, sweeps, start and the sweeps it ran), which a fresh
    refit repeats (:mod:`homofac.fit.refit`)."""
    log = log or (lambda msg: None)
    if head is None:
        head = fit_sum(target, structure, mapper, size, strided(samples, stride),
                       options.model_copy(update={"iterations": int(sweeps)}), log, line_size=line_size, slots=slots)
    # in blocks of the short fit's pair count: the sweep programs it compiled
    out = fit_sum(target, structure, mapper, size, samples, options, log, previous=head.model, line_size=line_size,
                  slots=slots, block=len(strided(samples, stride).a))
    note = {"stride": int(stride), "sweeps": int(sweeps), "start": head.solver.get("start"),
            "ran": int(head.solver.get("iterations", 0))}
    record = {**out.solver, "start": head.solver.get("start"), "head": note}
    return out._replace(solver=record, assemble_s=head.assemble_s + out.assemble_s, solve_s=head.solve_s + out.solve_s)


def recorded_head(solver: dict | None) -> dict | None:
    """The short fit a sum's recorded ALS fit continued from (:func:`continued`'s ``head`` note), or None."""
    head = (solver or {}).get("head")
    return head if isinstance(head, dict) and "stride" in head and "sweeps" in head else None


def tabulated(fit: SumFit, structure: Structure, unknowns: int | None = None) -> SumFit:
    """``fit`` (of :func:`~homofac.fit.structures.lined` ``(structure)``) with its highlight terms' lines
    ``c(n.i) w(n.v)`` written into the tables of ``structure`` (:func:`homofac.fit.table.tabulate`); the
    record names ``structure`` and keeps the lines' as ``table.lines``. ``unknowns``: the table
    structure's (default: the lines' fit's)."""
    model = table.tabulate(fit.model, structure)
    record = {**fit.solver, "structure": structure.record(), "lookups": int(model.lookups),
              "table": {"lines": fit.solver["structure"], "size": TABLE_SIZE}}
    return SumFit(model, record, fit.assemble_s, fit.solve_s, fit.warnings,
                  fit.unknowns if unknowns is None else int(unknowns))


def _grid_indices(target, structure, specs, layouts, a, b):
    """Unknown indices of the n and r texel each sample reads, when the samples are grid-aligned."""
    if target.kind != "lighting" or structure.parametrization not in GRID_PARAMETRIZATIONS:
        return None
    dirs = [s for s in specs if s.role in ("factor", "diffuse_fitted", "reflection") and s.mapper != "line"]
    if not dirs:
        return None
    lay = layouts[dirs[0].name]
    if any((layouts[s.name].mapper, layouts[s.name].size) != (lay.mapper, lay.size) for s in dirs):
        return None
    r = np.asarray(project(pz.reflection_projection(structure.parametrization), a, b, target.context))
    ia = als.single_texel(lay.mapper, lay.size, a, lay.unknown_of_texel)
    ib = als.single_texel(lay.mapper, lay.size, r, lay.unknown_of_texel) if ia is not None else None
    if ia is None or ib is None:
        return None
    return ia, ib, lay


#: Lighting parametrizations whose sums ``als`` fits on grid samples: each n and r (or r_off) lookup reads
#: one texel.
GRID_PARAMETRIZATIONS = ("NR", "NRW", "R", "NRO", "RO")

#: Why ``linear.polish`` is refused (here for a fit that is not ALS, by the pipeline before sampling).
POLISH_NEEDS_GRID = "linear.polish follows an als fit on grid samples (sampling.kind: grid)"

#: Why ``linear.nv_balance`` is refused for a BRDF target (by the pipeline before sampling, and here).
NV_BALANCE_NEEDS_LIGHTING = "linear.nv_balance weighs the n.v bins of lighting pairs (n, v); a brdf target has none"

#: n.v bins of :func:`nv_weights` (equal width on [0, 1]).
NV_BINS = 8


def nv_weights(a, b, y, bins: int, beta: float) -> np.ndarray:
    """Sample weights ``(mean of |y|^2 over the sample's n.v bin)^-beta``, scaled to mean 1 (``linear.nv_balance``).

    The plain least-squares objective is dominated by the brightest values: for a dielectric the
    Fresnel-boosted grazing views, so the frontal views (a weak specular over the diffuse term) are fitted
    worst, relative to what they show. With beta = 1 each of the ``bins`` n.v bins weighs its squared
    error relative to its own mean square target: every bin's relative error counts by its sample count.
    ``a``, ``b``: normals and views (N, 3); ``y``: the full target values (N, 3) (what the metrics compare).
    """
    if beta <= 0:
        return np.ones(len(y), np.float32)
    nv = np.clip(np.sum(np.asarray(a, np.float64) * np.asarray(b, np.float64), -1), 0.0, 1.0)
    k = np.minimum((nv * bins).astype(np.int64), bins - 1)
    y2 = np.mean(np.asarray(y, np.float64) ** 2, axis=1)
    count = np.bincount(k, minlength=bins)
    ms = np.bincount(k, weights=y2, minlength=bins) / np.maximum(count, 1)
    floor = 1e-12 * max(float(np.max(ms)), 1e-30)
    w = np.maximum(ms, floor)[k] ** (-beta)
    return (w / np.mean(w)).astype(np.float32)


#: Seconds between two progress lines of a long ALS fit.
PROGRESS_S = 3.0


def als_sweeps(p: als.Padded, lam, sweeps: int, tolerance: float, log=None,
               history: np.ndarray | None = None, budget: int | None = None) -> tuple[als.Padded, int, bool, np.ndarray]:
    """At most ``sweeps`` ALS sweeps (:func:`homofac.fit.als.sweep`, its programs compiled per slots and block
    size, called per sweep) of the padded state ``p``, stopping when a sweep lowers the objective f by less than
    ``tolerance * f`` (relative decrease ``(f_prev - f) / f_prev``; 0: never). ``history``: the objective
    after each sweep run before (a fit continued, :func:`advance`): the rule reads it as if the sweeps had
    run in one call. Logs ``ALS sweep i / budget: objective f`` (``budget``: the fit's whole sweep budget, default
    the history's sweeps plus ``sweeps``) at most every :data:`PROGRESS_S` seconds. Returns
    ``(p after, sweeps run in this call, converged, hist)``, hist the whole history (float32: the sweeps'
    own values)."""
    hist: list[float] = [] if history is None else [float(h) for h in np.asarray(history)]
    before = len(hist)
    total = int(budget) if budget is not None else before + int(sweeps)
    converged = False
    shown = time.perf_counter()
    state = p.state
    for i in range(1, int(sweeps) + 1):
        *state, h = als.sweep(*state, p.data, lam, p.masks, slots=p.slots)
        hist.append(float(np.asarray(h)[-1]))
        if len(hist) > 1 and tolerance > 0 and hist[-2] - hist[-1] <= tolerance * abs(hist[-2]):
            converged = True
        if log is not None and (time.perf_counter() - shown >= PROGRESS_S or converged) and i < sweeps:
            log(f"ALS sweep {len(hist)} / {total}: objective {hist[-1]:.6g}" + (" (converged)" if converged else ""))
            shown = time.perf_counter()
        if converged:
            break
    return p._replace(state=tuple(state)), len(hist) - before, converged, np.asarray(hist, np.float32)


def _term_flags(structure, fitted_terms, kinds: tuple[int, ...] | None = None):
    """The ALS flags of the fitted terms (:class:`homofac.fit.als.Flags`), the projections and texture
    names of their factors: ``(flags, names, hprojs, cprojs, cnames, kinds)``; ``kinds``: the extra lines
    (indices into :data:`EXTRA_LINE_PROJECTIONS`) the flags hold (default: those some term reads)."""
    flags_p, flags_q, flags_w, names = [], [], [], []
    rproj = pz.reflection_projection(structure.parametrization)  # r, or r_off for NRO and RO
    flags_h, hprojs, cprojs, cnames = [], [], [], []
    for term in fitted_terms:
        roles = {f[0]: f[1] for f in term.factors}
        flags_p.append("n" in roles)
        flags_q.append(rproj in roles)
        flags_w.append("nv" in roles)
        hproj = next((h for h in HIGHLIGHT_PROJECTIONS if h in roles), None)
        flags_h.append(hproj is not None)
        hprojs.append(hproj)
        # the extra lines of a highlight term (per kind: its projection, or None)
        cprojs.append([next((c for c in kind if c in roles), None) for kind in EXTRA_LINE_PROJECTIONS])
        cnames.append([roles.get(c) for c in cprojs[-1]])
        names.append((roles.get("n"), roles.get(rproj), roles.get("nv"), roles.get(hproj)))
    if kinds is None:
        kinds = tuple(e for e in range(len(EXTRA_LINE_PROJECTIONS)) if any(c[e] for c in cprojs))
    has_h = any(flags_h)
    flags = als.Flags(tuple(flags_p), tuple(flags_q), tuple(flags_w), tuple(flags_h) if has_h else (),
                      tuple(tuple(c[e] is not None for c in cprojs) for e in kinds) if has_h else ())
    return flags, names, hprojs, cprojs, cnames, kinds if has_h else ()


def als_slots(target: Target, structures, mapper: str, size: int, line_size: int = LINE_SIZE) -> als.Slots:
    """The ALS slots (:class:`homofac.fit.als.Slots`) a run's fits on one set of samples share
    (:func:`fit_sum` ``slots=``): the largest count of terms without a line and every kind of extra
    line where some structure has one. Those two groups cost next to nothing padded (an empty plain slot
    adds a term to the texel systems only; an extra line no term reads is skipped at run time), while an
    empty slot carrying a line enlarges every line system; so the structures with the same numbers of
    lined and highlight terms share one compiled sweep (and their highlight terms' start with it)."""
    quantity = _quantity(target)
    out = als.Slots()
    for structure in structures:
        if target.kind != "lighting" or structure.parametrization not in GRID_PARAMETRIZATIONS:
            continue  # not an ALS fit: nothing to share
        s = lined(structure) if structure.highlights.table else structure
        _, terms = skeleton(s, target.kind, quantity, mapper, size, line_size)
        own = als.slots_of(_term_flags(s, [t for t in terms if t.fitted])[0])
        out = out.union(als.Slots(plain=own.plain, extra=len(EXTRA_LINE_PROJECTIONS) if own.extra else 0))
    return out


def _als_start(structure, specs, fitted_terms, layouts, x0, grid, a, b, y, opts: LinearOptions, weights, context=None,
               log=None, slots: als.Slots | None = None, warm: bool = False, block: int = 0):
    """The padded ALS state of the start ``x0`` (with the highlight terms' own start, :func:`_highlight_first`,
    unless ``warm``: ``x0`` is a previous model's fit, :func:`warm_start`, whose highlight terms are kept as
    they are; the samples in :func:`homofac.fit.als.blocks` of ``block``) and the function that reads a state
    back into texels by texture name."""
    ia, ib, lay = grid
    n = lay.n_valid
    # padded to slots with extra lines, every kind of extra line has its place (the masks say which are read)
    every = slots is not None and slots.extra > 0
    flags, names, hprojs, cprojs, cnames, kinds = _term_flags(
        structure, fitted_terms, tuple(range(len(EXTRA_LINE_PROJECTIONS))) if every else None)
    if slots is not None:
        slots = slots.union(als.slots_of(flags))  # the structure's own terms where the slots given have fewer
    K = len(fitted_terms)
    line = next((s.size for s in specs if s.mapper == "line"), LINE_SIZE)  # every line of a sum has one size
    P = np.ones((K, n, 3))
    Q = np.ones((K, n, 3))
    W = np.ones((K, line, 3))
    D = np.ones((K, line, 3))
    C = np.ones((len(kinds), K, line, 3))
    for t, names_t in enumerate(names):
        for name, arr in zip(names_t + tuple(cnames[t][e] for e in kinds), (P, Q, W, D, *C)):
            if name:
                arr[t] = x0[name]
    nb = np.asarray(mappers.neighbours(lay.mapper, lay.size))[lay.texel_of_unknown]
    nb_unk = np.where(nb >= 0, lay.unknown_of_texel[np.maximum(nb, 0)], -1)
    nv = np.clip(np.sum(a * b, -1), 0.0, 1.0)
    vi, vw = als.line_footprint(jnp.asarray(nv, jnp.float32), line)
    hi, hw = _scalar_footprints(hprojs, a, b, context, line)  # each highlight line at its light's nh_dom
    # ... and its extra lines at their scalars (the light's v.h', n.i)
    extra = [_scalar_footprints([c[e] for c in cprojs], a, b, context, line) for e in kinds]
    data = als.GridData(jnp.asarray(ia), jnp.asarray(ib), jnp.asarray(vi, jnp.int32), jnp.asarray(vw, jnp.float32),
                        jnp.asarray(y, jnp.float32), jnp.asarray(np.maximum(nb_unk, 0), jnp.int32),
                        jnp.asarray(nb_unk >= 0, jnp.float32), jnp.asarray(np.sqrt(weights), jnp.float32), hi, hw,
                        tuple(i for i, _ in extra), tuple(w for _, w in extra))
    has_h = bool(flags.h)
    p = als.padded(P, Q, W, data, flags, D if has_h else None, tuple(C) if flags.c else None, slots, block)
    lam = jnp.float32(opts.laplacian)
    if has_h and not warm:
        p = _highlight_first(p, flags, lam, opts, log)

    def unpack(state: als.Padded) -> dict:
        out = als.unpadded(state, flags)
        P, Q, W = out[:3]
        D = out[3] if has_h else None
        C = list(out[4]) if flags.c else []
        X = {}
        for t, names_t in enumerate(names):
            for name, arr in zip(names_t + tuple(cnames[t][e] for e in kinds), (P, Q, W, D, *C)):
                if name:
                    X[name] = arr[t]
        return X

    return p, unpack


def _scalar_footprints(projs, a, b, context, size: int):
    """The line footprints (N, K, 2) on ``size`` texels of each term's scalar projection (None: the term has none; all None:
    (None, None)), sample-major as :class:`~homofac.fit.als.GridData` holds them."""
    if all(p is None for p in projs):
        return None, None
    idx, wts = np.zeros((len(a), len(projs), 2), np.int32), np.zeros((len(a), len(projs), 2), np.float32)
    aj, bj = jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32)
    for t, proj in enumerate(projs):  # one projection per term (at most three lights)
        if proj is not None:
            i_t, w_t = _scalar_footprint(aj, bj, _needed(proj, context), proj=proj, size=size)
            idx[:, t], wts[:, t] = np.asarray(i_t), np.asarray(w_t)
    return jnp.asarray(idx), jnp.asarray(wts)


def _needed(proj: str, context: dict | None) -> dict:
    """The projection context as float32 arrays (jit arguments), checked for the keys ``proj`` reads."""
    missing = [k for k in pj.get(proj).context if k not in (context or {})]
    if missing:
        project(proj, np.zeros((1, 3), np.float32), np.zeros((1, 3), np.float32), context)  # its one-line error
    return {k: jnp.asarray(v, jnp.float32) for k, v in (context or {}).items()}


@jit(kind="lookup", static_argnames=("proj", "size"))
def _scalar_footprint(a, b, context: dict, *, proj: str, size: int):
    """The line footprint (:func:`homofac.fit.als.line_footprint`) of the scalar projection ``proj``."""
    return als.line_footprint(jnp.asarray(project(proj, a, b, context), jnp.float32), size)


@jit(kind="lookup", static_argnames=("proj", "mapper", "size"))
def _lm_lookup(a, b, context: dict, unknown_of_texel, *, proj: str, mapper: str, size: int) -> refine.Lookup:
    """The bilinear footprint of projection ``proj`` on a texture's valid unknowns (missing texels weight 0)."""
    idx, w = mappers.bilinear(mapper, project(proj, a, b, context), size)
    unk = unknown_of_texel[idx]
    return refine.Lookup(jnp.where(unk >= 0, unk, 0).astype(jnp.int32), jnp.where(unk >= 0, w, 0.0))


def highlight_sweeps(opts: LinearOptions) -> int:
    """ALS sweeps of the highlight terms' own start (:func:`_highlight_first`): ``linear.highlight_start``, at
    most ``iterations // 2`` (its default), at least 1."""
    half = max(1, int(opts.iterations) // 2)
    return half if opts.highlight_start is None else max(1, min(int(opts.highlight_start), half))


def _highlight_first(p: als.Padded, flags: als.Flags, lam, opts: LinearOptions, log=None) -> als.Padded:
    """Start the highlight terms (and an n-only diffuse texture) on the data alone, the products absent:
    started together, the products' maps of r take the sun's highlight first and the joint ALS stays
    there (near-mirror / city: 0.50 nrmse against 0.2 from this start). The same compiled sweep as the
    full fit, the other terms' slots masked out, :func:`highlight_sweeps` sweeps. Returns the full start."""
    keep = [h or (pp and not q and not w) for pp, q, w, h in zip(flags.p, flags.q, flags.w, flags.h)]
    on = als.pad(np.asarray(keep, np.float32), p.order, 0.0)  # the kept terms' slots
    m = p.masks
    sub = als.Masks(*(np.asarray(x) * on for x in m[:5]), np.asarray(m.c) * on[None])
    out, *_ = als_sweeps(p._replace(masks=sub), lam, highlight_sweeps(opts), float(opts.tolerance), log)
    keep_slot = on > 0

    def merged(new, old):  # on the host: no program per array shape
        return jnp.asarray(np.where(keep_slot.reshape((-1,) + (1,) * (new.ndim - 1)), np.asarray(new), np.asarray(old)))

    P, Q, W, D, C = out.state
    P0, Q0, W0, D0, C0 = p.state
    return p._replace(state=(merged(P, P0), merged(Q, Q0), merged(W, W0), merged(D, D0),
                             tuple(merged(c, c0) for c, c0 in zip(C, C0))))


def _fit_lm(target, fitted_specs, fitted_terms, layouts, x0, a, b, y, opts: LinearOptions, method: str, weights,
            chunk: int = 0):
    names = [s.name for s in fitted_specs]
    index = {n: k for k, n in enumerate(names)}
    lookups, which, terms = [], [], []
    aj, bj = jnp.asarray(a), jnp.asarray(b)
    for term in fitted_terms:
        ks = []
        for proj, tex in term.factors:
            lay = layouts[tex]
            lookups.append(_lm_lookup(aj, bj, _needed(proj, target.context), jnp.asarray(lay.unknown_of_texel),
                                      proj=proj, mapper=lay.mapper, size=lay.size))
            which.append(index[tex])
            ks.append(index[tex])
        terms.append(tuple(ks))
    sizes = tuple(layouts[n].n_valid for n in names)
    N = len(a)
    edges = []
    for n in names:
        lay = layouts[n]
        nb = np.asarray(mappers.neighbours(lay.mapper, lay.size))[lay.texel_of_unknown]
        nb_unk = np.where(nb >= 0, lay.unknown_of_texel[np.maximum(nb, 0)], -1)
        edges.append(jnp.asarray(refine.edges_of(nb_unk)))
    mu = tuple(jnp.float32(opts.laplacian * N / s) for s in sizes)
    scales = refine.column_scales(lookups, tuple(which), sizes)
    prob = refine.Problem(tuple(lookups), jnp.asarray(y, jnp.float32), tuple(edges), mu, scales,
                          jnp.asarray(np.sqrt(weights), jnp.float32))
    X0 = tuple(jnp.asarray(x0[n], jnp.float32) for n in names)
    X, steps, ok, start_obj, end_obj = refine.solve_objectives(
        X0, prob, tuple(terms), method=method, backend=opts.backend, iterations=int(opts.iterations),
        inner=int(opts.inner_iterations), chunk=chunk)
    return {n: np.asarray(x) for n, x in zip(names, X)}, steps, ok, np.array([start_obj, end_obj])


def _model(target, structure, specs, terms, fixed_data, fitted, *, sigma, layouts=None, only_fixed=False):
    """The Factorization of a skeleton: computed textures as they are, fitted ones from their unknowns."""
    textures, out_terms = [], []
    for s in specs:
        if s.name in fixed_data:
            data = fixed_data[s.name]
        elif only_fixed:
            continue
        else:
            lay = layouts[s.name]
            h, w = lay.shape
            flat = np.zeros((h * w, 3), np.float32)
            flat[lay.texel_of_unknown] = fitted[s.name]
            data = flat.reshape(h, w, 3)
        textures.append(Texture(s.name, s.mapper, s.size, jnp.asarray(data, jnp.float32)))
    for term in terms:
        if only_fixed and term.fitted:
            continue
        corr = np.asarray(sigma, np.float32) if term.fitted else _fixed_correction(target, term)
        out_terms.append(Term(tuple(Factor(p, t) for p, t in term.factors), jnp.asarray(corr, jnp.float32), term.kind))
    if only_fixed and not out_terms:
        out_terms = [Term((), jnp.zeros(3, jnp.float32), "fixed")]
    model = Factorization(target.kind, _quantity(target), tuple(textures), tuple(out_terms), dict(target.context),
                          structure.label())
    return model if only_fixed else precision.normalize(model)




# ------------------------------------------------------------------------------------------------
# choosing the structure (max_lookups, target_error)


#: ``selection.metric`` when a :func:`choose` scores with the ridge stratum (``score``), and the key of
#: each candidate's figure in ``selection.tried``.
RIDGE_METRIC = "validation_ridge_nrmse"
#: How logs and reasons name that figure.
RIDGE_WORDS = "validation nrmse with the ridge stratum"


def scored_by(ridge: bool) -> tuple[str, str]:
    """The record key and the words of the figure the choices read: the ridge stratum's
    (:data:`RIDGE_METRIC`) or the plain validation nrmse."""
    return (RIDGE_METRIC, RIDGE_WORDS) if ridge else ("validation_nrmse", "validation nrmse")


def choose(fit: Callable, structures: list, *, target_error: float | None, max_lookups: int | None,
           analysis: dict | None = None, log: Callable[[str], None] | None = None,
           score: Callable | None = None):
    """Fit ``structures`` (cheapest first) with ``fit(structure) -> Result`` and keep one.

    With ``target_error``: the first whose validation nrmse meets it (else the best, with a warning);
    otherwise (``max_lookups`` alone) the one with the lowest validation nrmse. The choice, every
    candidate's error and lookups, and the analysis that bounded it are recorded as ``selection``.
    ``score(result)``, when given, is the validation nrmse the choice uses instead of the plain one
    (the quality mode's estimate with the ridge stratum, :func:`homofac.fit.polish.ridge_nrmse`),
    recorded beside it as :data:`RIDGE_METRIC`.
    """
    log = log or (lambda msg: None)
    _, what = scored_by(score is not None)
    tried, best = [], None
    for s in structures:
        log(f"structure {s.label()}: fitting")
        res = fit(s)
        plain = float(res.metrics["validation"]["float"]["nrmse"])
        err = plain if score is None else float(score(res))
        met = target_error is not None and err <= target_error
        tried.append({**s.record(), "label": s.label(), "lookups": int(res.model.lookups), "validation_nrmse": plain,
                      **({} if score is None else {RIDGE_METRIC: err}),
                      "fit_s": float(res.timings.get("solve_s", 0.0)), "met": met})
        log(f"structure {s.label()}: {res.model.lookups} lookups, validation nrmse {plain:.4g}"
            + ("" if score is None else f", {RIDGE_WORDS} {err:.4g}"))
        if best is None or err < best[1]:
            best = (res, err, s)
        if met:
            reason = f"{s.label()} is the cheapest structure with {what} {err:.4g} <= {target_error:g}"
            return _selected(res, tried, reason, target_error, max_lookups, True, analysis, score is not None)
    res, err, s = best
    if target_error is not None:
        reason = (f"no structure within {max_lookups} lookups meets target_error {target_error:g}; the best is "
                  f"{s.label()} with {what} {err:.4g}")
        log("warning: " + reason)
        res = res.replace(warnings=tuple(res.warnings) + (reason,))
        return _selected(res, tried, reason, target_error, max_lookups, False, analysis, score is not None)
    reason = f"{s.label()} has the lowest {what} ({err:.4g}) within {max_lookups} lookups"
    log(reason)
    return _selected(res, tried, reason, target_error, max_lookups, True, analysis, score is not None)


def _selected(res, tried, reason, target_error, max_lookups, met, analysis, ridge: bool):
    key, _ = scored_by(ridge)
    return res.replace(selection={
        "target_error": None if target_error is None else float(target_error), "max_lookups": max_lookups,
        "metric": RIDGE_METRIC if ridge else "validation.float.nrmse", "met": met,
        "chosen": tried[-1] if met and target_error is not None else min(tried, key=lambda t: t[key]),
        "reason": reason, "tried": tried,
        **({"analysis": analysis} if analysis else {}),
    })


__all__ = ["RIDGE_METRIC", "RIDGE_WORDS", "Running", "SumFit", "advance", "begin", "choose", "continued", "finish", "diffuse_albedo", "fit_sum", "nv_weights", "has_diffuse",
           "line_size_of", "recorded_head", "scored_by", "start", "strided", "tabulated", "warm_start"]
