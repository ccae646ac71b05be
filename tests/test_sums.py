"""Sums of products in linear space (issue 13): structures, grid ALS, Levenberg-Marquardt, the choice
within a lookup budget, the exact diffuse term, and the config keys ``terms``, ``diffuse``, ``nv_factor``,
``max_lookups``."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import homofac as hf
from homofac.brdf import measured
from homofac.errors import HomofacError
from homofac.factorization import Factor, Factorization, Term, Texture
from homofac.fit import als, pipeline, refine, sampling, structures, sums
from homofac.fit.options import LinearOptions
from homofac.fit.polish import recorded_linear
from homofac.fit.samples import Samples, evaluate_grouped
from homofac.fit.structures import Structure
from homofac.fit.system import texture_layout
from homofac.light.sources import bundled
from homofac.param import mappers
from homofac.target import Target
from helpers import nrw_sum

S = 8


def _nrmse(pred, y):
    pred, y = np.asarray(pred, np.float64), np.asarray(y, np.float64)
    return float(np.mean(np.linalg.norm(pred - y, axis=0) / np.linalg.norm(y, axis=0)))


def _model_target(model) -> Target:
    return Target("lighting", lambda n, v: model.evaluate(n, v), "lighting")


def _samples(target, kind="grid", count=6000, seed=0, validation=2000):
    if kind == "grid":
        g = sampling.grouped_grid("dual_paraboloid", S, count, seed)
    else:
        g = sampling.grouped_random(count, seed)
    p = g.flatten()
    vg = sampling.grouped_random(validation, seed + 1)
    v = vg.flatten()
    y = np.asarray(target(p.a, p.b), np.float32)
    vy = np.asarray(target(v.a, v.b), np.float32)
    return Samples(p.a, p.b, y, v.a, v.b, vy)


@pytest.fixture(scope="module")
def exact_sum():
    model = nrw_sum(2, S)
    target = _model_target(model)
    return model, target, _samples(target)


def test_skeleton_names_lookups_and_labels():
    tex, terms = structures.skeleton(Structure("NR", 2, "exact", True), "lighting", "lighting", "dual_paraboloid", 16)
    assert [t.name for t in tex] == ["E", "n0", "r0", "w0", "n1", "r1", "w1"]
    assert [len(t.factors) for t in terms] == [1, 3, 3]
    assert terms[0].kind == "irradiance" and not terms[0].fitted
    assert structures.lookups(Structure("NR", 1, "exact", True), "lighting") == 4  # the count
    assert structures.lookups(Structure("NR", 2, "exact", True), "lighting") == 7
    assert structures.lookups(Structure("NR", 2, "fitted", True, reflection=True), "lighting") == 8
    # BRDF: PQP with w(cos_i) w(cos_o) and the constant diffuse term (no lookup)
    tex, terms = structures.skeleton(Structure("PQP", 2, "exact", True), "brdf", "brdf", "parabolic", 16)
    assert terms[0].factors == () and [f[0] for f in terms[1].factors] == ["wi", "h", "wo", "cos_i", "cos_o"]


def test_candidates_fit_the_budget_cheapest_first():
    for budget in (4, 8, 16):
        c = structures.candidates("lighting", budget)
        n = [structures.lookups(s, "lighting") for s in c]
        assert c and max(n) <= budget and n == sorted(n)
        assert any(s.nv_factor for s in c)
    assert structures.candidates("lighting", 4, has_diffuse=False)[0].diffuse is None
    # the products read at the off-specular reflection (NRO) and those without p(n) at it (q(r') w(n.v),
    # parametrization RO) compete within each budget
    assert [s.label() for s in structures.candidates("lighting", 4, highlight=False)] == [
        "E'+NRW x1", "E'+NROW x1", "E'+ROW x1+R"]
    assert [s.label() for s in structures.candidates("lighting", 3, highlight=False)] == ["E'+ROW x1"]
    assert [s.label() for s in structures.candidates("lighting", 8, parametrization="NRO", highlight=False)] == [
        "E'+SS+NROW x1+R", "E'+NROW x2+R", "E'+ROW x3+R"]
    # and each family again with the highlight term of the brightest light (test_highlight.py)
    assert [s.label() for s in structures.candidates("lighting", 4)] == [
        "E'+NRW x1", "E'+NROW x1", "E'+ROW x1+R", "E'+RO x1+HW x1"]
    assert not any(s.rw_terms for b in (4, 8, 16) for s in structures.ladder("lighting", b))
    with pytest.raises(HomofacError, match="max_lookups 1"):
        structures.candidates("lighting", 1)


def test_grid_samples_hit_one_texel_each():
    g = sampling.grouped_grid("dual_paraboloid", S, 5000, 3)
    p = g.flatten()
    assert len(p) == 5000 and np.all(np.sum(p.a * p.b, -1) > 0)
    lay = texture_layout("n", "dual_paraboloid", S)
    r = 2 * np.sum(p.a * p.b, -1, keepdims=True) * p.a - p.b
    assert als.single_texel("dual_paraboloid", S, p.a, lay.unknown_of_texel) is not None
    assert als.single_texel("dual_paraboloid", S, r, lay.unknown_of_texel) is not None
    # random pairs are not grid-aligned
    q = sampling.grouped_random(500, 1).flatten()
    assert als.single_texel("dual_paraboloid", S, q.a, lay.unknown_of_texel) is None


@pytest.mark.slow
def test_als_recovers_an_exact_sum_of_two_products(exact_sum):
    model, target, s = exact_sum
    one = sums.fit_sum(target, Structure("NR", 1, None, True), "dual_paraboloid", S, s,
                       LinearOptions(iterations=40, laplacian=1e-4))
    two = sums.fit_sum(target, Structure("NR", 2, None, True), "dual_paraboloid", S, s,
                       LinearOptions(iterations=60, laplacian=1e-4, start="product"))
    assert two.solver["method"] == "als"
    e1 = _nrmse(one.model.evaluate(s.val_a, s.val_b), s.val_y)
    e2 = _nrmse(two.model.evaluate(s.val_a, s.val_b), s.val_y)
    assert e2 < 0.02, e2  # the target is exactly of this structure
    assert e2 < 0.5 * e1
    assert two.model.lookups == 6 and len(two.model.terms) == 2


def test_als_fits_products_without_a_normal_factor():
    """Parametrization R with the n.v factor (sum_t q_t(r) w_t(n.v), for near-mirrors under lamps) is an ALS
    structure on grid samples: it recovers an exact sum of that form, far better than one term does."""
    model = nrw_sum(2, S, seed=20, normal=False)
    target = _model_target(model)
    s = _samples(target)
    err = {}
    for K in (1, 2):
        fit = sums.fit_sum(target, Structure("R", K, None, True), "dual_paraboloid", S, s,
                           LinearOptions(iterations=60, laplacian=1e-4, start="product"))
        assert fit.solver["method"] == "als" and fit.model.lookups == 2 * K
        err[K] = _nrmse(fit.model.evaluate(s.val_a, s.val_b), s.val_y)
    assert err[2] < 0.02 and err[2] < 0.5 * err[1], err


def test_als_fits_a_sum_that_mixes_products_with_and_without_a_normal_factor():
    """``rw_terms`` puts q(r) w(n.v) terms beside the p(n) q(r) w(n.v) products (texture names r1, w1 after
    n0, r0, w0): ALS recovers an exact sum of one of each, which neither two NRW products nor one fit
    as well."""
    model = nrw_sum(2, S, seed=30, normal=(True, False))
    target = _model_target(model)
    s = _samples(target)
    err = {}
    for name, structure in {"NRW+RW": Structure("NR", 1, None, True, rw_terms=1),
                            "NRW": Structure("NR", 1, None, True)}.items():
        fit = sums.fit_sum(target, structure, "dual_paraboloid", S, s,
                           LinearOptions(iterations=60, laplacian=1e-4, start="product"))
        assert fit.solver["method"] == "als"
        err[name] = _nrmse(fit.model.evaluate(s.val_a, s.val_b), s.val_y)
        if name == "NRW+RW":
            assert fit.model.lookups == 5
            assert [[(f.projection, f.texture) for f in t.factors] for t in fit.model.terms] == [
                [("n", "n0"), ("r", "r0"), ("nv", "w0")], [("r", "r1"), ("nv", "w1")]]
            assert Structure.of(fit.solver["structure"]) == structure
    assert err["NRW+RW"] < 0.02 and err["NRW+RW"] < 0.5 * err["NRW"], err


def test_rw_terms_are_refused_where_they_mean_nothing():
    with pytest.raises(HomofacError, match="rw_terms: the q\\(r\\) w\\(n.v\\) terms are for lighting"):
        structures.skeleton(Structure("PQP", 1, rw_terms=1), "brdf", "brdf", "parabolic", 8)
    with pytest.raises(HomofacError, match="rw_terms: R products are already"):
        structures.skeleton(Structure("R", 1, None, True, rw_terms=1), "lighting", "lighting", "dual_paraboloid", 8)
    with pytest.raises(HomofacError, match="rw_terms"):
        pipeline.options("NR", advanced={"rw_terms": -1})


@pytest.mark.slow
def test_levenberg_marquardt_matches_on_random_samples(exact_sum):
    model, target, _ = exact_sum
    s = _samples(target, kind="random", count=6000)
    fit = sums.fit_sum(target, Structure("NR", 1, None, True), "dual_paraboloid", S, s,
                       LinearOptions(method="levenberg_marquardt", iterations=15, laplacian=1e-4, start="product"))
    assert fit.solver["method"] == "levenberg_marquardt"
    assert fit.solver["objective"] < fit.solver["objective_start"]
    with pytest.raises(HomofacError, match="grid samples"):
        sums.fit_sum(target, Structure("NR", 1, None, True), "dual_paraboloid", S, s, LinearOptions(method="als"))


@pytest.mark.slow
def test_jaxopt_backend_reaches_a_comparable_objective(exact_sum):
    pytest.importorskip("jaxopt")
    model, target, s = exact_sum
    kw = dict(method="levenberg_marquardt", iterations=10, laplacian=1e-3, start="product")
    a = sums.fit_sum(target, Structure("NR", 1, None, True), "dual_paraboloid", S, s, LinearOptions(**kw))
    b = sums.fit_sum(target, Structure("NR", 1, None, True), "dual_paraboloid", S, s,
                     LinearOptions(backend="jaxopt", **kw))
    assert b.solver["backend"] == "jaxopt"
    assert b.solver["objective"] < b.solver["objective_start"]
    assert b.solver["objective"] < 1.5 * a.solver["objective"] + 1e-3 * a.solver["objective_start"]


@pytest.fixture(scope="module")
def plastic():
    env = hf.light.load_environment(str(bundled("forest")), resolution=8)
    brdf = hf.brdf.cook_torrance(kd=(0.3, 0.25, 0.2), ks=1.0, roughness=0.6, f0=0.04)
    target = hf.light.lighting_target(brdf, env)
    g = sampling.grouped_grid("dual_paraboloid", S, 8000, 0)
    p = g.flatten()
    vg = sampling.grouped_random(3000, 1)
    v = vg.flatten()
    s = Samples(p.a, p.b, np.asarray(evaluate_grouped(target, g)), v.a, v.b, np.asarray(evaluate_grouped(target, vg)))
    return target, s


@pytest.mark.slow
def test_exact_diffuse_term_is_the_irradiance(plastic):
    target, s = plastic
    fit = sums.fit_sum(target, Structure("NR", 1, "exact", True), "dual_paraboloid", S, s, LinearOptions(iterations=10))
    m = fit.model
    assert m.terms[0].kind == "irradiance" and [f.texture for f in m.terms[0].factors] == ["E"]
    e = hf.baselines.base.irradiance_map(target.fn.env, "dual_paraboloid", S)
    d0 = np.asarray(m.term_values(s.a[:50], s.b[:50])[0])
    kd = np.array([0.3, 0.25, 0.2])
    # grid normals are texel centres: the term is kd/pi E at that texel, exactly
    idx, w = mappers.bilinear("dual_paraboloid", s.a[:50], S)
    e_at = np.asarray(e).reshape(-1, 3)[np.asarray(idx)[np.arange(50), np.argmax(np.asarray(w), 1)]]
    np.testing.assert_allclose(d0, kd / np.pi * e_at, rtol=1e-4, atol=1e-6)


@pytest.mark.slow
def test_more_structure_fits_better_and_beats_one_product(plastic):
    target, s = plastic
    errs = {}
    for st in (Structure("NR", 1, None, False), Structure("NR", 1, "exact", True), Structure("NR", 2, "fitted", True)):
        f = sums.fit_sum(target, st, "dual_paraboloid", S, s, LinearOptions(iterations=20))
        errs[st.label()] = _nrmse(f.model.evaluate(s.a, s.b), s.y)
    assert errs["E+NRW x1"] < errs["NR x1"]
    assert errs["E'+NRW x2"] < errs["E+NRW x1"]


@pytest.mark.slow
def test_factorize_keys_validate_and_record(plastic, tmp_path):
    target, s = plastic
    fac = hf.fit.factorize(target, "NR", texture_size=S, terms=2, diffuse="exact", nv_factor=True, samples=s,
                           advanced={"linear": {"iterations": 5}})
    assert fac.model.lookups == 7 and fac.solver["structure"]["terms"] == 2
    assert fac.metrics["validation"]["float"]["nrmse"] < 1
    fac.save(tmp_path / "out")
    back = hf.output.load(tmp_path / "out")
    np.testing.assert_allclose(np.asarray(back.evaluate(s.val_a[:200], s.val_b[:200])),
                               np.asarray(fac.evaluate(s.val_a[:200], s.val_b[:200])), rtol=2e-5, atol=1e-6)
    for bad, msg in [({"terms": 0}, "terms"), ({"diffuse": "approx"}, "diffuse"), ({"max_lookups": 0}, "max_lookups"),
                     ({"advanced": {"linear": {"method": "adam"}}}, "linear.method"),
                     ({"advanced": {"linear": {"sweeps": 3}}}, "sweeps")]:
        with pytest.raises(HomofacError, match=msg):
            hf.fit.factorize(target, "NR", texture_size=S, samples=s, **bad)
    with pytest.raises(HomofacError, match="baseline"):
        hf.fit.factorize(target, "split_sum", texture_size=S, samples=s, terms=2)


@pytest.mark.slow
def test_max_lookups_picks_within_the_budget(plastic):
    target, s = plastic
    fac = hf.fit.factorize(target, "NR", texture_size=S, max_lookups=8, samples=s,
                           advanced={"linear": {"iterations": 5}, "analysis": {"pair": "nr"}})
    sel = fac.selection
    assert fac.model.lookups <= 8 and sel["max_lookups"] == 8
    assert fac.analysis is not None and fac.analysis["pair"] == "nr"  # Mahajan analysis beside the choice
    errs = [t["validation_nrmse"] for t in sel["tried"]]
    pol = sel.get("polish")  # the kept structure polished off the grid (ALS fits only)
    assert pol is None or pol["validation_nrmse_before"] == pytest.approx(min(errs))
    kept = pol["validation_nrmse_after"] if pol is not None and pol["kept"] else min(errs)
    assert fac.metrics["validation"]["float"]["nrmse"] == pytest.approx(kept)
    assert all(t["lookups"] <= 8 for t in sel["tried"]) and len(sel["tried"]) >= 2


@pytest.mark.slow
def test_diffuse_needs_a_kd(plastic):
    target, s = plastic
    brdf = hf.brdf.phong(exponent=20.0, ks=1.0, kd=0.0)
    t2 = hf.light.lighting_target(brdf, target.fn.env)
    fac = hf.fit.factorize(t2, "NR", texture_size=S, terms=1, nv_factor=True, samples=s,
                           advanced={"linear": {"iterations": 3}})
    assert fac.solver["start"] == "product"  # no microfacet NDF: the log-space product starts it


# ------------------------------------------------------------------------------------------------
# BRDF side: K-term PQP, zeros of measured data


def _pqp(S, colour, lobe, sharp, name="p"):
    d = np.asarray(mappers.texel_directions("parabolic", S), np.float64)
    z = np.clip(d[..., 2:3], 0, 1)
    p = (0.35 + 0.65 * z) * np.sqrt(np.asarray(colour))[None, None]
    q = 0.25 + lobe * np.exp(-sharp * (1 - z)) * np.array([1.0, 0.9, 0.85])
    tex = (Texture("p", "parabolic", S, jnp.asarray(mappers.dilate("parabolic", S, p.astype(np.float32)))),
           Texture("q", "parabolic", S, jnp.asarray(mappers.dilate("parabolic", S, q.astype(np.float32)))))
    return Factorization("brdf", "brdf", tex, (Term((Factor("wi", "p"), Factor("h", "q"), Factor("wo", "p")),
                                                     jnp.ones(3)),), {}, name)


class _Above:
    """A BRDF callable from a model: its value where wi and wo are above the horizon, else 0."""

    def __init__(self, models):
        self.models = models

    def __call__(self, wi, wo):
        flat = lambda x: x.reshape(-1, 3)  # noqa: E731
        v = sum(m.evaluate(flat(wi), flat(wo)) for m in self.models).reshape(wi.shape[:-1] + (3,))
        return jnp.where((wi[..., 2:3] > 0) & (wo[..., 2:3] > 0), v, 0.0)


@pytest.fixture(scope="module")
def garnet():
    """McCool's garnet-red shape (p(wi) q(h) p(wo), red) written as a MERL table with the grazing
    configurations (theta_d > 80 deg) unmeasured, as measured data are: about 1% of the samples read 0."""
    model = _pqp(32, (0.55, 0.08, 0.10), 3.0, 25.0)
    table = measured.tabulate_merl(_Above([model])).copy()
    _, td, _ = measured.merl_grid()
    table[np.asarray(td) > np.deg2rad(80)] = -1.0  # holes
    return model, hf.fit.brdf_target(hf.brdf.merl(table=table))


def _clean_nrmse(fac, model, s):
    clean = np.asarray(_Above([model])(jnp.asarray(s.val_a), jnp.asarray(s.val_b))) * s.val_a[:, 2:3]
    pred = np.asarray(fac.evaluate(s.val_a, s.val_b)) * s.val_a[:, 2:3]
    return _nrmse(pred, clean)


@pytest.mark.slow
def test_measured_zeros_are_left_out_of_the_log_system(garnet):
    model, target = garnet
    s = hf.fit.draw_samples(target, "PQP", {"cache": False, "validation": 5000})
    zero = float(np.mean(np.any(s.y <= 0, axis=1)))
    assert 0.003 < zero < 0.03  # "about 1% zero samples"
    auto = hf.fit.factorize(target, "PQP", samples=s)
    assert auto.solver["zeros"] == "ignore" and auto.solver["ignored_samples"] == int(round(zero * len(s.y)))
    biased = hf.fit.factorize(target, "PQP", samples=s, solver={"zeros": "bias"})
    assert _clean_nrmse(auto, model, s) <= 0.08  # issue 13's bar for garnet red
    assert auto.metrics["validation"]["float"]["nrmse"] <= 0.08
    assert _clean_nrmse(biased, model, s) > 2 * _clean_nrmse(auto, model, s)  # what the zeros cost in log space


@pytest.mark.slow
def test_two_term_pqp_fits_a_sum_of_two_lobes():
    """A BRDF that is a sum of two PQP products: two linear-space terms hold it, one product cannot."""
    a = _pqp(16, (0.5, 0.1, 0.1), 2.0, 40.0)
    b = _pqp(16, (0.1, 0.2, 0.5), 0.4, 4.0)
    target = hf.fit.brdf_target(_Above([a, b]))
    s = hf.fit.draw_samples(target, "PQP", {"cache": False, "size": 12, "validation": 3000})
    one = hf.fit.factorize(target, "PQP", texture_size=16, samples=s)
    two = hf.fit.factorize(target, "PQP", texture_size=16, samples=s, terms=2,
                           advanced={"linear": {"iterations": 30, "laplacian": 1e-4}})
    assert two.solver["method"] == "levenberg_marquardt" and two.model.lookups == 6
    e1 = one.metrics["validation"]["float"]["nrmse"]
    e2 = two.metrics["validation"]["float"]["nrmse"]
    assert e2 < 0.6 * e1, (e1, e2)


def test_als_blocks_in_chunks_equal_one_pass(exact_sum, monkeypatch):
    """Bounded memory: the normal equations summed over sample chunks equal the one-pass sums."""
    model, target, s = exact_sum
    st = Structure("NR", 2, None, True)
    one = sums.fit_sum(target, st, "dual_paraboloid", S, s, LinearOptions(iterations=3, start="product"))
    monkeypatch.setattr(als, "CHUNK_BYTES", 4 * 1024 * 3 * 4)  # chunks of 1024 samples
    jax.clear_caches()  # the chunk size is read when the sweep's programs compile
    many = sums.fit_sum(target, st, "dual_paraboloid", S, s, LinearOptions(iterations=3, start="product"))
    for a, b in zip(one.model.textures, many.model.textures):
        np.testing.assert_allclose(np.asarray(a.data), np.asarray(b.data), rtol=2e-3, atol=2e-4)


@pytest.mark.slow
def test_prefiltered_keeps_the_split_sum_and_corrects_it(plastic):
    """E + SS + corrections: the split sum's own terms are in the model unchanged, and the corrections
    lower the training error below split-sum's."""
    target, s = plastic
    fit = sums.fit_sum(target, Structure("NR", 1, "exact", True, prefiltered=True), "dual_paraboloid", S, s,
                       LinearOptions(iterations=15))
    base = hf.baselines.build("split_sum", target, "dual_paraboloid", S, None)
    m = fit.model
    assert [t.kind for t in m.terms] == ["irradiance", "prefiltered", "fitted"] and m.lookups == 6
    both = np.asarray(m.term_values(s.a[:300], s.b[:300]))[:2].sum(0)
    np.testing.assert_allclose(both, np.asarray(base.evaluate(s.a[:300], s.b[:300])), rtol=2e-3, atol=1e-5)
    assert _nrmse(m.evaluate(s.a, s.b), s.y) < _nrmse(base.evaluate(s.a, s.b), s.y)


