"""Refits (issue 15): a new environment or material on a fit's layout gives the metrics of a full run.

Small sizes (8-16) so the file runs in seconds; the default-case timing is benchmarks/test_refit.py.
"""

from __future__ import annotations

import sys

import jax.numpy as jnp
import numpy as np
import pytest

import homofac as hf
import homofac.fit.refit  # noqa: F401  (the module; hf.fit.refit is the function)
from homofac.errors import HomofacError
from helpers import worst
from homofac.fit import differentiable as dr
from homofac.fit import footprints, sampling, transport

rf = sys.modules["homofac.fit.refit"]

RES = 8
KW = dict(texture_size=16, sampling={"kind": "texels", "size": 8, "validation": 2000, "cache": False})


def gold(**kw):
    p = dict(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    p.update(kw)
    return hf.brdf.cook_torrance(**p)


@pytest.fixture(scope="module")
def envs():
    return hf.light.load_environment("forest", resolution=RES), hf.light.load_environment("city", resolution=RES)


#: The config a run records (what :func:`homofac.fit.prepare_refit` redraws a saved result's pairs from).
CFG = {"parametrization": "NR", "texture_size": 16, "sampling": KW["sampling"]}


@pytest.fixture(scope="module")
def base(envs):
    return hf.fit.factorize(hf.light.lighting_target(gold(), envs[0]), "NR", config=CFG, **KW)


@pytest.mark.slow
def test_environment_refit_equals_a_full_run(base, envs):
    r = hf.fit.refit(base, environment=envs[1])
    full = hf.fit.factorize(hf.light.lighting_target(gold(), envs[1]), "NR", **KW)
    assert set(r.metrics) == set(full.metrics) == {"train", "validation"}
    rel, where = worst(r.metrics, full.metrics)
    assert rel < 0.01, where
    assert r.solver["refit"] and r.solver["method"].startswith("normal equations")
    # the layout is kept: same textures, same pairs
    assert [t.shape for t in r.model.textures] == [t.shape for t in base.model.textures]
    assert r.counts["train"] == base.counts["train"]
    # it really is the new environment: the error of the old model on the new target is much larger
    assert r.metrics["validation"]["float"]["nrmse"] < 0.9 * hf.fit.measure(
        base, r.target, r.state.samples(*rf.values(r.state, r.target)))["validation"]["float"]["nrmse"]


@pytest.mark.slow  # compile- or subprocess-heavy: with the slow set, to keep the fast suite under 5 min
def test_refits_chain_and_come_back(base, envs):
    r1 = hf.fit.refit(base, environment=envs[1])
    r2 = hf.fit.refit(r1, environment=envs[0])  # warm: the state is shared along the chain
    assert r2.state is base.state
    rel, where = worst(r2.metrics, base.metrics)
    assert rel < 0.01, where
    n, v = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]]), np.array([[0.0, 0.6, 0.8], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(np.asarray(r2.evaluate(n, v)), np.asarray(base.evaluate(n, v)), rtol=2e-3)


def test_brdf_refit_equals_a_full_run(base, envs):
    b = gold(roughness=0.5, f0=(0.9, 0.9, 0.9), kd=(0.2, 0.1, 0.05))
    r = hf.fit.refit(base, brdf=b)
    full = hf.fit.factorize(hf.light.lighting_target(b, envs[0]), "NR", **KW)
    rel, where = worst(r.metrics, full.metrics)
    assert rel < 0.01, where


def test_transport_path_equals_the_direct_values(base, envs):
    st = base.state
    new = rf.new_target(base, environment=envs[1])
    direct = rf.values(st, new, use_transport=False)
    via = rf.values(st, new, use_transport=True)
    for d, t in zip(direct, via):
        np.testing.assert_allclose(t, d, rtol=1e-4, atol=1e-6 * float(np.abs(d).max()))
    # a colour change of the same shape reuses the same transport
    b = gold(f0=(0.5, 0.6, 0.7), kd=(0.3, 0.2, 0.1), ks=0.8)
    col = rf.new_target(base, brdf=b)
    np.testing.assert_allclose(rf.values(st, col, use_transport=True)[0], rf.values(st, col, use_transport=False)[0],
                               rtol=1e-4, atol=1e-6)


@pytest.mark.slow
def test_lobe_sums_and_transport_match_the_lighting_computation(envs):
    g = sampling.grouped_pairs("texels", 6, mapper="dual_paraboloid")
    brdfs = [gold(roughness=r) for r in (0.2, 0.45)] 
    sums = transport.lobe_sums(brdfs, envs[1], g.normals, g.views)
    for i, b in enumerate(brdfs):
        fn = hf.light.Lighting(b, envs[1])
        ref = np.asarray(fn.grouped(jnp.asarray(g.normals), jnp.asarray(g.views)))[g.mask]
        got = np.asarray(transport.combine(b, sums, i, g.normals, g.views))[g.mask]
        np.testing.assert_allclose(got, ref, rtol=1e-4, atol=1e-6 * ref.max())
        tr = transport.build_transport(fn, g.normals, g.views)
        flat = np.flatnonzero(g.mask.reshape(-1))
        got2 = np.asarray(transport.transported_values(tr, fn, g.normals, g.views, flat))
        np.testing.assert_allclose(got2, ref, rtol=1e-4, atol=1e-6 * ref.max())
    phong = hf.brdf.phong(kd=0.05, ks=0.9, exponent=40.0)
    ref = np.asarray(hf.light.Lighting(phong, envs[0]).grouped(jnp.asarray(g.normals), jnp.asarray(g.views)))
    got = np.asarray(transport.combine(phong, transport.lobe_sums([phong], envs[0], g.normals, g.views), 0,
                                       g.normals, g.views))
    np.testing.assert_allclose(got[g.mask], ref[g.mask], rtol=1e-4, atol=1e-6 * ref.max())


def test_footprint_evaluation_equals_the_model(base):
    s = base.state
    fp = footprints.footprints(base.model, s.validation.a, s.validation.b)
    a, b = jnp.asarray(s.validation.a), jnp.asarray(s.validation.b)
    np.testing.assert_allclose(np.asarray(footprints.evaluate(base.model, fp)), np.asarray(base.model.evaluate(a, b)),
                               rtol=1e-5, atol=1e-7)
    q = base.encoded()
    np.testing.assert_allclose(np.asarray(footprints.evaluate_quantized(base.model, q, fp)),
                               np.asarray(base.evaluate(a, b, quantized=True)), rtol=1e-5, atol=1e-7)


def test_lsmr_path_for_large_layouts(base, envs, monkeypatch):
    st = base.state
    monkeypatch.setattr(rf, "CHOLESKY_MAX_UNKNOWNS", 10)  # force the warm-started iterative path
    fresh = base.replace(state=rf.prepare(base.replace(state=None), st.options).state)
    r = hf.fit.refit(fresh, environment=envs[1], transport=False)
    assert r.solver["method"] == "lsmr"
    full = hf.fit.factorize(hf.light.lighting_target(gold(), envs[1]), "NR", **KW)
    rel, where = worst(r.metrics, full.metrics)
    assert rel < 0.01, where


def test_refit_of_a_saved_result(base, envs, tmp_path):
    fac = base  # the run with its config recorded
    fac.save(tmp_path / "out")
    loaded = hf.output.load(tmp_path / "out")
    assert loaded.state is None
    with pytest.raises(HomofacError, match="no refit state"):
        hf.fit.refit(loaded, target=hf.light.lighting_target(gold(), envs[1]))
    ready = hf.fit.prepare_refit(loaded)
    np.testing.assert_array_equal(ready.state.train.a, fac.state.train.a)
    np.testing.assert_array_equal(ready.state.validation.b, fac.state.validation.b)
    r = hf.fit.refit(ready, target=hf.light.lighting_target(gold(), envs[1]))
    rel, where = worst(r.metrics, hf.fit.refit(fac, environment=envs[1]).metrics)
    assert rel < 1e-3, where


@pytest.mark.slow
def test_brdf_factorization_refit():
    kw = dict(mapper="parabolic", texture_size=8, sampling={"kind": "texels", "size": 6, "validation": 1000,
                                                            "cache": False})
    b1 = hf.brdf.cook_torrance(kd=0.1, ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    b2 = hf.brdf.cook_torrance(kd=0.2, ks=0.7, roughness=0.5, f0=(0.9, 0.6, 0.3))
    fac = hf.fit.factorize(hf.fit.brdf_target(b1), "PQP", **kw)
    with pytest.raises(HomofacError, match="no environment"):
        hf.fit.refit(fac, environment=hf.light.uniform(1.0, 4))
    r = hf.fit.refit(fac, brdf=b2)
    full = hf.fit.factorize(hf.fit.brdf_target(b2), "PQP", **kw)
    rel, where = worst(r.metrics, full.metrics)
    assert rel < 0.01, where


@pytest.mark.slow
def test_sum_refit_warm_start_and_fresh(envs):
    kw = dict(texture_size=8, terms=2, diffuse="exact", nv_factor=True, advanced={"linear": {"iterations": 8}},
              sampling={"count": 6000, "validation": 1000, "cache": False})
    fac = hf.fit.factorize(hf.light.lighting_target(gold(), envs[0]), "NR", **kw)
    # from its own optimum on the same target the exact block ALS can only go down
    same = hf.fit.refit(fac, environment=envs[0])
    assert same.solver["start"] == "previous"
    assert same.solver["objective"] <= fac.solver["objective"] * (1 + 1e-4)
    # fresh: the full run's start rule on the new target: the full run's result on the same pairs
    fresh = hf.fit.refit(fac, environment=envs[1], start="fresh")
    full = hf.fit.factorize(hf.light.lighting_target(gold(), envs[1]), "NR", **kw)
    rel, where = worst(fresh.metrics, full.metrics)
    assert rel < 0.01, where
    warm = hf.fit.refit(fac, environment=envs[1])
    assert warm.model.lookups == full.model.lookups
    assert warm.metrics["validation"]["float"]["nrmse"] < 1.5 * full.metrics["validation"]["float"]["nrmse"]


@pytest.mark.slow
def test_baseline_refit(envs):
    kw = dict(texture_size=8, sampling={"kind": "texels", "size": 6, "validation": 1000, "cache": False})
    fac = hf.fit.factorize(hf.light.lighting_target(gold(), envs[0]), "split_sum", **kw)
    r = hf.fit.refit(fac, environment=envs[1])
    full = hf.fit.factorize(hf.light.lighting_target(gold(), envs[1]), "split_sum", **kw)
    rel, where = worst(r.metrics, full.metrics)
    assert rel < 0.01, where


def test_refit_refuses_bad_input(base, envs):
    with pytest.raises(HomofacError, match="nothing changes"):
        hf.fit.refit(base)
    with pytest.raises(HomofacError, match="Environment"):
        hf.fit.refit(base, environment=np.ones((6, 3)))
    with pytest.raises(HomofacError, match="not both"):
        hf.fit.refit(base, environment=envs[1], target=base.target)
    with pytest.raises(HomofacError, match="brdf target"):
        hf.fit.refit(base, target=hf.fit.brdf_target(gold()))
    with pytest.raises(HomofacError, match="start"):
        hf.fit.refit(base, environment=envs[1], start="cold")


@pytest.mark.slow
def test_a_layout_with_unreached_unknowns_refits_finite_and_equal(envs):
    """Pairs of one perspective view of a sphere leave the back paraboloid half without a sample (and its
    texels out of reach of the smoothing rows): the normal equations are near-singular there. The refit
    must neither hand back non-finite textures (a float32 inverse did) nor differ from a full run."""
    lo = [hf.light.load_environment(n, resolution=4) for n in ("forest", "city")]
    px = dr.sphere_pixels(20, camera="perspective")
    kw = dict(texture_size=8, solver={"method": "lsmr", "laplacian": 1.0})
    t0, t1 = (hf.light.lighting_target(gold(), e) for e in lo)
    fac = hf.fit.factorize(t0, "NR", samples=dr.pixel_samples(t0, px), **kw)
    r = hf.fit.refit(fac, environment=lo[1])
    assert r.solver["method"] == "normal equations (cholesky)"
    assert all(np.all(np.isfinite(np.asarray(t.data))) for t in r.model.textures)
    full = hf.fit.factorize(t1, "NR", samples=dr.pixel_samples(t1, px), **kw)
    rel, where = worst(r.metrics, full.metrics)
    assert rel < 0.01, where
