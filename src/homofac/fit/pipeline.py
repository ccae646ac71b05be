"""``factorize``: target -> samples -> system -> solve -> textures -> metrics (DESIGN.md, data flow).

Each stage is a pure function in its own module; this composes them and records timings, so a
notebook can call the stages one by one and the CLI is just this function driven by a config.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable, NamedTuple

import jax.numpy as jnp
import numpy as np

from ..errors import HomofacError
from ..param import mappers
from ..param import parametrizations as pz
from . import cache, precision, sampling
from .factorization import Factorization, evaluate_textures
from .metrics import metrics
from .solvers import solve
from .start import starting_solution
from .system import build_system, make_layout
from .target import Target, evaluate, evaluate_grouped

#: Default sampling settings (DESIGN.md config).
DEFAULT_SAMPLING = {
    "kind": "texels", "size": 24, "view_size": None, "validation": 20000, "seed": 0, "count": 0, "mapper": None,
    "cache": True,
}
#: Default solver settings (DESIGN.md config).
DEFAULT_SOLVER = {
    "method": "lsmr", "tolerance": 1e-6, "max_iterations": 1000, "laplacian": 1.0, "epsilon": 1e-5, "levels": 1,
}
#: Largest texture size accepted (a 4096^2 cube has 100M unknowns: nothing here would finish).
MAX_TEXTURE_SIZE = 1024


class Samples(NamedTuple):
    """Training and validation pairs with their exact target values (float32 numpy)."""

    a: np.ndarray
    b: np.ndarray
    y: np.ndarray
    val_a: np.ndarray
    val_b: np.ndarray
    val_y: np.ndarray


def default_mapper(kind: str) -> str:
    """parabolic for BRDF targets (hemisphere), dual_paraboloid for lighting (sphere)."""
    return "parabolic" if kind == "brdf" else "dual_paraboloid"


def check_mapper(kind: str, mapper: str, parametrization: pz.Parametrization) -> None:
    """Lighting projections span the whole sphere: refuse hemisphere-only mappers for them."""
    m = mappers.get(mapper)
    if kind == "lighting" and not m.covers_sphere:
        raise HomofacError(
            f"mapper {mapper} covers only the upper hemisphere; lighting textures need dual_paraboloid, cube or octahedral"
        )


def check_size(texture_size: int) -> None:
    """Texture sizes from 4 to MAX_TEXTURE_SIZE."""
    if not isinstance(texture_size, (int, np.integer)) or isinstance(texture_size, bool):
        raise HomofacError(f"texture_size must be an integer, got {texture_size!r}")
    if texture_size < 4:
        raise HomofacError(f"texture_size must be at least 4, got {texture_size}")
    if texture_size > MAX_TEXTURE_SIZE:
        raise HomofacError(f"texture_size {texture_size} is absurdly large (at most {MAX_TEXTURE_SIZE})")


def draw_samples(target: Target, parametrization: str, sampling_cfg: dict, log: Callable = print) -> Samples:
    """Sample the target on training pairs (thesis §4.2 / §5.6) and on a seeded validation set.

    With ``sampling_cfg["cache"]`` (the default) the samples are read from, or written to, the on-disk
    cache of :mod:`homofac.fit.cache`, keyed by a hash of the target and the sampling settings.
    """
    s = {**DEFAULT_SAMPLING, **(sampling_cfg or {})}
    k = cache.key(target, s, parametrization) if s["cache"] else None
    if k is not None:
        hit = cache.load(k)
        if hit is not None:
            log(f"samples from cache {k[:12]} ({len(hit.a)} training pairs)")
            return hit
    samples = _draw(target, parametrization, s, log)
    if k is not None:
        cache.store(k, samples)
    return samples


def _draw(target: Target, parametrization: str, s: dict, log: Callable) -> Samples:
    smapper = s["mapper"] or default_mapper(target.kind)
    if target.kind == "lighting":
        # grouped by normal: per-normal work (weights, frames, diffuse, horizon culling) done once
        groups = sampling.grouped_pairs(s["kind"], int(s["size"]), mapper=smapper, count=int(s["count"]),
                                        seed=int(s["seed"]), view_size=s["view_size"])
        pairs = groups.flatten()
        if len(pairs) == 0:
            raise HomofacError("sampling produced no valid direction pairs; increase sampling.size")
        log(f"sampling {len(pairs)} training pairs ({len(groups.normals)} normals)")
        y = np.asarray(evaluate_grouped(target, groups))
        vgroups = sampling.grouped_random(int(s["validation"]), int(s["seed"]) + 1)
        val = vgroups.flatten()
        val_y = np.asarray(evaluate_grouped(target, vgroups)) if len(val) else np.zeros((0, 3), np.float32)
        return Samples(pairs.a, pairs.b, y, val.a, val.b, val_y)
    pairs = sampling.sample_pairs(
        target.kind, s["kind"], int(s["size"]), mapper=smapper, parametrization=parametrization,
        count=int(s["count"]), seed=int(s["seed"]), view_size=s["view_size"],
    )
    if len(pairs) == 0:
        raise HomofacError("sampling produced no valid direction pairs; increase sampling.size")
    log(f"sampling {len(pairs)} training pairs")
    y = np.asarray(evaluate(target, pairs.a, pairs.b))
    val = sampling.random_pairs(target.kind, int(s["validation"]), int(s["seed"]) + 1)
    val_y = np.asarray(evaluate(target, val.a, val.b)) if len(val) else np.zeros((0, 3), np.float32)
    return Samples(pairs.a, pairs.b, y, val.a, val.b, val_y)


def _check_values(y: np.ndarray, what: str) -> None:
    if not np.all(np.isfinite(y)):
        bad = int(np.sum(~np.isfinite(y)))
        raise HomofacError(f"the target gave {bad} non-finite values on the {what} samples")
    if not np.any(y > 0):
        raise HomofacError(f"the target is zero on every {what} sample: nothing to factor")


def factorize(
    target: Target,
    parametrization: str,
    *,
    mapper: str | None = None,
    texture_size: int = 32,
    sampling: dict | None = None,
    solver: dict | None = None,
    samples: Samples | None = None,
    config: dict | None = None,
    target_info: dict | None = None,
    log: Callable[[str], None] | None = None,
    keep_samples: bool = False,
) -> Factorization:
    """Factor ``target`` into textures: the whole pipeline of thesis §6.1.8 (steps 1-7).

    Args:
        target: a :class:`~homofac.fit.target.Target` (``brdf_target`` or ``lighting_target``).
        parametrization: ``IV``, ``GSHD``, ``PQP`` (BRDF) or ``N``, ``R``, ``NR``, ``NRV``, ``NRHD``.
        mapper: direction mapper of the textures (default: parabolic for BRDF, dual_paraboloid for lighting).
        texture_size: S of the mapper table (4 ... 1024).
        sampling: ``{kind, size, view_size, validation, seed, count, mapper, cache}`` (DESIGN.md config
            ``sampling``; ``cache``: reuse samples on disk, see :mod:`homofac.fit.cache`).
        solver: ``{method, tolerance, max_iterations, laplacian, epsilon, levels}``; ``levels`` > 1 solves at
            S / 2^(levels-1) first and refines each doubled size from the upsampled result.
        samples: precomputed :class:`Samples` (skip sampling, e.g. to compare solvers).
        config: the resolved config to record in the result.
        target_info: description of the target to record.
        log: progress callback (one line per stage); silent when None.
        keep_samples: keep the samples on the result (``fac.samples``, written as samples.npz).
    """
    log = log or (lambda msg: None)
    t_start = time.perf_counter()
    p = pz.get(parametrization, target.kind)
    mapper = mapper or default_mapper(target.kind)
    check_mapper(target.kind, mapper, p)
    check_size(texture_size)
    scfg = {**DEFAULT_SOLVER, **(solver or {})}
    if not (scfg["laplacian"] >= 0 and np.isfinite(scfg["laplacian"])):
        raise HomofacError(f"solver.laplacian must be a finite number >= 0, got {scfg['laplacian']}")

    t0 = time.perf_counter()
    if samples is None:
        samples = draw_samples(target, parametrization, sampling or {}, log)
    sample_s = time.perf_counter() - t0
    _check_values(samples.y, "training")

    levels = level_sizes(int(texture_size), int(scfg["levels"]))
    dtype = jnp.result_type(float)
    a, b, y = (jnp.asarray(v, dtype) for v in (samples.a, samples.b, samples.y))
    x0 = None
    assemble_s = solve_s = 0.0
    iterations = 0
    warnings = []
    for size in levels:
        # multi-resolution (thesis §3.1.2): solve small, upsample the log textures, refine with the same samples
        log(f"assembling the system ({p.J} factors, {p.T} textures of {mapper} {size})")
        t0 = time.perf_counter()
        coarse = (layout, res.x) if x0 is not None else None
        layout = make_layout(mapper, size, p.T)
        sys, alpha = build_system(p, layout, a, b, y, eps=float(scfg["epsilon"]), context=target.context)
        x0 = starting_solution(sys, layout, p.J) if coarse is None else upsample(coarse[0], coarse[1], layout)
        assemble_s += time.perf_counter() - t0
        log(f"solving with {scfg['method']} ({layout.n_unknowns} unknowns x 3 channels, {len(samples.a)} rows)")
        res = solve(
            sys, x0, method=scfg["method"], laplacian=float(scfg["laplacian"]),
            tolerance=float(scfg["tolerance"]), max_iterations=int(scfg["max_iterations"]),
        )
        solve_s += res.seconds
        iterations += res.iterations
        if not res.converged:
            msg = (f"solver {res.method} did not converge in {res.iterations} iterations at size {size} "
                   f"(residual {res.residual:.3g})")
            warnings.append(msg)
            log("warning: " + msg)

    textures_log = unpack(res.x, layout)
    textures = precision.exponentiate(textures_log, alpha, p.J)
    textures, correction = precision.normalize(p, textures, layout.valid.reshape(layout.shape))
    fac = Factorization(
        kind=target.kind, parametrization=p.name, mapper=mapper, texture_size=int(texture_size),
        textures=tuple(textures), correction=correction, context=dict(target.context),
        quantity=target.quantity if target.kind == "brdf" else "lighting",
    )
    log("measuring errors")
    mets = measure(fac, target, samples, eps=float(scfg["epsilon"]))
    total_s = time.perf_counter() - t_start
    return dataclasses.replace(
        fac,
        **{
            "metrics": mets,
            "solver": {
                "method": res.method, "iterations": iterations, "converged": not warnings, "levels": levels,
                "residual": res.residual, "objective": res.objective,
                "tolerance": float(scfg["tolerance"]), "max_iterations": int(scfg["max_iterations"]),
                "laplacian": float(scfg["laplacian"]), "epsilon": float(scfg["epsilon"]),
            },
            "timings": {"sample_s": sample_s, "assemble_s": assemble_s, "solve_s": solve_s, "total_s": total_s},
            "counts": {
                "train": int(len(samples.a)), "validation": int(len(samples.val_a)),
                "unknowns": int(layout.n_unknowns), "lights": int(getattr(target.fn, "n_lights", 0)),
            },
            "config": config or {},
            "target_info": target_info or {},
            "warnings": tuple(warnings),
            "samples": samples if keep_samples else None,
        }
    )


def level_sizes(texture_size: int, levels: int) -> list[int]:
    """Texture sizes of a multi-resolution solve, coarsest first: S / 2^(levels-1), ..., S (at least 4)."""
    if levels < 1:
        raise HomofacError(f"solver.levels must be at least 1, got {levels}")
    sizes = [texture_size]
    for _ in range(levels - 1):
        if sizes[0] // 2 < 4 or sizes[0] % 2:
            break
        sizes.insert(0, sizes[0] // 2)
    return sizes


def upsample(coarse_layout, x, fine_layout):
    """Starting solution on a finer layout: the coarse log textures looked up (bilinearly, through the
    mapper) at the directions of the fine texels (thesis §3.1.2, multi-resolution start)."""
    m = mappers.get(fine_layout.mapper)
    dirs = jnp.asarray(mappers.texel_directions(m, fine_layout.size).reshape(-1, 3)[fine_layout.texel_of_unknown])
    out = []
    for t in unpack(x, coarse_layout):
        out.append(mappers.lookup(m, t, dirs.astype(t.dtype)))
    return jnp.concatenate(out, axis=0)


def unpack(x, layout) -> list:
    """Split the unknown vector (n, 3) into log textures (H, W, 3); invalid texels get 0."""
    h, w = layout.shape
    out = []
    for k in range(layout.n_textures):
        xk = x[k * layout.n_valid : (k + 1) * layout.n_valid]
        t = jnp.zeros((h * w, 3), x.dtype).at[jnp.asarray(layout.texel_of_unknown)].set(xk)
        out.append(t.reshape(h, w, 3))
    return out


def measure(fac: Factorization, target: Target, samples: Samples, eps: float = 1e-5) -> dict:
    """Pinned metrics on training and validation samples, float and 8-bit textures.

    ``quantized`` is the thesis' RMS II (§4.3, §6.1.8 step 10): the 8-bit RGBA textures with the
    prescale and alpha trick of ``fac.encoding`` (or the stored ``fac.rgba8``) and their decode rule.
    """
    if fac.rgba8 is None:
        fac = dataclasses.replace(fac, rgba8=fac.encoded())  # encode once, not per chunk
    out = {}
    for split, a, b, y in (
        ("train", samples.a, samples.b, samples.y),
        ("validation", samples.val_a, samples.val_b, samples.val_y),
    ):
        if len(a) == 0:
            continue
        aj, bj = jnp.asarray(a), jnp.asarray(b)
        exact = target.shown(aj, jnp.asarray(y))
        out[split] = {}
        for name, quant in (("float", False), ("quantized", True)):
            approx = _eval_chunked(fac, aj, bj, quant)
            out[split][name] = metrics(target.shown(aj, approx), exact, eps)
    return out


def _eval_chunked(fac: Factorization, a, b, quantized: bool, chunk: int = 65536):
    parts = [fac.evaluate(a[i : i + chunk], b[i : i + chunk], quantized=quantized) for i in range(0, a.shape[0], chunk)]
    return jnp.concatenate(parts, axis=0)


__all__ = ["factorize", "draw_samples", "measure", "unpack", "Samples", "evaluate_textures"]