def test_the_candidates_share_one_split_sum_start_equal_to_each_ones_own(plastic, monkeypatch):
    """The split sum's (A, B) line of a lighting is computed once for every candidate that starts from it
    (sums._dfg through sums._memo), and each candidate's start is the one it computes alone."""
    target, s = plastic
    cands = [Structure("NRO", 1, "fitted", True), Structure("RO", 1, "fitted", True, reflection=True)]
    calls, real = [], sums.ss.dfg
    monkeypatch.setattr(sums.ss, "dfg", lambda *a: calls.append(1) or real(*a))

    def start(structure):
        specs, terms = structures.skeleton(structure, "lighting", "lighting", "dual_paraboloid", S, 32)
        layouts = {t.name: texture_layout(t.name, t.mapper, t.size) for t in specs if t.role not in sums.FIXED_ROLES}
        return sums.start(target, structure, terms, layouts, s, s.y, np.ones(3), "split_sum", "dual_paraboloid", S,
                          None)[0]

    monkeypatch.setattr(sums, "_MEMO", {})
    shared = [start(c) for c in cands]
    assert len(calls) == 1
    for c, got in zip(cands, shared):
        monkeypatch.setattr(sums, "_MEMO", {})  # alone: nothing computed before
        own = start(c)
        assert got.keys() == own.keys()
        for name in own:
            np.testing.assert_array_equal(got[name], own[name])
    assert len(calls) == 1 + len(cands)


