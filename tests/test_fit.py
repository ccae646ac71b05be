"""Factorization core: exact recovery of synthetic products, solver agreement, metrics, start."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import pytest

from homofac import brdf
from homofac.errors import HomofacError
from homofac.factorization import Factorization
from homofac.fit import metrics as met
from homofac.fit import pipeline, solvers
from homofac.fit.options import FitOptions
from homofac.fit.product import level_sizes
from homofac.fit.start import starting_solution
from homofac.fit.solvers.adjoint import AdjointOperator
from homofac.fit.solvers.lsmr import _lsmr
from homofac.fit.system import adjoint_plan, apply_transpose, build_system, objective, parametrization_layout, to_scipy
from homofac.options import validate
from homofac.param import mappers
from homofac.param import parametrizations as pz
from homofac.target import brdf_target


def smooth_texture(rng, shape, amplitude=0.25, modes=3):
    """exp of a low-frequency random Fourier series: smooth, positive, unit-ish mean."""
    h, w = shape
    y, x = np.meshgrid(np.linspace(0, 1, h), np.linspace(0, 1, w), indexing="ij")
    log = np.zeros(shape)
    for _ in range(modes):
        kx, ky = rng.uniform(0.2, 0.6, 2)
        ph = rng.uniform(0, 2 * np.pi, 2)
        log += rng.normal() * np.sin(2 * np.pi * kx * x + ph[0]) * np.cos(2 * np.pi * ky * y + ph[1])
    log *= amplitude / max(np.abs(log).max(), 1e-9)
    tint = rng.uniform(0.6, 1.0, 3)
    return np.exp(log)[..., None] * tint


class TextureBRDF(eqx.Module):
    """A BRDF that is exactly a product of textures (the synthetic target of the exactness tests)."""

    textures: tuple
    parametrization: str = eqx.field(static=True)
    mapper: str = eqx.field(static=True)

    def __call__(self, wi, wo):
        size = self.textures[0].shape[0]
        model = Factorization.product("brdf", "brdf", self.parametrization, self.mapper, size, self.textures,
                                      jnp.ones(3, wi.dtype))
        v = model.evaluate(wi, wo)
        return jnp.where((wi[..., 2:3] > 0) & (wo[..., 2:3] > 0), v, 0.0)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["PQP", "IV", "GSHD"])
def test_synthetic_product_is_recovered(x64, name):
    """A BRDF built from smooth textures is recovered by its own parametrization (nrmse < 1e-3)."""
    rng = np.random.default_rng(1)
    size = 12
    shape = mappers.texture_shape(mappers.get("parabolic"), size)
    p = pz.get(name)
    tex = tuple(jnp.asarray(smooth_texture(rng, shape)) for _ in p.textures)
    target = brdf_target(TextureBRDF(tex, name, "parabolic"))
    fac = pipeline.factorize(
        target, name, mapper="parabolic", texture_size=size,
        sampling={"kind": "texels", "size": 14, "validation": 2000, "seed": 3},
        solver={"method": "lsmr", "tolerance": 1e-8, "max_iterations": 3000, "laplacian": 1e-2},
    )
    val = fac.metrics["validation"]["float"]
    assert val["nrmse"] < 1e-3, val
    assert fac.metrics["train"]["float"]["nrmse"] < 1e-3


def _small_system(x64_dtype=jnp.float64):
    target = brdf_target(brdf.cook_torrance(kd=0.1, ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34)))
    p = pz.get("PQP")
    samples = pipeline.draw_samples(target, "PQP", {"kind": "texels", "size": 8, "validation": 0})
    layout = parametrization_layout(p, "parabolic", 6)
    sys, alpha = build_system(p, layout, jnp.asarray(samples.a, x64_dtype), jnp.asarray(samples.b, x64_dtype),
                              jnp.asarray(samples.y, x64_dtype), eps=1e-5)
    return sys, layout, p


@pytest.mark.slow
def test_solvers_agree_with_direct_optimum(x64):
    """LSMR, QMR, normal-equation CG and optimistix Gauss-Newton reach an objective within 1e-4 (relative)
    of the direct normal-equation optimum."""
    sys, layout, p = _small_system()
    x0 = starting_solution(sys, layout, p.J)
    direct = solvers.solve(sys, x0, method="direct", laplacian=1.0)
    lsmr = solvers.solve(sys, x0, method="lsmr", laplacian=1.0, tolerance=1e-10, max_iterations=5000)
    qmr = solvers.solve(sys, x0, method="qmr", laplacian=1.0, tolerance=1e-10, max_iterations=20000)
    cg = solvers.solve(sys, x0, method="cg", laplacian=1.0, tolerance=1e-10, max_iterations=20000)
    gn = solvers.solve(sys, x0, method="optimistix", laplacian=1.0, tolerance=1e-10, max_iterations=5000)
    start = float(objective(sys, 1.0, x0))
    assert direct.objective < start
    for r in (lsmr, qmr, cg, gn):
        assert (r.objective - direct.objective) / direct.objective < 1e-4, (r.method, r.objective, direct.objective)
    assert lsmr.converged and cg.converged and gn.converged


def test_optimistix_with_a_capped_lsmr_moves_as_far_as_lsmr():
    """``optimistix`` whose LSMR stops on ``max_iterations`` takes the truncated step (solvers.inexact):
    it lowers the objective at least as far as ``lsmr`` with the same cap, where optimistix alone
    returned the start."""
    sys, layout, p = _small_system(jnp.float32)
    x0 = starting_solution(sys, layout, p.J)
    start = float(objective(sys, 1.0, x0))
    lsmr = solvers.solve(sys, x0, method="lsmr", laplacian=1.0, tolerance=1e-8, max_iterations=5)
    gn = solvers.solve(sys, x0, method="optimistix", laplacian=1.0, tolerance=1e-8, max_iterations=5)
    assert lsmr.objective < 0.99 * start
    assert gn.objective <= lsmr.objective * 1.001, (gn.objective, lsmr.objective, start)


def test_starting_solution_fills_every_valid_texel():
    sys, layout, p = _small_system(jnp.float32)
    x0 = np.asarray(starting_solution(sys, layout, p.J))
    assert x0.shape == (layout.n_unknowns, 3)
    assert np.all(np.isfinite(x0))
    # The start is already a useful approximation: better than all-zero (the log mean).
    assert float(objective(sys, 1.0, jnp.asarray(x0))) < float(objective(sys, 1.0, jnp.zeros_like(jnp.asarray(x0))))


def test_start_is_exact_for_single_factor():
    """For one factor and data exactly on texel centres, the averaging start is the answer (thesis §5.4)."""
    p = pz.get("N")
    layout = parametrization_layout(p, "cube", 4)
    dirs = np.asarray(mappers.texel_directions(mappers.get("cube"), 4)).reshape(-1, 3)
    vals = np.exp(np.sin(3 * dirs[:, :1]) + 0.1 * np.arange(3))
    sys, alpha = build_system(p, layout, jnp.asarray(dirs), jnp.asarray(dirs), jnp.asarray(vals, jnp.float32), eps=1e-5)
    x0 = starting_solution(sys, layout, 1)
    want = np.log((vals + 1e-5 * np.asarray(alpha)) / np.asarray(alpha))
    np.testing.assert_allclose(np.asarray(x0)[layout.textures[0].unknown_of_texel[np.arange(len(dirs))]], want, atol=1e-5)


def test_metrics_by_hand():
    e = np.array([[1.0, 2.0, 4.0], [3.0, 2.0, 0.0]])
    a = np.array([[1.5, 2.0, 4.0], [3.0, 1.0, 0.0]])
    m = met.metrics(a, e)
    # per channel |a-e|: [0.5, 0], [0, 1], [0, 0]
    assert m["avg_abs"] == pytest.approx(np.mean([0.25, 0.5, 0.0]))
    assert m["max_abs"] == pytest.approx(np.mean([0.5, 1.0, 0.0]))
    assert m["rms"] == pytest.approx(np.mean([np.sqrt(0.125), np.sqrt(0.5), 0.0]))
    assert m["nrmse"] == pytest.approx(np.mean([0.5 / np.sqrt(10), 1 / np.sqrt(8), 0.0]))
    assert m["avg_rel"] == pytest.approx(np.mean([0.25, 0.25, 0.0]))
    assert m["max_rel"] == pytest.approx(np.mean([0.5, 0.5, 0.0]))
    assert set(m) == set(met.NAMES)


def test_metrics_are_differentiable():
    e = jnp.ones((10, 3))
    g = jax.grad(lambda s: met.metric_arrays(e * s, e)["rms"])(1.5)
    assert np.isfinite(float(g)) and float(g) > 0


@pytest.mark.slow
def test_zero_values_take_the_bias_path(x64):
    """Zeros in the target (eq. 26 bias) give finite textures and a finite log system."""
    from homofac import brdf

    b = brdf.cook_torrance(kd=0.0, ks=1.0, roughness=0.15, f0=(1.0, 0.0, 0.34))  # green channel exactly 0
    fac = pipeline.factorize(
        brdf_target(b), "PQP", texture_size=8, sampling={"kind": "texels", "size": 8, "validation": 500}
    )
    assert all(np.all(np.isfinite(np.asarray(t))) for t in fac.textures)
    assert np.isfinite(fac.metrics["validation"]["float"]["nrmse"])


@pytest.mark.slow
def test_multiresolution_reaches_the_single_level_error():
    """solver.levels = 2 (solve at S/2, upsample through the mapper, refine; thesis §3.1.2) reaches the
    validation error of the single-level solve at S within 2 %, and its first level is really coarse."""
    target = brdf_target(brdf.cook_torrance(kd=0.1, ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34)))
    samples = pipeline.draw_samples(target, "PQP", {"kind": "texels", "size": 16, "validation": 3000, "seed": 2},
                                    log=lambda m: None)
    common = dict(mapper="parabolic", texture_size=16, samples=samples)
    one = pipeline.factorize(target, "PQP", solver={"tolerance": 1e-7, "max_iterations": 3000}, **common)
    two = pipeline.factorize(target, "PQP", solver={"tolerance": 1e-7, "max_iterations": 3000, "levels": 2},
                             **common)
    assert two.solver["levels"] == [8, 16]
    assert one.solver["levels"] == [16]
    e1 = one.metrics["validation"]["float"]["nrmse"]
    e2 = two.metrics["validation"]["float"]["nrmse"]
    assert np.isfinite(e2) and e2 <= 1.02 * e1, (e1, e2)
    assert two.textures[0].shape == one.textures[0].shape


def test_level_sizes_halve_down_to_four():
    assert level_sizes(32, 3) == [8, 16, 32]
    assert level_sizes(8, 5) == [4, 8]
    assert level_sizes(6, 2) == [6]  # 3 < 4: no coarser level


def test_solver_names_match_the_config():
    """Every registered solver is a valid solver.method (with its own option model), and nothing else is."""
    for name, record in solvers.SOLVERS.items():
        opts = validate(FitOptions, {"solver": {"method": name}}, "").solver
        assert opts.method == name and isinstance(opts, record.options)
        assert record.memory(1000, 100, 8) > 0 and record.doc
    with pytest.raises(HomofacError, match="solver"):
        validate(FitOptions, {"solver": {"method": "nope"}}, "")


def test_column_scaling_is_the_inverse_column_norm():
    """column_scale(A) gives d_j = 1/||A e_j|| of the augmented matrix (data and lambda-Laplacian rows)
    when no row holds a column twice (IV: two textures, four distinct bilinear taps each)."""
    target = brdf_target(brdf.cook_torrance(kd=0.1, ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34)))
    p = pz.get("IV")
    s = pipeline.draw_samples(target, "IV", {"kind": "texels", "size": 8, "validation": 0, "cache": False},
                              log=lambda m: None)
    layout = parametrization_layout(p, "parabolic", 6)
    sys, _ = build_system(p, layout, jnp.asarray(s.a), jnp.asarray(s.b), jnp.asarray(s.y), eps=1e-5)
    d = np.asarray(solvers.column_scale(sys, 0.5))
    a = to_scipy(sys, 0.5, layout.n_unknowns)
    norms = np.sqrt(np.asarray(a.multiply(a).sum(axis=0))).ravel()
    np.testing.assert_allclose(d, 1 / norms, rtol=1e-5)


@pytest.mark.parametrize("name", ["PQP", "NR"])
def test_gathered_transpose_is_the_transpose(name):
    """apply_transpose (the entries sorted by column, gathered in chunks) is A^T of the augmented matrix
    (scipy's), with PQP's rows holding a column twice and the zero-weight taps of invalid texels; LSMR
    with it reaches LSMR's solution with jax's derived transpose."""
    kind = "brdf" if name == "PQP" else "lighting"
    target = brdf_target(brdf.cook_torrance(kd=0.1, ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34)))
    p = pz.get(name)
    rng = np.random.default_rng(3)
    if kind == "brdf":
        s = pipeline.draw_samples(target, name, {"kind": "texels", "size": 8, "validation": 0, "cache": False},
                                  log=lambda m: None)
        a, b, y = s.a, s.b, s.y
    else:  # random (n, v) pairs and values: the rows' structure is what is tested
        a = rng.normal(size=(3000, 3)); a /= np.linalg.norm(a, axis=1, keepdims=True)
        b = rng.normal(size=(3000, 3)); b /= np.linalg.norm(b, axis=1, keepdims=True)
        y = rng.uniform(0.1, 1.0, (3000, 3))
    layout = parametrization_layout(p, "dual_paraboloid", 8)
    sys, _ = build_system(p, layout, jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32),
                          jnp.asarray(y, jnp.float32), eps=1e-5)
    plan = adjoint_plan(sys)
    lam = 0.7
    r = rng.normal(size=(sys.cols.shape[0] + layout.n_unknowns, 5)).astype(np.float32)
    expect = to_scipy(sys, lam, layout.n_unknowns).T @ r.astype(np.float64)
    got = np.asarray(apply_transpose(sys, jnp.float32(lam), plan, jnp.asarray(r)))
    np.testing.assert_allclose(got, expect, rtol=2e-4, atol=2e-4 * np.abs(expect).max())
    x0 = jnp.zeros((layout.n_unknowns, 3), jnp.float32)
    ref, _, _ = _lsmr(sys, jnp.float32(lam), x0, rtol=1e-6, max_steps=500)
    fast, _, _ = _lsmr(sys, jnp.float32(lam), x0, rtol=1e-6, max_steps=500, plan=plan)
    assert float(objective(sys, lam, fast)) <= float(objective(sys, lam, ref)) * (1 + 1e-4)
    np.testing.assert_allclose(np.asarray(fast), np.asarray(ref), atol=2e-3 * float(jnp.abs(ref).max()))


def test_adjoint_operator_uses_the_given_transpose():
    """AdjointOperator.transpose() is the given function (not jax's derived transpose), conj leaves it,
    and transposing twice is the operator again."""
    a = jnp.arange(6.0, dtype=jnp.float32).reshape(3, 2)
    op = AdjointOperator(lambda x: a @ x, lambda y: 2.0 * (a.T @ y), jax.ShapeDtypeStruct((2,), jnp.float32),
                         jax.ShapeDtypeStruct((3,), jnp.float32))
    y = jnp.asarray([1.0, -2.0, 0.5], jnp.float32)
    np.testing.assert_allclose(op.transpose().mv(y), 2.0 * (a.T @ y))  # the given (here deliberately 2 A^T)
    assert lx.conj(op) is op
    np.testing.assert_allclose(op.T.T.mv(jnp.ones(2)), a @ jnp.ones(2))
