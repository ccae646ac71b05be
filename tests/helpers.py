"""Hand-built factorizations shared by the tests (made-up smooth textures, known structure)."""

from __future__ import annotations

import contextlib

import jax
import jax.numpy as jnp
import numpy as np

from homofac.bake import Bake
from homofac.bake.build import layer_size
from homofac.bake.model import diffuse_sh9
from homofac.bake.plan import plan as make_plan
from homofac.factorization import Factor, Factorization, Term, Texture
from homofac.param import mappers


@contextlib.contextmanager
def optimized_xla():
    """Compile with XLA's optimizations on inside the block (tests/conftest.py compiles the fast tests at -O0),
    then restore the test's setting: for the fixtures that make bakes, whose prefilter programs run about five
    times longer at -O0 than they take to compile optimized (the session's five bakes: 22.5 s CPU at -O0, 10.7 s
    optimized; docs/notes/suite.md)."""
    was = jax.config.read("jax_disable_most_optimizations")
    jax.config.update("jax_disable_most_optimizations", False)
    try:
        yield
    finally:
        jax.config.update("jax_disable_most_optimizations", was)


def smooth_texture(mapper: str, S: int, seed: int, lo=0.2, signed=False) -> np.ndarray:
    """A smooth positive (or signed) RGB texture: a low-order function of the texel directions."""
    rng = np.random.default_rng(seed)
    d = np.asarray(mappers.texel_directions(mapper, S), np.float64)
    if d.ndim == 2:  # line: scalars
        d = np.stack([d, d * 0, d * 0], -1)
    c = rng.normal(size=(3, 3))
    t = lo + 0.5 * (1 + np.tanh(d @ c))
    if signed:
        t = t - 0.6
    return mappers.dilate(mapper, S, t.astype(np.float32))


def two_terms(S: int = 8, signed: bool = False) -> Factorization:
    """kd/pi E(n) + P(r) W(n.v): the shape of split-sum, with smooth made-up textures."""
    textures = (
        Texture("E", "dual_paraboloid", S, jnp.asarray(smooth_texture("dual_paraboloid", S, 1))),
        Texture("P", "dual_paraboloid", S, jnp.asarray(smooth_texture("dual_paraboloid", S, 2, signed=signed))),
        Texture("W", "line", 16, jnp.asarray(smooth_texture("line", 16, 3))),
    )
    terms = (
        Term((Factor("n", "E"),), jnp.asarray([0.1, 0.09, 0.08]), "irradiance"),
        Term((Factor("r", "P"), Factor("nv", "W")), jnp.asarray([1.0, 0.8, 0.4]), "prefiltered"),
    )
    return Factorization("lighting", "lighting", textures, terms, {}, "two_terms")


def nrw_sum(K: int = 2, S: int = 8, line: int = 32, seed: int = 10, normal: bool | tuple = True) -> Factorization:
    """sum_t p_t(n) q_t(r) w_t(n.v) with smooth positive made-up textures (the structure of ``NR`` with
    ``nv_factor`` and ``terms: K``, texture names n0, r0, w0, ...); ``normal=False``: without p_t(n)
    (the structure of ``R`` with ``nv_factor``); a tuple: per term (``(True, False)``: the structure of
    ``NR`` with ``nv_factor`` and ``rw_terms: 1``)."""
    textures, terms = [], []
    flags = normal if isinstance(normal, tuple) else (normal,) * K
    for t in range(K):
        s = "" if K == 1 else str(t)
        n = [Texture(f"n{s}", "dual_paraboloid", S, jnp.asarray(smooth_texture("dual_paraboloid", S, seed + 3 * t)))]
        textures += (n if flags[t] else []) + [
            Texture(f"r{s}", "dual_paraboloid", S, jnp.asarray(smooth_texture("dual_paraboloid", S, seed + 3 * t + 1))),
            Texture(f"w{s}", "line", line, jnp.asarray(smooth_texture("line", line, seed + 3 * t + 2))),
        ]
        factors = ((Factor("n", f"n{s}"),) if flags[t] else ()) + (Factor("r", f"r{s}"), Factor("nv", f"w{s}"))
        terms.append(Term(factors, jnp.asarray([1.0, 0.7, 0.5]) / (t + 1), "fitted"))
    return Factorization("lighting", "lighting", tuple(textures), tuple(terms), {}, "nrw_sum")