def test_spd_solve_equals_lapack():
    rng = np.random.default_rng(3)
    for K in (1, 2, 5):
        r = rng.normal(size=(40, 3, K, K))
        A = r @ np.swapaxes(r, -1, -2) + 0.1 * np.eye(K)
        b = rng.normal(size=(40, 3, K))
        np.testing.assert_allclose(np.asarray(als.spd_solve(jnp.asarray(A), jnp.asarray(b))),
                                   np.linalg.solve(A, b[..., None])[..., 0], rtol=1e-3, atol=1e-4)


def test_nv_weights_balance_the_bins():
    """beta = 0: the plain objective (all ones); beta = 1: every n.v bin's mean weighted y^2 is the same
    (each bin's squared error counts relative to its own targets); weights have mean 1."""
    rng = np.random.default_rng(3)
    n = np.tile([0.0, 0.0, 1.0], (4000, 1))
    nv = rng.uniform(0.0, 1.0, 4000)
    v = np.stack([np.sqrt(1 - nv**2), np.zeros_like(nv), nv], axis=1)
    y = (0.05 + 3.0 * (1.0 - nv) ** 5)[:, None] * np.array([1.0, 0.8, 0.6]) * rng.uniform(0.5, 1.5, (4000, 1))
    np.testing.assert_array_equal(sums.nv_weights(n, v, y, 8, 0.0), np.ones(4000, np.float32))
    w = sums.nv_weights(n, v, y, 8, 1.0).astype(np.float64)
    assert w.shape == (4000,) and abs(w.mean() - 1.0) < 1e-5 and np.all(w > 0)
    k = np.minimum((nv * 8).astype(int), 7)
    per_bin = [np.mean(w[k == b] * np.mean(y[k == b] ** 2, axis=1)) for b in range(8)]
    np.testing.assert_allclose(per_bin, per_bin[0], rtol=1e-5)
    half = sums.nv_weights(n, v, y, 8, 0.5).astype(np.float64)
    per = [half[k == b][0] for b in range(8)]  # one weight per bin
    assert np.all(np.diff(per[:5]) > 0) and per[7] > 10 * per[0]  # the frontal (dim) bins weigh more


