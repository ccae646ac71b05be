"""The off-specular products (issue 13): the projection ``r_off`` = normalize(r + beta (1 - n.v) n), its
inverse and the grid design on it, the NRO / RO sums fitted by ALS, and the context key ``shift``."""

from __future__ import annotations

import json

import numpy as np
import pytest

import homofac as hf
from homofac.fit import plan
from homofac.errors import HomofacError
from homofac.factorization import Factor, Factorization, Term
from homofac.fit import als, draw, pipeline, polish, sampling, sums
from homofac.fit.polish import recorded_linear
from homofac.app import budget, run
from homofac.app.config import Config
from homofac.fit.options import DEFAULT_VALIDATION, FitOptions, LinearOptions, SamplingOptions
from homofac.fit.samples import Samples
from homofac.fit.structures import Structure
from homofac.fit.system import texture_layout
from homofac.light.lighting import DEFAULT_SHIFT
from homofac.param import parametrizations as pz
from homofac.param import projections as pj
from homofac.target import Target
from helpers import nrw_sum

S = 8
RNG = np.random.default_rng(7)


def _pairs(count: int, rng=RNG):
    n = rng.normal(size=(count, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    v = rng.normal(size=(count, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return n, np.where(np.sum(n * v, 1, keepdims=True) < 0, -v, v)


def _nrmse(pred, y):
    pred, y = np.asarray(pred, np.float64), np.asarray(y, np.float64)
    return float(np.mean(np.linalg.norm(pred - y, axis=0) / np.linalg.norm(y, axis=0)))


def test_r_off_is_r_for_frontal_views_and_lifts_grazing_ones_by_atan_beta():
    n, v = _pairs(2000)
    beta = 0.3
    r_off = np.asarray(pj.apply("r_off", n, v, {"shift": beta}))
    r = np.asarray(pj.apply("r", n, v))
    np.testing.assert_allclose(np.linalg.norm(r_off, axis=1), 1.0, atol=1e-6)
    front = np.asarray(pj.apply("r_off", n, n, {"shift": beta}))
    np.testing.assert_allclose(front, n, atol=1e-6)  # v = n: r' = r = n
    # a grazing view (n.v = 0): r' sits atan(beta) above the horizon of n, in the plane of r and n
    t = np.cross(n, [0.0, 0.0, 1.0])
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    g = np.asarray(pj.apply("r_off", n, t, {"shift": beta}))
    np.testing.assert_allclose(np.arcsin(np.sum(g * n, 1)), np.arctan(beta), atol=1e-6)
    # the lift grows toward grazing views: the elevation of r' is never below that of r
    assert np.all(np.sum(r_off * n, 1) >= np.sum(r * n, 1) - 1e-6)
    assert np.allclose(np.asarray(pj.apply("r_off", n, v, {"shift": 0.0})), r, atol=1e-6)


@pytest.mark.parametrize("beta", [0.0, 0.1, 0.3, 0.6, 0.9])
def test_r_off_inverse_round_trips(beta):
    n, v = _pairs(20000)
    p = np.asarray(pj.apply("r_off", n, v, {"shift": beta}), np.float64)
    back, density = pj.get("r_off").invert(n, p, {"shift": beta})
    np.testing.assert_allclose(back, v, atol=1e-9)
    assert np.all((density >= 0) & (density <= 1))


@pytest.mark.parametrize("beta", [0.1, 0.3, 0.6])
def test_accepting_r_off_uniform_directions_by_the_density_gives_uniform_views(beta):
    """Directions p uniform on n's hemisphere, inverted and kept with probability density: n.v is then
    uniform on [0, 1], as for uniform views (what makes the grid design follow the validation pairs)."""
    rng = np.random.default_rng(3)
    count = 400_000
    n = np.tile([0.0, 0.0, 1.0], (count, 1))
    p = rng.normal(size=(count, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    p[:, 2] = np.abs(p[:, 2])
    v, density = pj.get("r_off").invert(n, p, {"shift": beta})
    keep = (rng.random(count) < density) & (v[:, 2] > 0)
    h, _ = np.histogram(v[keep, 2], bins=10, range=(0, 1))
    assert np.all(np.abs(h / h.mean() - 1) < 0.05), h / h.mean()
    # without the density the frontal views would be over-represented
    h0, _ = np.histogram(v[v[:, 2] > 0, 2], bins=10, range=(0, 1))
    assert h0[-1] / h0[0] > 1.05 and abs(h[-1] / h[0] - 1) < 0.05


def test_grid_design_on_r_off_reads_one_texel_per_lookup_and_follows_the_validation_distribution():
    ctx = {"shift": 0.3}
    g = sampling.grouped_grid("dual_paraboloid", S, 20000, 3, projection="r_off", context=ctx)
    p = g.flatten()
    assert len(p) == 20000 and np.all(np.sum(p.a * p.b, -1) > 0)
    lay = texture_layout("n", "dual_paraboloid", S)
    r_off = np.asarray(pj.apply("r_off", p.a, p.b, ctx))
    assert als.single_texel("dual_paraboloid", S, p.a, lay.unknown_of_texel) is not None
    assert als.single_texel("dual_paraboloid", S, r_off, lay.unknown_of_texel) is not None
    # the plain r of these pairs is off the grid
    assert als.single_texel("dual_paraboloid", S, np.asarray(pj.apply("r", p.a, p.b)), lay.unknown_of_texel) is None
    nv = np.sum(p.a * p.b, -1)
    h, _ = np.histogram(nv, bins=5, range=(0, 1))
    assert np.all(np.abs(h / h.mean() - 1) < 0.12), h / h.mean()  # texel-centre quantised, about uniform


def test_grid_design_refuses_a_projection_without_an_inverse():
    with pytest.raises(HomofacError, match="no inverse"):
        sampling.grouped_grid("dual_paraboloid", S, 100, 0, projection="v")


def _nro_sum(K: int, normal: bool, beta: float) -> Factorization:
    """An exact sum of the NRO (or RO) structure with the n.v factor: nrw_sum read at r_off."""
    m = nrw_sum(K, S, seed=30, normal=normal)
    terms = tuple(Term(tuple(Factor("r_off" if f.projection == "r" else f.projection, f.texture) for f in t.factors),
                       t.correction, t.kind) for t in m.terms)
    return Factorization("lighting", "lighting", m.textures, terms, {"shift": beta}, "nro_sum")


@pytest.mark.parametrize("name,normal", [  # NRO, with its normal factor, compiles twice as long: slow
    pytest.param("NRO", True, marks=pytest.mark.slow), ("RO", False)])
def test_als_recovers_an_exact_off_specular_sum(name, normal):
    beta = 0.3
    model = _nro_sum(2, normal, beta)
    target = Target("lighting", lambda n, v: model.evaluate(n, v), "lighting", {"shift": beta})
    g = sampling.grouped_grid("dual_paraboloid", S, 6000, 0, projection="r_off", context={"shift": beta})
    p, vp = g.flatten(), sampling.grouped_random(2000, 1).flatten()
    s = Samples(p.a, p.b, np.asarray(model.evaluate(p.a, p.b)), vp.a, vp.b, np.asarray(model.evaluate(vp.a, vp.b)))
    err = {}
    for K in (1, 2):
        fit = sums.fit_sum(target, Structure(name, K, None, True), "dual_paraboloid", S, s,
                           LinearOptions(iterations=60, laplacian=1e-4, start="product"))
        assert fit.solver["method"] == "als"
        assert {f.projection for t in fit.model.terms for f in t.factors} >= {"r_off", "nv"}
        assert fit.model.context == {"shift": beta}
        err[K] = _nrmse(fit.model.evaluate(s.val_a, s.val_b), s.val_y)
    assert err[2] < 0.03 and err[2] < 0.5 * err[1], err


@pytest.mark.slow  # two full fits; the fast suite fits r_off in the chooser test below and the exact RO sum
def test_nro_fits_end_to_end_and_beats_nr_on_a_glossy_metal_under_lamps(tmp_path):
    """factorize(target, "NRO") fills the context (shift = the roughness), draws its own grid and fits by
    ALS; under the interior's lamps its validation error is below NR's of the same structure; the saved
    directory loads back to the same values and its shader reads r_off."""
    brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    target = hf.light.lighting_target(brdf, hf.light.load_environment("interior", 8))
    kw = dict(texture_size=S, diffuse="fitted", nv_factor=True, sampling={"count": 20000, "validation": 3000})
    nr = hf.fit.factorize(target, "NR", **kw)
    nro = hf.fit.factorize(target, "NRO", **kw)
    assert nro.model.context == {"shift": pytest.approx(0.15)} and nro.solver["method"] == "als"
    assert [f.projection for f in nro.model.terms[1].factors] == ["n", "r_off", "nv"]
    e = {k: f.metrics["validation"]["float"]["nrmse"] for k, f in (("NR", nr), ("NRO", nro))}
    assert e["NRO"] < e["NR"], e
    nro.save(tmp_path / "out", shaders=["glsl"])
    doc = json.loads((tmp_path / "out" / "factorization.json").read_text())
    assert doc["context"] == {"shift": pytest.approx(0.15)}
    back = hf.load(tmp_path / "out")
    n, v = _pairs(500)
    np.testing.assert_allclose(np.asarray(back.evaluate(n, v)), np.asarray(nro.evaluate(n, v)), rtol=1e-5, atol=1e-6)
    assert "hf_proj_r_off" in (tmp_path / "out" / "shader.glsl").read_text()


def test_shift_defaults_to_the_roughness_and_is_checked():
    env = hf.light.load_environment("interior", 8)
    gold = hf.brdf.cook_torrance(kd=0.05, ks=1.0, roughness=0.3, f0=0.9)
    mirror = hf.brdf.ggx(kd=0.0, ks=1.0, roughness=0.1, f0=0.95)
    assert hf.light.lighting_target(gold, env, parametrization="NRO").context == {"shift": pytest.approx(0.15)}
    assert hf.light.lighting_target(mirror, env, parametrization="RO").context == {"shift": pytest.approx(0.1)}
    lam = hf.brdf.lambert(kd=0.5)
    assert hf.light.lighting_target(lam, env, parametrization="NRO").context["shift"] == DEFAULT_SHIFT
    assert hf.light.lighting_target(gold, env, parametrization="NRO", shift=0.2).context["shift"] == pytest.approx(0.2)
    assert hf.light.lighting_target(gold, env, parametrization="NR").context == {}
    for bad in (1.5, 0.95, -0.1, "0.3", [0.1, 0.2], float("nan"), True):
        with pytest.raises(HomofacError, match="context.shift must be") as e:
            hf.light.lighting_target(gold, env, parametrization="NRO", shift=bad)
        assert "\n" not in str(e.value)
    with pytest.raises(HomofacError, match="shift is beta of the off-specular reflection of NRO and RO, not of NR"):
        hf.light.lighting_target(gold, env, parametrization="NR", shift=0.2)
    with pytest.raises(HomofacError, match="unknown context key"):
        pj.check_context("beta", 0.3)
    assert pz.reflection_projection("NRO") == pz.reflection_projection("RO") == "r_off"
    assert pz.reflection_projection("NR") == pz.reflection_projection("NRW") == "r"


def test_loading_refuses_a_bad_shift(tmp_path):
    model = _nro_sum(1, True, 0.3)
    hf.fit.Result(model).save(tmp_path / "out")
    path = tmp_path / "out" / "factorization.json"
    doc = json.loads(path.read_text())
    for bad in (2.0, "x", [0.3]):
        doc["context"] = {"shift": bad}
        path.write_text(json.dumps(doc))
        with pytest.raises(HomofacError, match="context.shift must be") as e:
            hf.load(tmp_path / "out")
        assert "\n" not in str(e.value)


def test_sampling_cache_keys_the_grid_projection_and_its_shift():
    from homofac.fit.draw import cache_settings
    from homofac.fit.options import SamplingOptions

    s = SamplingOptions(kind="grid", size=8, mapper="dual_paraboloid")
    assert "grid_projection" not in cache_settings(s, "lighting", "NR", {})
    a = cache_settings(s, "lighting", "NRO", {"shift": 0.3})
    b = cache_settings(s, "lighting", "NRO", {"shift": 0.2})
    assert a["grid_projection"] == {"projection": "r_off", "shift": pytest.approx(0.3)} and a != b


def test_max_lookups_draws_grid_pairs_per_direction_and_keeps_the_chosen_structures_own():
    """With NR the preset's candidates lie on its grid directions (r_off: NRO, RO) and get grid pairs of
    their own, drawn once, not NR's; the kept result carries the pairs it was fitted on (its refit state)
    and the shift in its model and target."""
    brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    target = hf.light.lighting_target(brdf, hf.light.load_environment("interior", 8))
    logs = []
    fac = hf.fit.factorize(target, "NR", texture_size=S, max_lookups=4,
                           advanced={"linear": {"iterations": 8, "polish": 0}, "validation_light": 8},
                           sampling={"count": 4000, "validation": 1000, "cache": False}, log=logs.append)
    tried = {t["label"]: t for t in fac.selection["tried"]}
    raced = fac.selection["race"]["rounds"][0]["labels"]  # every candidate runs the race's first sweeps
    assert set(raced) == {"E'+NROW x1", "E'+ROW x1+R", "E'+RO x1+HW x1"}  # fast's directions: r_off
    assert tried and set(tried) <= set(raced) and set(tried) == set(fac.selection["race"]["kept"])
    assert sum("training pairs" in m for m in logs) == 1  # one grid, on r_off (RO's with or without HW)
    best = min(tried.values(), key=lambda t: t["validation_nrmse"])
    assert fac.selection["chosen"]["label"] == best["label"]
    assert fac.solver["nv_balance"] == plan.PRESETS["fast"].nv_balance  # the chooser's default, not given
    chosen = fac.solver["structure"]["parametrization"]
    proj = pz.reflection_projection(chosen)
    lay = texture_layout("n", "dual_paraboloid", S)
    train = fac.state.train
    d = np.asarray(pj.apply(proj, train.a, train.b, fac.model.context))
    assert als.single_texel("dual_paraboloid", S, d, lay.unknown_of_texel) is not None  # its own grid
    if proj == "r_off":
        assert fac.model.context["shift"] == pytest.approx(0.15)
        assert set(fac.target.context) == set(fac.model.context)  # with the light of a highlight term, if kept
        for k, v in fac.model.context.items():
            np.testing.assert_allclose(np.asarray(fac.target.context[k]), np.asarray(v))
    # samples given: only the candidates on their direction
    s = hf.fit.draw_samples(target, "NR", {"kind": "grid", "size": S, "mapper": "dual_paraboloid", "count": 4000,
                                           "validation": 1000, "cache": False})
    only = hf.fit.factorize(target, "NR", texture_size=S, max_lookups=4, samples=s,
                            advanced={"linear": {"iterations": 8, "nv_balance": 0.0, "polish": 0},
                                      "validation_light": 8})
    assert [t["label"] for t in only.selection["tried"]] == ["E'+NRW x1"]
    assert only.solver["nv_balance"] == 0.0  # given: kept


def test_a_budget_above_balanced_draws_best_s_grid_pairs_unless_the_count_is_given(monkeypatch):
    """A chooser budget above balanced's takes the ``best`` preset's grid count; a given count, balanced's
    budget or one structure keep theirs; the memory estimate reads the same count (behaviour, not the
    presets' numbers: those are tuned in fit/plan.py, so ``best``'s count is set apart from balanced's here)."""
    monkeypatch.setitem(plan.PRESETS, "best", plan.PRESETS["best"]._replace(grid_count=2 * plan.PRESETS["balanced"].grid_count))
    q = plan.budget_of(FitOptions(preset="balanced"))
    best = plan.grid_count(FitOptions(preset="best"))
    assert best > plan.grid_count(FitOptions(preset="balanced"))
    assert plan.grid_count(FitOptions(max_lookups=q + 1)) == best
    assert plan.grid_count(FitOptions(target_error=0.1, terms=2)) == best  # the ladder's budget is best's
    assert plan.grid_count(FitOptions(max_lookups=q)) == plan.grid_count(FitOptions(preset="balanced"))
    assert plan.grid_count(FitOptions(terms=6, nv_factor=True)) == sampling.GRID_COUNT
    assert plan.grid_count(FitOptions(max_lookups=q + 1, sampling={"count": 1000})) == 1000
    assert pipeline.resolve_sampling(FitOptions(max_lookups=q + 1), "lighting", "dual_paraboloid").count == best
    gold = {"kind": "lighting", "brdf": {"model": "cook_torrance", "roughness": 0.3}, "environment": {"file": "forest"}}
    small = budget.estimate(Config.model_validate({"target": gold, "max_lookups": q}))
    large = budget.estimate(Config.model_validate({"target": gold, "max_lookups": q + 1}))
    assert large["samples"] > small["samples"]


def test_a_budget_above_balanced_ranks_on_best_s_validation_pairs_unless_their_count_is_given(monkeypatch):
    """A chooser budget above balanced's ranks on the ``best`` preset's validation count; a given count
    (even the default's value, or 0), balanced's budget or one structure keep theirs; resolve_sampling and
    the memory estimate agree (``best``'s count set apart from the default's here, as above)."""
    monkeypatch.setitem(plan.PRESETS, "best", plan.PRESETS["best"]._replace(validation=4 * DEFAULT_VALIDATION))
    q = plan.budget_of(FitOptions(preset="balanced"))
    default = DEFAULT_VALIDATION
    best = plan.validation_count(FitOptions(preset="best"))
    assert best > default
    assert plan.validation_count(FitOptions(max_lookups=q + 1)) == best
    assert plan.validation_count(FitOptions(target_error=0.1, terms=2)) == best
    assert plan.validation_count(FitOptions(max_lookups=q)) == plan.validation_count(FitOptions(preset="balanced"))
    assert plan.validation_count(FitOptions(terms=6, nv_factor=True)) == default
    assert plan.validation_count(FitOptions(max_lookups=q + 1, sampling={"validation": default})) == default
    assert plan.validation_count(FitOptions(max_lookups=q + 1, sampling={"validation": 0})) == 0
    for kind in ("grid", "texels"):
        opts = FitOptions(max_lookups=q + 1, sampling={"kind": kind})
        assert pipeline.resolve_sampling(opts, "lighting", "dual_paraboloid").validation == best
    gold = {"kind": "lighting", "brdf": {"model": "cook_torrance", "roughness": 0.3}, "environment": {"file": "forest"}}
    count = plan.grid_count(FitOptions(preset="best"))
    own = budget.estimate(Config.model_validate({"target": gold, "max_lookups": q + 1,
                                                 "sampling": {"count": count, "validation": default}}))
    rule = budget.estimate(Config.model_validate({"target": gold, "max_lookups": q + 1}))
    assert rule["samples"] > own["samples"]  # the same grid, more validation pairs


def test_a_recorded_config_keeps_the_validation_count_unset_so_a_refit_applies_the_same_rule():
    """Not given, ``sampling.validation`` is recorded as null: the recorded quality-mode config, read back
    (as a refit from disk reads it), still draws the preset's validation pairs, and the refit's layout check
    compares the counts the rule gives (a record with the default's value written out agrees with a
    config that leaves it out; one with another count does not)."""
    gold = {"kind": "lighting", "brdf": {"model": "cook_torrance", "roughness": 0.3}, "environment": {"file": "forest"}}
    cfg = Config.model_validate({"target": gold, "max_lookups": 16})
    record = cfg.model_dump(mode="json")
    assert record["sampling"]["validation"] is None
    back = pipeline.options(**{k: v for k, v in record.items() if k in FitOptions.model_fields})
    assert plan.validation_count(back) == plan.validation_count(FitOptions(preset="best"))
    assert run.layout_difference(record, cfg, "lighting") is None
    plain = Config.model_validate({"target": gold, "terms": 2, "nv_factor": True})
    old = plain.model_dump(mode="json")
    old["sampling"]["validation"] = DEFAULT_VALIDATION  # how results saved before 2026-12-05 record it
    assert run.layout_difference(old, plain, "lighting") is None
    old["sampling"]["validation"] = 5000
    assert "sampling.validation: 20000 in the config, 5000 in the saved" in run.layout_difference(old, plain, "lighting")
    # outside the pipeline (hf.fit.draw_samples) a count not given is the default's
    assert draw.counted(SamplingOptions()).validation == DEFAULT_VALIDATION
    assert draw.counted(SamplingOptions(validation=0)).validation == 0


@pytest.mark.slow
def test_the_chooser_polishes_the_structure_it_keeps_and_a_refit_repeats_it():
    """max_lookups ranks the candidates on their grid ALS fits, then polishes the kept one off the grid
    (the preset's Levenberg-Marquardt steps; ``balanced``'s, at a 4-lookup budget: ``fast`` has no polish);
    the selection records the validation error before and
    after, linear.polish given (0 here) turns it off, and a fresh refit on the same target repeats it
    (its solver record says what the full run did)."""
    brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    target = hf.light.lighting_target(brdf, hf.light.load_environment("interior", 8))
    kw = dict(texture_size=S, preset="balanced", max_lookups=4, sampling={"count": 20000, "validation": 3000, "cache": False})
    no_highlights = {"highlights": {"terms": 0}}  # a kept highlight structure is not polished
    fac = hf.fit.factorize(target, "NR", advanced={**no_highlights, "linear": {"iterations": 8, "polish_size": 8}},
                           **kw)
    assert not Structure.of(fac.solver["structure"]).highlights.terms
    val = lambda r: r.metrics["validation"]["float"]["nrmse"]  # noqa: E731
    note = fac.selection["polish"]
    before, after = note["validation_nrmse_before"], note["validation_nrmse_after"]
    assert note["steps"] == plan.PRESETS["balanced"].polish
    assert before == pytest.approx(fac.selection["chosen"]["validation_nrmse"])
    assert val(fac) == pytest.approx(after)
    assert after < before  # small lamps: detail at the texel scale, which the grid fit never sees between centres
    assert fac.solver["polish"]["steps"] == plan.PRESETS["balanced"].polish and fac.solver["polish"]["size"] == 8
    assert fac.selection["chosen"]["label"] == Structure.of(fac.solver["structure"]).label()
    off = hf.fit.factorize(target, "NR", advanced={**no_highlights, "linear": {"iterations": 8, "polish": 0}}, **kw)
    assert "polish" not in off.selection and "polish" not in off.solver
    assert val(off) == pytest.approx(before, rel=1e-5)  # the same ALS fits, the same choice
    again = hf.fit.refit(fac, brdf=brdf, start="fresh")
    assert again.solver["polish"]["steps"] == plan.PRESETS["balanced"].polish
    assert again.solver["nv_balance"] == fac.solver["nv_balance"] == plan.PRESETS["balanced"].nv_balance
    assert val(again) == pytest.approx(val(fac), rel=1e-3)


@pytest.mark.slow
def test_the_quality_mode_polishes_a_kept_highlight_structure_where_the_validation_error_falls():
    """Above balanced's budget a kept structure with a highlight term is polished in three stages (without,
    then with the ridge pairs, and with them from the ALS fit), and the best stage is kept exactly when its
    validation error (with the ridge stratum) is below the ALS fit's; the result is the kept one. The
    structure, the line size and the polish are all chosen on that estimate."""
    brdf = hf.brdf.cook_torrance(kd=(0.3, 0.05, 0.05), ks=1.0, roughness=0.2, f0=0.04)
    target = hf.light.lighting_target(brdf, hf.light.load_environment("city", 8))
    fac = hf.fit.factorize(target, "NR", texture_size=S, max_lookups=plan.PRESETS["balanced"].lookups + 1,
                           diffuse="fitted", advanced={"highlights": {"terms": 1, "fresnel": True, "cosine": True},
                                                       "linear": {"iterations": 6, "polish_size": 8}},
                           sampling={"count": 20000, "validation": 3000, "cache": False})
    assert Structure.of(fac.solver["structure"]).highlights.terms == 1
    note = fac.selection["polish"]
    assert note["rule"] == "vote" and note["steps"] == plan.PRESETS["best"].polish
    key = sums.RIDGE_METRIC
    sel = fac.selection
    assert sel["metric"] == key and sel["chosen"][key] == min(t[key] for t in sel["tried"])
    assert "lines" not in sel  # 32-texel lines are best's line ratio x 8: no line vote
    # the polish starts from what the structure vote kept, or from its disc version where the disc vote kept that
    disc = sel.get("disc")
    entering = ({k: disc[k][1] for k in ("validation_nrmse", key)} if disc and disc["kept"] else sel["chosen"])
    assert note["validation_nrmse_before"] == pytest.approx(entering["validation_nrmse"])
    assert note[key + "_before"] == pytest.approx(entering[key])
    # the stages the plan's polish vote names: with polish_direct the ridge pairs from the ALS fit alone, else
    # three (without, then with the ridge pairs, and with them from the ALS fit)
    stages, ridge = note["stages"], plan.PRESETS["best"].ridge
    three = [(0, "als"), (ridge, "polish"), (ridge, "als")]
    which = [2] if plan.PRESETS["best"].polish_direct else [0, 1, 2]  # each stage's index among the three
    assert [(st["ridge"], st["start"]) for st in stages] == [three[i] for i in which]
    best = int(np.argmin([st[key] for st in stages]))
    assert note[key + "_after"] == stages[best][key]
    assert note["kept"] == (note[key + "_after"] < note[key + "_before"])
    kept = note["validation_nrmse_after"] if note["kept"] else note["validation_nrmse_before"]
    assert fac.metrics["validation"]["float"]["nrmse"] == pytest.approx(kept)
    assert ("polish" in fac.solver) == note["kept"]  # a refit repeats what was kept
    assert note["stage"] == (which[best] if note["kept"] else None)
    assert (note["ridge"], note["start"]) == ((stages[best]["ridge"], stages[best]["start"]) if note["kept"]
                                              else (0, None))
    if note["kept"]:  # the record says which path a refit takes
        assert polish.recorded_direct(fac.solver) == (note["stage"] == 2)
        assert recorded_linear(LinearOptions(), fac.solver).ridge == note["ridge"]
    if note["stage"] == 1:
        assert fac.solver["polish"]["ridge"]["pairs"] == plan.PRESETS["best"].ridge
        assert "ridge" not in fac.solver["polish"]["first"]
    elif note["stage"] == 0:
        assert "ridge" not in fac.solver["polish"]


class _Voted:
    """The part of a Result the line vote reads: its plain validation nrmse and its selection."""

    def __init__(self, plain: float, ridge: float, selection: dict | None = None):
        self.metrics = {"validation": {"float": {"nrmse": plain}}}
        self.ridge, self.selection = ridge, selection or {}

    def replace(self, selection):
        return _Voted(self.metrics["validation"]["float"]["nrmse"], self.ridge, selection)


def test_the_line_vote_keeps_the_lowest_score_and_records_both_figures():
    """With the ridge stratum's score the line vote keeps the size of lowest score, not of lowest plain
    validation nrmse, and records both (the gold under the city sun: plain 0.062 / 0.080, the ridge
    stratum the other way)."""
    fitted = {128: _Voted(0.080, 0.110)}
    first = _Voted(0.062, 0.128, {"metric": sums.RIDGE_METRIC})
    structure = Structure.of({"parametrization": "NR", "terms": 1, "nv_factor": True})
    kept, line = pipeline._line_vote(first, structure, (32, 128), lambda st, size: fitted[size], lambda m: None,
                                     lambda r: r.ridge)
    assert line == 128 and kept.ridge == 0.110
    assert kept.selection["lines"] == {"sizes": [32, 128], "validation_nrmse": [0.062, 0.080], "kept": 128,
                                       sums.RIDGE_METRIC: [0.128, 0.110]}
    assert kept.selection["metric"] == sums.RIDGE_METRIC
    plain, line = pipeline._line_vote(first, structure, (32, 128), lambda st, size: fitted[size], lambda m: None)
    assert line == 32 and sums.RIDGE_METRIC not in plain.selection["lines"]


@pytest.mark.slow  # about 40 s of compiling (three Levenberg-Marquardt candidates), more on a busy machine
def test_max_lookups_with_texel_sampling_fits_the_off_specular_candidates_with_their_shift():
    """Texel pairs are one pool for every candidate (they do not lie on a grid of r or r_off), but each
    candidate reads its own parametrization's context: NRO / RO read ``shift`` (the crash was "projection
    r_off needs context['shift']" after the NR candidates had been fitted)."""
    brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    target = hf.light.lighting_target(brdf, hf.light.load_environment("interior", 8))
    logs = []
    fac = hf.fit.factorize(target, "NR", texture_size=S, max_lookups=4,
                           advanced={"highlights": {"terms": 0}, "analysis": {"size": 4},
                                     "linear": {"iterations": 1, "polish": 0}},
                           sampling={"kind": "texels", "size": 4, "validation": 200, "cache": False},
                           log=logs.append)
    labels = {t["label"] for t in fac.selection["tried"]}
    assert any("O" in lab.split("+")[1] for lab in labels)  # an off-specular candidate was fitted
    assert sum("training pairs" in m for m in logs) == 1  # one texel pool for all
    if "shift" in pz.get(fac.solver["structure"]["parametrization"]).context:
        assert "shift" in fac.model.context


def test_off_grid_figures_are_the_mean_squared_residuals_on_the_strided_grid_the_off_grid_and_the_validation_pairs():
    """The polish gate's evidence: the kept fit's mean squared residual on every k-th grid pair, on the off-grid
    pairs and on the validation pairs (each over its own pairs and the 3 channels), the off-grid one over the
    grid one as the ratio; evaluated in padded calls of a fixed size (the last call's padding cut off)."""
    class Zero:  # a model that reads 0 everywhere: the residual is the target itself
        @staticmethod
        def evaluate(a, b):
            return np.zeros((a.shape[0], 3), np.float32)

    rng = np.random.default_rng(0)
    a, b = (rng.normal(size=(10, 3)).astype(np.float32) for _ in range(2))
    y = np.where((np.arange(10) % 2 == 0)[:, None], 1.0, 5.0) * np.ones((10, 3), np.float32)  # every 2nd reads 1
    val_y = np.full((7, 3), 3.0, np.float32)
    samples = Samples(a, b, y, a[:7], b[:7], val_y)
    off = Samples(a[:5], b[:5], np.full((5, 3), 2.0, np.float32), a[:0], b[:0], val_y[:0])
    fig = polish.off_grid_figures(Zero(), samples, off, stride=2, chunk=4)
    assert (fig.grid, fig.off, fig.ratio, fig.validation) == pytest.approx((1.0, 4.0, 4.0, 9.0))
    every = polish.off_grid_figures(Zero(), samples, off, stride=1, chunk=4)
    assert every.grid == pytest.approx(13.0) and every.ratio == pytest.approx(4.0 / 13.0)


@pytest.mark.slow
def test_the_polish_gate_skips_the_polish_where_the_off_grid_residual_is_not_above_it_and_records_why(monkeypatch):
    """A plan's ``polish_gate`` above the kept fit's off-grid / grid residual ratio skips the polish: the result is the
    ALS fit, ``selection.polish`` records the rule, the gate and the figures, and the solver record has no polish (so a
    refit does not polish either); a gate below the ratio polishes and votes as before, the figures recorded."""
    brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    target = hf.light.lighting_target(brdf, hf.light.load_environment("interior", 8))
    kw = dict(texture_size=S, preset="balanced", max_lookups=4, sampling={"count": 20000, "validation": 3000, "cache": False},
              advanced={"highlights": {"terms": 0}, "linear": {"iterations": 8, "polish_size": 8}})
    monkeypatch.setitem(plan.PRESETS, "balanced", plan.PRESETS["balanced"]._replace(polish_gate=1e9))
    gated = hf.fit.factorize(target, "NR", **kw)
    note = gated.selection["polish"]
    assert note["rule"] == "gate" and not note["kept"] and note["gate"] == 1e9
    assert 0 < note["off_grid"]["ratio"] == pytest.approx(note["off_grid"]["off"] / note["off_grid"]["grid"])
    assert "polish" not in gated.solver
    monkeypatch.setitem(plan.PRESETS, "balanced", plan.PRESETS["balanced"]._replace(polish_gate=1e-9))
    voted = hf.fit.factorize(target, "NR", **kw)
    assert voted.selection["polish"]["rule"] == "vote"
    assert voted.selection["polish"]["off_grid"] == pytest.approx(note["off_grid"])  # the same ALS fit, the same pairs
    assert voted.selection["polish"]["validation_nrmse_before"] == pytest.approx(
        gated.metrics["validation"]["float"]["nrmse"], rel=1e-6)
