"""Ridge pairs (homofac.fit.ridge): uniform on the grazing ridge of bright lights, weighted as an unbiased
stratum of the validation distribution, and how the polish uses them (issue 13, where the error lives)."""

from __future__ import annotations

import numpy as np
import pytest

import homofac as hf
from homofac.errors import HomofacError
from homofac.fit import pipeline, polish, ridge, sampling, sums
from homofac.fit.options import FitOptions, LinearOptions
from homofac.fit.polish import recorded_linear
from homofac.fit.structures import Structure

SUN = np.array([0.5, -0.3, 0.81])
SUN /= np.linalg.norm(SUN)
GRID = {"kind": "grid", "size": 8, "mapper": "dual_paraboloid", "count": 20000, "validation": 2000, "cache": False}


def _uniform(count: int, seed: int):
    """Validation-distribution pairs (n uniform, v uniform on its hemisphere)."""
    p = sampling.random_pairs("lighting", count, seed)
    return p.a.astype(np.float64), p.b.astype(np.float64)


def test_ridge_pairs_lie_on_the_ridge_are_valid_and_seeded():
    rp = ridge.ridge_pairs(SUN, 3000, seed=4)
    assert rp.a.shape == rp.b.shape == (3000, 3) and rp.weight.shape == (3000,)
    assert ridge.in_ridge(rp.a, rp.b, SUN).all()
    np.testing.assert_allclose(np.linalg.norm(rp.a, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(rp.b, axis=1), 1.0, atol=1e-5)
    assert np.all(np.sum(rp.a * rp.b, axis=1) > sampling.MIN_COS * 0.99)
    # one light: every pair stands for the same share, P / M
    np.testing.assert_allclose(rp.weight, rp.probability[0] / 3000, rtol=1e-9)
    again = ridge.ridge_pairs(SUN, 3000, seed=4)
    assert np.array_equal(again.a, rp.a) and np.array_equal(again.b, rp.b)
    assert not np.array_equal(ridge.ridge_pairs(SUN, 3000, seed=5).a, rp.a)


@pytest.mark.parametrize("elevation_deg", [40.0, 3.0])
def test_the_ridge_probability_is_the_share_of_uniform_pairs_on_it(elevation_deg):
    """P_j from the construction equals the fraction of 2 million validation pairs on the ridge (within 5
    standard errors), for a high light and one just over the horizon of the z-up world."""
    e = np.radians(elevation_deg)
    light = np.array([np.cos(e), 0.0, np.sin(e)])
    p = ridge.ridge_pairs(light, 20000, seed=1).probability[0]
    a, b = _uniform(2_000_000, 7)
    frac = ridge.in_ridge(a, b, light).mean()
    assert abs(frac - p) < 5 * np.sqrt(p / 2_000_000), (frac, p)


def test_two_overlapping_lights_weights_estimate_the_union_and_its_means():
    """With two lights 5 degrees apart (overlapping cones) the balance-heuristic weights give P(R1 u R2) and
    E[g 1_R] of the uniform pairs, g = 1 / (n.v + 0.01) (the ridge's own steep shape)."""
    l1 = SUN
    side = np.cross(l1, [0.0, 0.0, 1.0])
    l2 = l1 * np.cos(np.radians(5.0)) + side / np.linalg.norm(side) * np.sin(np.radians(5.0))
    rp = ridge.ridge_pairs(np.stack([l1, l2]), 40000, seed=2)
    g = 1.0 / (np.sum(rp.a * rp.b, axis=1) + 0.01)
    a, b = _uniform(3_000_000, 11)
    on = ridge.in_any_ridge(a, b, np.stack([l1, l2]))
    gu = 1.0 / (np.sum(a * b, axis=1) + 0.01)
    p_union = on.mean()
    assert ridge.in_ridge(a, b, l1).mean() + ridge.in_ridge(a, b, l2).mean() > 1.3 * p_union  # they overlap
    assert abs(rp.weight.sum() - p_union) < 5 * np.sqrt(p_union / 3_000_000)
    want = np.mean(gu * on)
    se = np.std(gu * on) / np.sqrt(len(gu))
    assert abs(np.sum(rp.weight * g) - want) < 5 * se + 0.02 * want


def test_the_stratified_nrmse_estimates_the_uniform_one_with_less_spread():
    """A model that misses a steep ridge value (exact = 1 + 3 / (n.v + 0.003) on the ridge, approx = 1):
    the stratified estimate from 4000 validation pairs and 20 000 ridge pairs agrees with the nrmse of
    4 000 000 uniform pairs, and over seeds it spreads less than the plain estimate of the 4000 pairs."""
    def grey(a, b):
        on = ridge.in_ridge(a, b, SUN)
        return (1.0 + on * 3.0 / (np.sum(a * b, axis=1) + 0.003))[:, None]

    def exact(a, b):
        return np.repeat(grey(a, b), 3, axis=1)

    a, b = _uniform(4_000_000, 21)
    e = grey(a, b)  # the metrics average equal channels: one is the reference's RGB nrmse
    want = hf.fit.metrics.metrics(np.ones_like(e), e)["nrmse"]
    plain, strat = [], []
    for seed in range(6):
        va, vb = _uniform(4000, 100 + seed)
        ve = exact(va, vb)
        rp = ridge.ridge_pairs(SUN, 20000, seed=200 + seed)
        re = exact(rp.a.astype(np.float64), rp.b.astype(np.float64))
        plain.append(hf.fit.metrics.metrics(np.ones_like(ve), ve)["nrmse"])
        strat.append(ridge.stratified_nrmse(np.ones_like(ve), ve, ridge.in_ridge(va, vb, SUN), np.ones_like(re), re,
                                            rp.weight))
    assert max(abs(x - want) for x in strat) < 0.01 * want
    assert np.std(strat) < 0.1 * np.std(plain)
    # nothing on the ridge: the plain nrmse
    va, vb = _uniform(3000, 5)
    ve, approx = exact(va, vb), np.full((3000, 3), 0.9)
    none = np.zeros((0, 3))
    assert ridge.stratified_nrmse(approx, ve, np.zeros(3000, bool), none, none, np.zeros(0)) == pytest.approx(
        hf.fit.metrics.metrics(approx, ve)["nrmse"], rel=1e-5)


@pytest.mark.slow  # two polished fits and a refit (about 40 s)
def test_the_polish_adds_the_ridge_pairs_and_records_them_for_a_refit():
    env = hf.light.sun_sky(SUN, sun_radiance=300.0, sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6), resolution=8)
    target = hf.light.lighting_target(hf.brdf.cook_torrance(kd=0.3, ks=1.0, roughness=0.6, f0=0.04), env)
    kw = dict(texture_size=8, sampling=GRID, diffuse="fitted", nv_factor=True)
    hl = {"highlights": {"terms": 1}}
    plain = hf.fit.factorize(target, "NR", advanced={**hl, "linear": {"polish": 2, "polish_size": 6}}, **kw)
    fac = hf.fit.factorize(target, "NR", advanced={**hl, "linear": {"polish": 2, "polish_size": 6, "ridge": 500}}, **kw)
    note = fac.solver["polish"]["ridge"]
    assert note["pairs"] == 500 and 0 < note["probability"][0] < 0.01
    np.testing.assert_allclose(note["lights"][0], np.asarray(fac.model.context["dominant"]), atol=1e-6)
    assert fac.solver["polish"]["samples"] == plain.solver["polish"]["samples"] + 500
    assert "ridge" not in plain.solver["polish"]
    # the ridge pairs come in a second stage, from the first stage (the plain polish)
    first = fac.solver["polish"]["first"]
    assert "ridge" not in first and first["samples"] == plain.solver["polish"]["samples"]
    assert first["objective"] == pytest.approx(plain.solver["polish"]["objective"], rel=1e-5)
    # the ridge pairs change the fit (they hold values the grid and texel pairs do not)
    n, v = ridge.ridge_pairs(np.asarray(note["lights"]), 200, seed=9)[:2]
    assert not np.allclose(np.asarray(fac.model.evaluate(n, v)), np.asarray(plain.model.evaluate(n, v)))
    assert recorded_linear(LinearOptions(), fac.solver).ridge == 500
    assert recorded_linear(LinearOptions(), plain.solver).ridge == 0
    again = hf.fit.refit(fac, target=target)
    assert again.solver["polish"]["ridge"]["pairs"] == 500