@pytest.mark.slow
def test_nv_balance_lowers_the_frontal_error(plastic):
    """On a dielectric the plain objective fits the bright grazing views first; nv_balance = 1 lowers the
    frontal bin's relative error (what split-sum holds on plastics) at a similar total error."""
    target, s = plastic
    nv = np.sum(s.val_a * s.val_b, axis=1)

    def errors(f):
        pred = np.asarray(f.model.evaluate(s.val_a, s.val_b), np.float64)
        front = nv > 0.5
        return (np.linalg.norm(pred[front] - s.val_y[front]) / np.linalg.norm(s.val_y[front]),
                np.linalg.norm(pred - s.val_y) / np.linalg.norm(s.val_y))

    st = Structure("NR", 2, "fitted", True)
    plain = errors(sums.fit_sum(target, st, "dual_paraboloid", S, s, LinearOptions(iterations=20)))
    fit = sums.fit_sum(target, st, "dual_paraboloid", S, s, LinearOptions(iterations=20, nv_balance=1.0))
    bal = errors(fit)
    assert fit.solver["nv_balance"] == 1.0
    assert bal[0] < 0.9 * plain[0]
    assert bal[1] < 1.3 * plain[1]


@pytest.mark.slow
def test_nv_balance_weighs_the_levenberg_marquardt_fit(plastic):
    """The same n.v-bin weights in the Levenberg-Marquardt objective (what ``linear.polish`` minimises):
    from the same start, the weighted fit has the lower frontal error, the plain one the lower total."""
    target, s = plastic
    nv = np.sum(s.val_a * s.val_b, axis=1)
    front = nv > 0.5
    st = Structure("NR", 1, "fitted", True)
    out = {}
    for beta in (0.0, 1.0):
        f = sums.fit_sum(target, st, "dual_paraboloid", S, s,
                         LinearOptions(method="levenberg_marquardt", iterations=12, nv_balance=beta))
        pred = np.asarray(f.model.evaluate(s.val_a, s.val_b), np.float64)
        out[beta] = (np.linalg.norm(pred[front] - s.val_y[front]) / np.linalg.norm(s.val_y[front]),
                     np.linalg.norm(pred - s.val_y) / np.linalg.norm(s.val_y))
        assert f.solver["nv_balance"] == beta and f.solver["objective"] < f.solver["objective_start"]
    assert out[1.0][0] < 0.95 * out[0.0][0], out
    assert out[0.0][1] <= out[1.0][1] * 1.02, out