def visible_pairs(count: int, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """``count`` random normals and views with n.v >= 0 (float64), seeded."""
    rng = np.random.default_rng(seed)
    n = rng.normal(size=(count, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    v = rng.normal(size=(count, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return n, np.where(np.sum(n * v, 1, keepdims=True) < 0, -v, v)


#: Metrics that are not continuous in the textures: the largest error over pairs after 8-bit rounding jumps by a
#: quantization level's share when float32 rounding (1e-6) moves one texel across a level's boundary.
DISCONTINUOUS = {("quantized", "max_rel"), ("quantized", "max_abs")}


def worst(a: dict, b: dict) -> tuple[float, str]:
    """Largest relative difference over the metrics of two metric dicts ({split: {float|quantized: {name: value}}})
    that are continuous in the textures (all but :data:`DISCONTINUOUS`), and where."""
    out = (0.0, "")
    for split in b:
        for kind in b[split]:
            for name, y in b[split][kind].items():
                if (kind, name) in DISCONTINUOUS:
                    continue
                x = a[split][kind][name]
                out = max(out, (abs(x - y) / max(abs(y), 1e-12), f"{split}.{kind}.{name}: {x} vs {y}"))
    return out


#: The forest bakes the bake tests share, by layout (tests/conftest.py ``forest_bakes`` builds each once per worker, on
#: first use): K = 2 products in RGB maps; the shared gain (K products and the tensor in the harmonic layers, one
#: gain); the mixed maps (RGBA: K products below the harmonic, K - 1 and the tensor from it up); the second
#: harmonic beside the products (fast). Layers 0.3 ... 1 (six): the harmonic from 0.55 holds layers 3-5.
FOREST_BAKES = {
    "plain": dict(preset="balanced", harmonic=0.0, diffuse="texture", layers=3),
    "shared": dict(preset="balanced", harmonic=0.55, analytic_source=False, layers=6, min_roughness=0.3),
    "mixed": dict(preset="balanced", harmonic=0.55, mixed=True, diffuse="texture", layers=6, min_roughness=0.3),
    "harmonic": dict(preset="fast", harmonic=0.3, layers=4),
}
#: The sizes of every bake in FOREST_BAKES (and of the tests' other small bakes).
BAKE_SIZES = dict(max_size=8, nv_size=8, samples=64, data_resolution=4, diffuse_size=8)


def made_up_bake(preset: str = "fast", seed: int = 0, diffuse_basis: str = "texture"):
    """A bake of the preset's structure (3 layers, small sizes) with smooth made-up positive textures: what the
    GPU == CPU and viewer tests need, without a fit. ``diffuse_basis="sh9"``: E_d's SH9 projections as well."""
    pl = make_plan(preset, max_size=16, layers=3, nv_size=8, diffuse_size=8, diffuse_basis=diffuse_basis, harmonic=0.0)
    rough = pl.roughnesses()
    P = tuple(np.stack([smooth_texture("cube", layer_size(r, pl.max_size), seed + 10 * j + k) for k in range(pl.terms)],
                       axis=2) for j, r in enumerate(rough))
    E = np.stack([smooth_texture("cube", pl.diffuse_size, seed + 100 + d) for d in range(pl.diffuse)], axis=2)
    rng = np.random.default_rng(seed)
    W = rng.uniform(0.2, 1.0, (pl.layers, pl.nv_size, 2 * pl.terms + pl.diffuse)).astype(np.float32)
    return Bake(pl, rough, (0.0,) * pl.layers, P, E, W, {"source": "forest"},
                diffuse_sh9(E) if diffuse_basis == "sh9" else None)


def small_fits(setattr, *, resolution: int = 4, texture_size: int = 8, count: int = 20_000,
               validation: int = 2_000, polish_size: int = 8) -> None:
    """Make ``hf.light.load_environment`` and ``hf.fit.factorize`` default to small sizes, so code written
    for users (the README's blocks, the quickstart notebook) runs as written in seconds: a light
    resolution, a texture size, grid / validation pair counts and (for a fitted sum) the polish's texel
    sampling size, each only where the call gives none of its own (a preset's other choices, its
    candidates, votes and polish steps, run unchanged). ``setattr``:
    ``monkeypatch.setattr`` in a test, the builtin in a notebook kernel."""
    import homofac as hf

    load, factorize = hf.light.load_environment, hf.fit.factorize

    def small_environment(*args, **kw):
        if len(args) < 2 and "resolution" not in kw:
            kw["resolution"] = resolution
        return load(*args, **kw)

    def small_factorize(*args, **kw):
        kw.setdefault("texture_size", texture_size)
        kw["sampling"] = {"count": count, "validation": validation, **(kw.get("sampling") or {})}
        if any(kw.get(k) is not None for k in ("preset", "max_lookups", "terms")) or "linear" in (kw.get("advanced") or {}):
            advanced = dict(kw.get("advanced") or {})
            advanced["linear"] = {"polish_size": polish_size, **(advanced.get("linear") or {})}
            kw["advanced"] = advanced
        return factorize(*args, **kw)

    setattr(hf.light, "load_environment", small_environment)
    setattr(hf.fit, "factorize", small_factorize)
