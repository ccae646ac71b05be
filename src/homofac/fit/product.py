"""One product in log space (thesis §3.1.2, §6.1.8 steps 1-7): system, start, solve, textures.

``log y = sum_j bilinear(x_k(j), pi_j(a, b))`` (eq. 26, 30-37) is linear in the log texels; it is
assembled as ELL rows (:mod:`.system`), started from the averaging algorithm (:mod:`.start`), solved by a
registered solver (:mod:`.solvers`), optionally coarse to fine (``solver.levels``), exponentiated and
normalized (:mod:`.precision`) into the one-term model of :class:`~homofac.factorization.Factorization`.
"""

from __future__ import annotations

import time
from typing import Callable, NamedTuple

import jax.numpy as jnp
import numpy as np

from ..errors import HomofacError
from ..factorization import Factorization
from ..param import mappers
from ..param import parametrizations as pz
from ..target import Target
from . import precision, solvers
from .samples import Samples
from .solvers import SolveResult, SolverOptions
from .start import starting_solution
from .system import Layout, build_system, parametrization_layout


class ProductFit(NamedTuple):
    """A fitted product and how the solve went (the run record's ``solver`` entry and timings)."""

    model: Factorization
    solver: dict
    assemble_s: float
    solve_s: float
    warnings: tuple
    layout: Layout


def check_mapper(kind: str, mapper: str) -> None:
    """Lighting projections span the whole sphere: refuse hemisphere-only mappers for them."""
    m = mappers.get(mapper)
    if m.scalar:
        raise HomofacError(f"mapper {mapper} is the 1D mapper of scalar factors; choose a direction mapper")
    if kind == "lighting" and not m.covers_sphere:
        raise HomofacError(
            f"mapper {mapper} covers only the upper hemisphere; lighting textures need dual_paraboloid, cube or octahedral"
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


def unpack(x, layout: Layout) -> list:
    """Split the unknown vector (n, 3) into log textures (H, W, 3); invalid texels get 0."""
    out = []
    for tex in layout.textures:
        h, w = tex.shape
        xk = x[tex.offset : tex.offset + tex.n_valid]
        t = jnp.zeros((h * w, 3), x.dtype).at[jnp.asarray(tex.texel_of_unknown)].set(xk)
        out.append(t.reshape(h, w, 3))
    return out


def upsample(coarse: Layout, x, fine: Layout):
    """Starting solution on a finer layout: the coarse log textures looked up (bilinearly, through the
    mapper) at the directions of the fine texels (thesis §3.1.2, multi-resolution start)."""
    out = []
    for ct, ft, t in zip(coarse.textures, fine.textures, unpack(x, coarse)):
        dirs = mappers.texel_directions(ft.mapper, ft.size)
        dirs = dirs.reshape((-1,) + dirs.shape[2:])[ft.texel_of_unknown]
        out.append(mappers.lookup(ct.mapper, t, jnp.asarray(dirs).astype(t.dtype)))
    return jnp.concatenate(out, axis=0)


def zeros_rule(target: Target, solver: SolverOptions) -> str:
    """``solver.zeros`` resolved: ``auto`` ignores zero samples of measured (merl) BRDFs, biases otherwise."""
    rule = getattr(solver, "zeros", "auto")
    if rule != "auto":
        return rule
    return "ignore" if target.kind == "brdf" and getattr(target.fn, "model", None) == "merl" else "bias"


def fit_product(
    target: Target,
    parametrization: str,
    mapper: str,
    texture_size: int,
    samples: Samples,
    solver: SolverOptions,
    log: Callable[[str], None] | None = None,
) -> ProductFit:
    """Fit one product of ``parametrization`` to the training samples in log space (see the module doc)."""
    log = log or (lambda msg: None)
    p = pz.get(parametrization, target.kind)
    check_mapper(target.kind, mapper)
    dtype = jnp.result_type(float)
    a, b, y = (np.asarray(v) for v in (samples.a, samples.b, samples.y))
    ignored = 0
    if zeros_rule(target, solver) == "ignore":
        # Measured BRDFs hold zeros (missing or clipped data): in log space one zero pulls the textures
        # toward log(eps) (eq. 26); leaving such samples out removes that bias and the eps parameter.
        keep = np.all(y > 0, axis=1)
        ignored = int(np.size(keep) - np.count_nonzero(keep))
        if not keep.any():
            raise HomofacError("solver.zeros: ignore left no training sample with all channels > 0")
        a, b, y = a[keep], b[keep], y[keep]
    a, b, y = (jnp.asarray(v, dtype) for v in (a, b, y))
    x0 = layout = res = None
    assemble_s = solve_s = 0.0
    iterations = 0
    warnings: list[str] = []
    sizes = level_sizes(int(texture_size), int(solver.levels))
    for size in sizes:
        # multi-resolution (thesis §3.1.2): solve small, upsample the log textures, refine with the same samples
        log(f"assembling the system ({p.J} factors, {p.T} textures of {mapper} {size})")
        t0 = time.perf_counter()
        coarse = (layout, res.x) if res is not None else None
        layout = parametrization_layout(p, mapper, size)
        sys, alpha = build_system(p, layout, a, b, y, eps=float(solver.epsilon), context=target.context)
        x0 = starting_solution(sys, layout, p.J) if coarse is None else upsample(coarse[0], coarse[1], layout)
        assemble_s += time.perf_counter() - t0
        log(f"solving with {solver.method} ({layout.n_unknowns} unknowns x 3 channels, {len(a)} rows)")
        res = solvers.solve(sys, x0, solver)
        solve_s += res.seconds
        iterations += res.iterations
        if not res.converged:
            msg = (f"solver {res.method} did not converge in {res.iterations} iterations at size {size} "
                   f"(residual {res.residual:.3g})")
            warnings.append(msg)
            log("warning: " + msg)
    model = _model(target, p, layout, res, alpha)
    record = {
        "method": res.method, "iterations": iterations, "converged": not warnings, "levels": sizes,
        "residual": res.residual, "objective": res.objective, "tolerance": float(solver.tolerance),
        "max_iterations": int(solver.max_iterations), "laplacian": float(solver.laplacian),
        "epsilon": float(solver.epsilon), "zeros": zeros_rule(target, solver), "ignored_samples": ignored,
    }
    return ProductFit(model, record, assemble_s, solve_s, tuple(warnings), layout)


def _model(target: Target, p: pz.Parametrization, layout: Layout, res: SolveResult, alpha) -> Factorization:
    textures = precision.exponentiate(unpack(res.x, layout), alpha, p.J)
    main = next(t for t in layout.textures if not mappers.get(t.mapper).scalar) if any(
        not mappers.get(t.mapper).scalar for t in layout.textures) else layout.textures[0]
    line = next((t.size for t in layout.textures if mappers.get(t.mapper).scalar), None)
    model = Factorization.product(
        target.kind, target.quantity if target.kind == "brdf" else "lighting", p.name, main.mapper, main.size,
        textures, jnp.ones((3,), textures[0].dtype), context=dict(target.context), line_size=line,
    )
    return precision.normalize(model)


__all__ = ["ProductFit", "check_mapper", "fit_product", "level_sizes", "unpack", "upsample", "zeros_rule"]