def test_weights_count_as_repeated_samples():
    """refine's objective: a sample of weight 2 counts as the same sample twice (weights multiply the
    squared data residuals, not the smoothing)."""
    rng = np.random.default_rng(0)
    n, texels = 40, 9
    cols = rng.integers(0, texels, (2, n, 4)).astype(np.int32)
    w = rng.uniform(0, 1, (2, n, 4)).astype(np.float32)
    y = rng.uniform(0, 1, (n, 3)).astype(np.float32)
    X = tuple(jnp.asarray(rng.uniform(0.5, 1.5, (texels, 3)), jnp.float32) for _ in range(2))
    edges = tuple(jnp.asarray(refine.edges_of(np.stack([np.roll(np.arange(texels), 1), -np.ones(texels, int),
                                                        -np.ones(texels, int), -np.ones(texels, int)], 1)))
                  for _ in range(2))
    mu = (jnp.float32(0.3), jnp.float32(0.7))
    scales = tuple(jnp.ones(texels) for _ in range(2))

    def problem(idx, weights):
        lk = tuple(refine.Lookup(jnp.asarray(cols[j][idx]), jnp.asarray(w[j][idx])) for j in range(2))
        return refine.Problem(lk, jnp.asarray(y[idx]), edges, mu, scales, jnp.sqrt(jnp.asarray(weights, jnp.float32)))

    terms = ((0, 1),)
    weights = np.ones(n)
    weights[:10] = 2.0
    weighted = refine.objective(X, problem(np.arange(n), weights), terms)
    repeated = refine.objective(X, problem(np.concatenate([np.arange(n), np.arange(10)]), np.ones(n + 10)), terms)
    np.testing.assert_allclose(float(weighted), float(repeated), rtol=1e-5)
    plain = refine.objective(X, problem(np.arange(n), np.ones(n)), terms)
    assert float(weighted) > float(plain)


