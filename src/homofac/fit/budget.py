"""Memory estimate of a run, and the refusal of configs that would not fit (issue 6).

:func:`estimate` counts the arrays a run holds at its peak, from the config alone (no sampling):

* training pairs M (counted from the sampling grids, valid pairs only) and validation pairs V;
* samples: a, b, y float32 (36 bytes per pair) plus the flattened grouped arrays (another 36);
* the system: ELL columns int32 and weights float32 with K = 4 J entries per row (8 K bytes), the
  log right-hand side (12), and the solver's gathered (M, K, 3) float32 operand in the forward and the
  transposed product (2 x 12 K bytes), plus about 8 solver vectors of (M + n, 3) float32;
* the lighting computation: one lax.map step of at most 2^22 light terms per group, with about 16
  float32 temporaries each (the lobe form's per-light work), plus the light arrays;
* ``direct``: the dense (n, n) float64 normal matrix and its Cholesky factor;
* a fixed 1 GB for the JAX/XLA runtime, compilation and compiled code (measured 0.4-0.9 GB).

It aims at the right order of magnitude and errs high (the tests check it against a measured peak).
:func:`check` refuses a config whose estimate exceeds the limit (``limits.memory_gb``; default half of
the machine's RAM) before any work starts, with the estimate in the message.
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import HomofacError

GB = 1024**3
RUNTIME_BYTES = int(1.0 * GB)


def physical_memory() -> int:
    """Total RAM in bytes (os.sysconf); 8 GB when it cannot be read."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 8 * GB


def default_limit() -> int:
    """Half of the machine's RAM."""
    return physical_memory() // 2


def _grid_count(mapper: str, size: int, hemisphere: bool) -> int:
    """Valid directions of a texel grid without building it: area fraction of the mapper's valid texels."""
    from ..param import mappers

    m = mappers.get(mapper)
    s = min(int(size), 64)  # the fraction is the same at any size; count it on a small table
    frac = float(np.mean(mappers.valid_mask(m, s)))
    count = frac * np.prod(mappers.texture_shape(m, int(size)))
    if hemisphere and m.covers_sphere:
        count /= 2
    return int(count)


def estimate(cfg) -> dict:
    """Estimated peak bytes of the run a :class:`~homofac.fit.config.Config` describes, by part."""
    from ..param import mappers
    from ..param import parametrizations as pz
    from .pipeline import default_mapper

    kind = cfg.target.kind
    p = pz.get(cfg.parametrization, kind) if cfg.target_error is None else None
    j = p.J if p else 4
    t = p.T if p else 4
    s = cfg.sampling
    smapper = s.mapper or default_mapper(kind)
    if s.kind == "random":
        m = s.count or s.size**2 * (s.view_size or s.size) ** 2 // 4
    elif s.kind == "latlong":
        m = (s.size * 2 * s.size) * ((s.view_size or s.size) * 2 * (s.view_size or s.size)) // (8 if kind == "brdf" else 2)
    else:
        hemi = kind == "brdf"
        m = _grid_count(smapper, s.size, hemi) * _grid_count(smapper, s.view_size or s.size, hemi)
        m = m if hemi else m // 2
    v = s.validation
    mapper = cfg.mapper or default_mapper(kind)
    n = t * int(np.prod(mappers.texture_shape(mappers.get(mapper), cfg.texture_size)))
    k = 4 * j
    parts = {
        "samples": (m + v) * 72,
        "system": m * (8 * k + 12) + n * 5 * 8,
        "solver": m * 2 * 12 * k + 8 * (m + n) * 12,
        "runtime": RUNTIME_BYTES,
    }
    if kind == "lighting":
        res = cfg.target.environment.resolution if cfg.target.environment else 32
        lights = 6 * res * res + len(cfg.target.environment.lights if cfg.target.environment else [])
        parts["lighting"] = (1 << 22) * 16 * 4 + lights * 200
    if cfg.solver.method == "direct":
        parts["direct"] = 2 * n * n * 8
    if cfg.solver.method in ("qmr", "cg"):
        parts["scipy"] = m * k * 16 * 3  # CSR float64 of the (augmented) matrix and its transpose
    parts["total"] = sum(parts.values())
    parts["pairs"] = m
    parts["unknowns"] = n
    return parts


def check(cfg, limit_bytes: int | None = None) -> dict:
    """Refuse (HomofacError, one line) when the estimate exceeds the limit; returns the estimate."""
    est = estimate(cfg)
    limit = limit_bytes if limit_bytes is not None else default_limit()
    if est["total"] > limit:
        raise HomofacError(
            f"estimated memory {est['total'] / GB:.1f} GB ({est['pairs']:,} training pairs, {est['unknowns']:,} "
            f"unknowns) exceeds the limit {limit / GB:.1f} GB (limits.memory_gb); reduce sampling.size, "
            "texture_size or target.environment.resolution, or raise the limit"
        )
    return est


__all__ = ["GB", "check", "default_limit", "estimate", "physical_memory"]