@pytest.mark.parametrize("linear, kw, match", [
    ({"polish": 2, "ridge": 100, "nv_balance": 1.0}, {}, "set one of them"),
    ({"ridge": 100}, {}, "linear.ridge adds pairs to the polish"),
    ({"ridge": 100, "polish": 0}, {"max_lookups": 16}, "linear.ridge adds pairs to the polish"),
    ({"ridge": -1}, {}, "ridge"),
])
def test_bad_ridge_options_are_refused_in_one_line(linear, kw, match):
    env = hf.light.sun_sky(SUN, sun_radiance=300.0, sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6), resolution=8)
    target = hf.light.lighting_target(hf.brdf.ggx(kd=0.3, ks=1.0, roughness=0.4, f0=0.04), env)
    with pytest.raises(HomofacError, match=match) as e:
        hf.fit.factorize(target, "NR", texture_size=8, sampling=GRID, diffuse="fitted", nv_factor=True,
                         advanced={"linear": linear}, **kw)
    assert "\n" not in str(e.value)


def test_ridge_needs_an_environment():
    brdf = hf.target.brdf_target(hf.brdf.ggx(kd=0.3, ks=1.0, roughness=0.4, f0=0.04))
    with pytest.raises(HomofacError, match="ridge") as e:
        hf.fit.factorize(brdf, "PQP", terms=2, advanced={"linear": {"polish": 2, "ridge": 100}})
    assert "\n" not in str(e.value)