def test_a_capped_inner_solve_still_steps():
    """Levenberg-Marquardt whose LSMR stops on its step cap takes the truncated step and goes on
    (solvers.inexact.Truncated): with 2 LSMR steps per system it falls as far as with 100, where optimistix
    alone ends the solve at the first capped system and returns the start."""
    rng = np.random.default_rng(0)
    n, texels = 400, 30
    cols = rng.integers(0, texels, (2, n, 4)).astype(np.int32)
    w = rng.dirichlet(np.ones(4), (2, n)).astype(np.float32)
    true = [rng.uniform(0.5, 1.5, (texels, 3)) for _ in range(2)]
    y = np.einsum("nk,nkc->nc", w[0], true[0][cols[0]]) * np.einsum("nk,nkc->nc", w[1], true[1][cols[1]])
    ring = np.stack([np.roll(np.arange(texels), 1)] + [-np.ones(texels, int)] * 3, 1)
    lk = tuple(refine.Lookup(jnp.asarray(cols[j]), jnp.asarray(w[j])) for j in range(2))
    prob = refine.Problem(lk, jnp.asarray(y, jnp.float32), (jnp.asarray(refine.edges_of(ring)),) * 2,
                          (jnp.float32(1e-4),) * 2, refine.column_scales(lk, (0, 1), (texels, texels)), jnp.ones(n))
    X0 = tuple(jnp.ones((texels, 3), jnp.float32) for _ in range(2))
    terms = ((0, 1),)
    start = float(refine.objective(X0, prob, terms))
    capped, steps, _ = refine.solve(X0, prob, terms, iterations=10, inner=2)
    full, _, _ = refine.solve(X0, prob, terms, iterations=10, inner=100)
    assert steps == 10
    assert float(refine.objective(capped, prob, terms)) < 1e-3 * start
    assert float(refine.objective(capped, prob, terms)) < 2 * float(refine.objective(full, prob, terms))


def _three_texture_problem(seed: int = 1):
    """A small sum of products (terms (0,), (1, 2)) over textures of 30, 12 and 7 unknowns, with smoothing and
    sample weights: data of a nearby true model plus noise, so that Levenberg-Marquardt takes several steps."""
    rng = np.random.default_rng(seed)
    n, sizes, terms = 500, (30, 12, 7), ((0,), (1, 2))
    which = [k for t in terms for k in t]
    cols = [rng.integers(0, sizes[k], (n, 4)).astype(np.int32) for k in which]
    w = [rng.dirichlet(np.ones(4), n).astype(np.float32) for _ in which]
    true = [rng.uniform(0.5, 1.5, (m, 3)).astype(np.float32) for m in sizes]
    y = sum(np.prod([np.einsum("nk,nkc->nc", w[j], true[which[j]][cols[j]]) for j in js], axis=0)
            for js in ([0], [1, 2])) + rng.normal(0, 0.01, (n, 3))
    lk = tuple(refine.Lookup(jnp.asarray(c), jnp.asarray(x)) for c, x in zip(cols, w))
    edges = tuple(jnp.asarray(refine.edges_of(np.stack([np.roll(np.arange(m), 1)] + [-np.ones(m, int)] * 3, 1)))
                  for m in sizes)
    prob = refine.Problem(lk, jnp.asarray(y, jnp.float32), edges, tuple(jnp.float32(1e-3) for _ in sizes),
                          refine.column_scales(lk, tuple(which), sizes),
                          jnp.asarray(np.sqrt(rng.uniform(0.5, 2.0, n)), jnp.float32))
    X0 = tuple(jnp.asarray(t * rng.uniform(0.6, 1.4, t.shape), jnp.float32) for t in true)
    return X0, prob, terms


def test_the_stacked_levenberg_marquardt_is_optimistixs():
    """refine's Levenberg-Marquardt (``_lm`` on the stacked unknowns) takes optimistix's steps: the same point
    as ``optx.LevenbergMarquardt`` with the truncated LSMR on the per-texture residuals after 5 steps (each step
    starts from the last, so a wrong one shows in the point), the same step count, and F before and after as
    :func:`refine.objective` reads them; the stacked residuals' sum of squares is F."""
    steps = 5
    import lineax as lx
    import optimistix as optx
    from homofac.fit.solvers.inexact import Truncated

    X0, prob, terms = _three_texture_problem()
    Z0, st = refine.stack(X0, prob, terms)
    F0 = float(refine.objective(X0, prob, terms))
    assert sum(float(jnp.sum(r * r)) for r in refine.stacked_residuals(Z0, st, terms)) == pytest.approx(F0, rel=1e-5)
    solver = optx.LevenbergMarquardt(rtol=1e-7, atol=1e-7, linear_solver=Truncated(lx.LSMR(rtol=1e-4, atol=1e-4,
                                                                                          max_steps=100)))
    sol = optx.least_squares(lambda z, p: refine.residuals(z, p, terms), solver,
                             tuple(x / s[:, None] for x, s in zip(X0, prob.scales)), args=prob, max_steps=steps,
                             throw=False)
    want = [np.asarray(z * s[:, None]) for z, s in zip(sol.value, prob.scales)]
    X, taken, _, before, after = refine.solve_objectives(X0, prob, terms, iterations=steps)
    assert taken == int(sol.stats["num_steps"])
    assert after < 0.9 * before
    assert before == pytest.approx(F0, rel=1e-5)
    assert after == pytest.approx(float(refine.objective(X, prob, terms)), rel=1e-5)
    for got, ref, x0 in zip(X, want, X0):
        assert got.shape == x0.shape
        np.testing.assert_allclose(np.asarray(got), ref, rtol=0, atol=1e-4 * float(np.max(np.abs(ref))))