@pytest.mark.slow  # three polish stages and a refit: about 55 s of CPU, most of it compiling
def test_the_direct_stage_starts_from_the_als_fit_and_a_refit_repeats_the_recorded_path():
    """polish_stages(direct=True): a third stage with the ridge pairs straight from the ALS fit, whose
    record has ``ridge`` and no ``first`` (recorded_direct); polish() returns the stage a record names, and a
    refit of a direct stage's record takes that path, not the two-stage one."""
    env = hf.light.sun_sky(SUN, sun_radiance=300.0, sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6), resolution=8)
    target = hf.light.lighting_target(hf.brdf.cook_torrance(kd=0.3, ks=1.0, roughness=0.6, f0=0.04), env)
    structure = Structure("NR", 1, "fitted", True, highlights={"terms": 1})
    tgt = sums.with_highlight_context(target, structure)
    lin = LinearOptions(polish=2, polish_size=6, ridge=500)
    samples = hf.fit.draw_samples(tgt, "NR", GRID)
    fit = sums.fit_sum(tgt, structure, "dual_paraboloid", 8, samples, lin.model_copy(update={"polish": 0}),
                       lambda m: None)
    pairs = polish.polish_pairs(tgt, "NR", lin, 0, False, lambda m: None)
    args = (tgt, structure, "dual_paraboloid", 8, fit, samples, pairs, lin, lambda m: None)
    stages = polish.polish_stages(*args, direct=True)
    assert len(stages) == 3 and len(polish.polish_stages(*args)) == 2
    records = [st.solver["polish"] for st in stages]
    assert "ridge" not in records[0] and records[1]["ridge"]["pairs"] == records[2]["ridge"]["pairs"] == 500
    assert "first" in records[1] and "first" not in records[2]
    assert [polish.recorded_direct(st.solver) for st in stages] == [False, False, True]
    # the direct stage starts where the first stage did (the ALS fit), on the ridge stage's objective
    assert records[2]["objective_start"] != pytest.approx(records[1]["objective_start"], rel=1e-3)
    alone = polish.polish_stage(*args[:4], fit, samples, pairs, lin.model_copy(update={"ridge": 0}), args[-1])
    assert alone.solver["polish"]["objective_start"] == pytest.approx(records[0]["objective_start"], rel=1e-6)
    n, v = ridge.ridge_pairs(SUN, 300, seed=3)[:2]
    for direct, want in ((True, stages[2]), (False, stages[1])):
        got = polish.polish(*args, direct=direct)
        np.testing.assert_allclose(np.asarray(got.model.evaluate(n, v)), np.asarray(want.model.evaluate(n, v)),
                                   rtol=1e-5, atol=1e-6)
    # a refit of a direct stage's record repeats the direct path
    kw = dict(texture_size=8, sampling=GRID, diffuse="fitted", nv_factor=True)
    fac = hf.fit.factorize(target, "NR", advanced={"highlights": {"terms": 1},
                                                   "linear": {"polish": 2, "polish_size": 6, "ridge": 500}}, **kw)
    record = {k: v for k, v in fac.solver["polish"].items() if k != "first"}
    direct = hf.fit.refit(fac.replace(solver={**fac.solver, "polish": record}), target=target)
    assert polish.recorded_direct(direct.solver) and direct.solver["polish"]["ridge"]["pairs"] == 500
    two = hf.fit.refit(fac, target=target)
    assert "first" in two.solver["polish"]
    assert not np.allclose(np.asarray(direct.model.evaluate(n, v)), np.asarray(two.model.evaluate(n, v)))