def test_nv_balance_needs_a_lighting_target():
    """BRDF pairs have no n.v: refused in one line before sampling, and by fit_sum."""
    target = hf.target.brdf_target(hf.brdf.phong(kd=0.2, ks=0.5, exponent=10.0))
    with pytest.raises(HomofacError, match="nv_balance weighs the n.v bins of lighting pairs") as err:
        hf.fit.factorize(target, "PQP", texture_size=S, terms=2, advanced={"linear": {"nv_balance": 1.0}},
                         sampling={"kind": "random", "count": 200, "validation": 10})
    assert "\n" not in str(err.value)


def test_polish_needs_grid_samples(exact_sum):
    """linear.polish follows an ALS fit: refused (one line, before sampling) on texel sampling, and by
    fit_sum for a fit that is not ALS."""
    _, target, s = exact_sum
    with pytest.raises(HomofacError, match="polish follows an als fit on grid samples") as err:
        hf.fit.factorize(target, "NR", texture_size=S, terms=1, advanced={"linear": {"polish": 2}},
                         sampling={"kind": "texels", "size": 6, "validation": 0, "cache": False})
    assert "\n" not in str(err.value)
    with pytest.raises(HomofacError, match="polish follows an als fit"):
        sums.fit_sum(target, Structure("NR", 1, None, True), "dual_paraboloid", S, s,
                     LinearOptions(method="levenberg_marquardt", polish=2, iterations=2))


def test_a_refit_takes_the_linear_settings_the_fit_recorded():
    """recorded_linear: nv_balance and the polish (steps, size) from the solver record, the rest from
    the options; a record without a polish means none was done."""
    lin = LinearOptions(iterations=4)
    out = recorded_linear(lin, {"nv_balance": 1.0, "polish": {"steps": 8, "iterations": 5, "size": 12}})
    assert (out.nv_balance, out.polish, out.polish_size, out.iterations) == (1.0, 8, 12, 4)
    assert recorded_linear(LinearOptions(polish=3), {"nv_balance": 0.0}).polish == 0
    assert recorded_linear(lin, {"polish": {"iterations": 6, "size": 16}}).polish == 6  # records before "steps"
    assert recorded_linear(lin, None) == lin.resolved()  # unset values (the preset's) run as 0


@pytest.mark.slow
def test_polish_lowers_the_off_grid_error():
    """A near-mirror under small lamps: the grid ALS fit sees the model only at texel centres; a few
    Levenberg-Marquardt steps on off-grid texel pairs lower the validation error (uniform pairs), the
    record says what the polish did, and a refit polishes again (its metrics equal its full run's)."""
    env = hf.light.load_environment("interior", resolution=16)
    mirror = lambda f0: hf.brdf.ggx(kd=0.0, ks=1.0, roughness=0.15, f0=f0)  # noqa: E731
    target = hf.light.lighting_target(mirror((0.95, 0.93, 0.88)), env)
    kw = dict(texture_size=16, terms=1, diffuse="fitted", nv_factor=True,
              sampling={"kind": "grid", "count": 60000, "validation": 4000, "cache": False})
    plain = hf.fit.factorize(target, "NR", **kw)
    pol = hf.fit.factorize(target, "NR", advanced={"linear": {"polish": 4, "polish_size": 12}}, **kw)
    val = lambda r: r.metrics["validation"]["float"]["nrmse"]  # noqa: E731
    # 0.5105 -> 0.5072 on the validation pairs (500 normals x 8 views); on 63 normals x 64 views it read
    # more than 1 %: the gain of 4 steps is small here, and 8 steps raised it (0.514)
    assert val(pol) < val(plain)
    rec = pol.solver["polish"]
    assert rec["iterations"] >= 1 and rec["samples"] > 0 and rec["objective"] < rec["objective_start"]
    assert "polish" not in plain.solver and pol.timings["polish_sample_s"] > 0
    copper = mirror((0.9, 0.6, 0.5))
    refit = hf.fit.refit(pol, brdf=copper)
    full = hf.fit.factorize(hf.light.lighting_target(copper, env), "NR",
                            advanced={"linear": {"polish": 4, "polish_size": 12}}, **kw)
    assert "polish" in refit.solver
    assert abs(val(refit) - val(full)) <= 0.01 * val(full)
