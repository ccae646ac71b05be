"""The highlight term of the brightest light (issue 13): the scalar projection ``nh_dom``, the direction
of the brightest light, the ALS block of a ``line`` factor read at it, and ``highlight_terms`` in a sum
and among the ``max_lookups`` candidates."""

from __future__ import annotations

import equinox as eqx
import numpy as np
import pytest

import homofac as hf
from homofac.fit import plan
from helpers import visible_pairs
from homofac.errors import HomofacError
from homofac.fit import als, pipeline, structures, sums
from homofac.fit.structures import Structure
from homofac.param import projections as pj

SUN = np.array([0.5, -0.3, 0.81])
SUN /= np.linalg.norm(SUN)
GRID = {"kind": "grid", "size": 8, "mapper": "dual_paraboloid", "count": 20000, "validation": 3000, "cache": False}


def _pairs(count: int, seed: int = 3):
    return visible_pairs(count, seed)


def test_nh_dom_is_one_on_the_mirror_configuration_and_falls_with_the_half_angle():
    n, v = _pairs(3000)
    ctx = {"dominant": SUN}
    x = np.asarray(pj.apply("nh_dom", n, v, ctx))
    assert np.all((x >= 0) & (x <= 1))
    # v the mirror image of the light about n: h' = n, the peak of the highlight
    mirror = 2 * np.sum(n * SUN, 1, keepdims=True) * n - SUN
    up = np.sum(n * SUN, 1) > 0.05
    np.testing.assert_allclose(np.asarray(pj.apply("nh_dom", n[up], mirror[up], ctx)), 1.0, atol=2e-3)
    # monotone in n.h' with the pinned warp 1 - (1 - c)^(1/4) where the light is above the horizon of n,
    # 0 where it has set (the far tail of the line: no highlight)
    h = SUN + v
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    c = np.clip(np.sum(n * h, 1), 0, 1)
    lit = np.sum(n * SUN, 1) > 0
    assert 0.2 < lit.mean() < 0.8
    np.testing.assert_allclose(x[lit], (1 - (1 - c) ** 0.25)[lit], atol=1e-5)
    np.testing.assert_array_equal(x[~lit], 0.0)
    assert pj.get("nh_dom").scalar and pj.get("nh_dom").context == ("dominant",)


def test_brightest_direction_finds_the_sun_where_eq_66_is_pulled_toward_the_sky():
    env = hf.light.sun_sky(SUN, sun_radiance=2.0e3, sun_angle_deg=3.0, sky=(0.4, 0.5, 0.8), sky_gradient=0.8,
                           resolution=16)
    peak = hf.light.brightest_direction(env)
    mean = np.asarray(hf.light.dominant_direction(env))
    assert np.degrees(np.arccos(np.clip(peak @ SUN, -1, 1))) < 3.0
    assert np.degrees(np.arccos(np.clip(mean @ SUN, -1, 1))) > 5.0  # the sky's pull on eq. 66
    dark = eqx.tree_at(lambda e: e.radiance, env, env.radiance * 0.0)  # the loaders refuse it; the function too
    with pytest.raises(HomofacError, match="no light"):
        hf.light.brightest_direction(dark)


def test_als_d_block_recovers_a_line_factor_read_at_a_second_scalar():
    """y = d(x) w(n.v) exactly (two lines, no p or q): the ALS with the D block reaches it."""
    rng = np.random.default_rng(0)
    N, Sw = 4000, 16
    nv, x = rng.uniform(0, 1, N), rng.uniform(0, 1, N)
    vi, vw = (np.asarray(u) for u in als.line_footprint(nv.astype(np.float32), Sw))
    hi, hw = (np.asarray(u) for u in als.line_footprint(x.astype(np.float32), Sw))
    w_true = 0.5 + np.linspace(0, 1, Sw)[:, None] * np.ones(3)
    d_true = np.exp(-((np.linspace(0, 1, Sw) - 0.8) / 0.2) ** 2)[:, None] * np.array([1.0, 0.7, 0.4])
    y = np.einsum("nk,nkc->nc", vw, w_true[vi]) * np.einsum("nk,nkc->nc", hw, d_true[hi])
    n1 = 4
    data = als.GridData(np.zeros(N, np.int32), np.zeros(N, np.int32), vi.astype(np.int32), vw.astype(np.float32),
                        y.astype(np.float32), np.zeros((n1, 4), np.int32), np.zeros((n1, 4), np.float32),
                        np.ones(N, np.float32), hi[:, None].astype(np.int32), hw[:, None].astype(np.float32))
    flags = als.Flags((False,), (False,), (True,), (True,))
    P, Q, W, D, hist = als.run(np.ones((1, n1, 3), np.float32), np.ones((1, n1, 3), np.float32),
                               np.ones((1, Sw, 3), np.float32), data, np.float32(0.0), flags=flags, sweeps=20,
                               D=np.zeros((1, Sw, 3), np.float32))
    pred = als.predict(P, Q, W, data, flags, D)
    assert float(np.max(np.abs(np.asarray(pred) - y))) < 1e-3 * float(np.max(y))
    assert np.all(np.diff(np.asarray(hist)) <= 1e-6 * float(hist[0]))  # ALS never increases the objective


def test_als_extra_line_blocks_recover_a_product_of_four_lines():
    """y = d(x) f(z) c(u) w(n.v) exactly (a highlight term with both extra lines, the Fresnel and the
    cosine line): the ALS with the D block and a tuple of two extra line blocks reaches it, monotonely."""
    rng = np.random.default_rng(1)
    N, Sw = 6000, 16
    s = np.linspace(0, 1, Sw)[:, None]
    lines = [0.5 + s * np.ones(3), np.exp(-((s - 0.8) / 0.2) ** 2) * np.array([1.0, 0.7, 0.4]),
             0.2 + s ** 2 * np.array([1.0, 1.0, 0.5]), np.sqrt(s) * np.ones(3)]  # w, d, f, c
    feet = [[np.asarray(u) for u in als.line_footprint(rng.uniform(0, 1, N).astype(np.float32), Sw)] for _ in lines]
    y = np.prod([np.einsum("nk,nkc->nc", w, t[i]) for (i, w), t in zip(feet, lines)], axis=0)
    n1 = 4

    def col(u, dtype):  # one term: (N, 1, 2)
        return u[:, None].astype(dtype)

    data = als.GridData(np.zeros(N, np.int32), np.zeros(N, np.int32), feet[0][0].astype(np.int32),
                        feet[0][1].astype(np.float32), y.astype(np.float32), np.zeros((n1, 4), np.int32),
                        np.zeros((n1, 4), np.float32), np.ones(N, np.float32), col(feet[1][0], np.int32),
                        col(feet[1][1], np.float32), (col(feet[2][0], np.int32), col(feet[3][0], np.int32)),
                        (col(feet[2][1], np.float32), col(feet[3][1], np.float32)))
    flags = als.Flags((False,), (False,), (True,), (True,), ((True,), (True,)))
    ones = np.ones((1, Sw, 3), np.float32)
    P, Q, W, D, C, hist = als.run(np.ones((1, n1, 3), np.float32), np.ones((1, n1, 3), np.float32), ones, data,
                                  np.float32(0.0), flags=flags, sweeps=60, D=ones, C=(ones, ones))
    assert len(C) == 2
    pred = np.asarray(als.predict(P, Q, W, data, flags, D, C))
    assert float(np.max(np.abs(pred - y))) < 2e-3 * float(np.max(y))
    assert np.all(np.diff(np.asarray(hist)) <= 1e-6 * float(hist[0]))  # ALS never increases the objective


def test_highlight_terms_in_the_skeleton_label_record_and_lookup_count():
    s = Structure("RO", 1, "fitted", False, highlights={"terms": 1})
    textures, terms = structures.skeleton(s, "lighting", "lighting", "dual_paraboloid", 8)
    assert terms[-1].factors == (("nh_dom", "d1"), ("nv", "w1"))
    assert [t.mapper for t in textures if t.name in ("d1", "w1")] == ["line", "line"]
    assert structures.lookups(s, "lighting") == structures.lookups(s.with_highlights(terms=0), "lighting") + 2
    assert s.label() == "E'+RO x1+HW x1"
    assert Structure.of(s.record()) == s
    with pytest.raises(HomofacError, match="lighting"):
        structures.skeleton(Structure("PQP", 1, highlights={"terms": 1}), "brdf", "brdf", "parabolic", 8)


def test_candidates_try_the_highlight_term_only_when_asked():
    with_h = structures.candidates("lighting", 4)
    without = structures.candidates("lighting", 4, highlight=False)
    assert any(c.highlights.terms for c in with_h) and not any(c.highlights.terms for c in without)
    assert all(structures.lookups(c, "lighting") <= 4 for c in with_h)
    assert not any(c.highlights.terms for c in structures.candidates("brdf", 8))


def test_a_given_highlight_count_constrains_the_chooser():
    cands = structures.candidates("lighting", 8)
    counts = {c.highlights.terms for c in cands}
    assert counts == {0, 1, 2}
    assert plan.constrained(cands, pipeline.options(max_lookups=8)) == cands  # not given: all of them
    for j in counts:
        kept = plan.constrained(cands, pipeline.options(max_lookups=8, advanced={"highlights": {"terms": j}}))
        assert kept and all(c.highlights.terms == j for c in kept)
        assert len(kept) == sum(c.highlights.terms == j for c in cands)
    both = plan.constrained(cands, pipeline.options(max_lookups=8, advanced={"highlights": {"terms": 1}},
                                                    diffuse="fitted"))
    assert both and all(c.highlights.terms == 1 and c.diffuse == "fitted" for c in both)


def test_a_glossy_metal_under_a_sun_fits_better_with_the_highlight_term(tmp_path):
    """The property the term is for: the sun's highlight of a near-mirror, which a map of r smears."""
    env = hf.light.sun_sky(SUN, sun_radiance=3.0e3, sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6), resolution=8)
    brdf = hf.brdf.ggx(kd=0.0, ks=1.0, roughness=0.15, f0=(0.95, 0.93, 0.88))
    target = hf.light.lighting_target(brdf, env, parametrization="RO")
    samples = hf.fit.draw_samples(target, "RO", GRID)
    plain = hf.fit.factorize(target, "RO", texture_size=8, samples=samples, diffuse="fitted", nv_factor=True,
                             advanced={"reflection": True})
    lit = hf.fit.factorize(target, "RO", texture_size=8, samples=samples, diffuse="fitted",
                           advanced={"highlights": {"terms": 1}})
    assert lit.model.lookups == plain.model.lookups == 4
    e_plain = plain.metrics["validation"]["float"]["nrmse"]
    e_lit = lit.metrics["validation"]["float"]["nrmse"]
    assert e_lit < 0.7 * e_plain, (e_lit, e_plain)
    # the model records the light it was fitted for, and reproduces its fit after a save / load
    assert np.degrees(np.arccos(np.clip(np.asarray(lit.model.context["dominant"]) @ SUN, -1, 1))) < 5.0
    n, v = _pairs(500)
    lit.save(tmp_path / "out")
    back = hf.output.load(tmp_path / "out")
    assert set(back.model.context) == {"dominant", "shift"}
    np.testing.assert_allclose(np.asarray(back.model.evaluate(n, v)), np.asarray(lit.model.evaluate(n, v)),
                               rtol=1e-5, atol=1e-6)


def test_highlight_terms_refuse_a_brdf_target():
    target = hf.fit.brdf_target(hf.brdf.ggx())
    with pytest.raises(HomofacError, match="lighting"):
        hf.fit.factorize(target, "PQP", texture_size=8, advanced={"highlights": {"terms": 1}})


def test_brightest_directions_find_two_lamps_brightest_first_and_the_terms_read_one_each():
    a, b = np.array([0.6, 0.0, 0.8]), np.array([-0.5, 0.5, 0.707])
    b /= np.linalg.norm(b)
    env = hf.light.painted_lights([(a, 6.0, (50.0, 50.0, 50.0)), (b, 6.0, (20.0, 20.0, 20.0))], 16, background=0.1)
    found = hf.light.brightest_directions(env, 2)
    assert np.degrees(np.arccos(np.clip(found[0] @ a, -1, 1))) < 3.0
    assert np.degrees(np.arccos(np.clip(found[1] @ b, -1, 1))) < 3.0
    _, terms = structures.skeleton(Structure("RO", 1, "fitted", True, highlights={"terms": 2}), "lighting", "lighting",
                                   "dual_paraboloid", 8)
    assert [t.factors[0][0] for t in terms[-2:]] == ["nh_dom", "nh_dom1"]
    target = hf.light.lighting_target(hf.brdf.ggx(kd=0.0, roughness=0.15), env)
    ctx = sums.with_highlight_context(target, Structure("RO", 1, highlights={"terms": 2})).context
    np.testing.assert_allclose(np.stack([ctx["dominant"], ctx["dominant1"]]), found)
    with pytest.raises(HomofacError, match="highlights.terms"):
        hf.fit.factorize(target, "RO", texture_size=8, advanced={"highlights": {"terms": 4}})


def test_vh_dom_is_the_fresnel_argument_of_the_light_and_n_v_at_the_peak():
    n, v = _pairs(3000)
    ctx = {"dominant": SUN}
    h = SUN + v
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    np.testing.assert_allclose(np.asarray(pj.apply("vh_dom", n, v, ctx)), np.clip(np.sum(v * h, 1), 0, 1), atol=1e-6)
    # a function of the view alone: the same for every normal
    np.testing.assert_allclose(np.asarray(pj.apply("vh_dom", n[::-1], v, ctx)), np.asarray(pj.apply("vh_dom", n, v, ctx)))
    # at the peak of the highlight (v the mirror image of the light about n) v.h' = n.v
    up = np.sum(n * SUN, 1) > 0.05
    mirror = 2 * np.sum(n * SUN, 1, keepdims=True) * n - SUN
    np.testing.assert_allclose(np.asarray(pj.apply("vh_dom", n[up], mirror[up], ctx)), np.sum(n[up] * mirror[up], 1),
                               atol=1e-5)
    assert pj.get("vh_dom").scalar and pj.get("vh_dom2").context == ("dominant2",)


def test_the_fresnel_line_in_the_skeleton_label_record_candidates_and_refusals():
    s = Structure("RO", 1, "fitted", True, highlights={"terms": 1, "fresnel": True})
    textures, terms = structures.skeleton(s, "lighting", "lighting", "dual_paraboloid", 8)
    assert terms[-1].factors == (("nh_dom", "d1"), ("vh_dom", "f1"), ("nv", "w1"))
    assert [t.mapper for t in textures if t.name in ("d1", "f1", "w1")] == ["line", "line", "line"]
    assert structures.lookups(s, "lighting") == structures.lookups(s.with_highlights(fresnel=False), "lighting") + 1
    assert s.label() == "E'+ROW x1+HFW x1"
    assert Structure.of(s.record()) == s
    with pytest.raises(HomofacError, match="highlights: fresnel: the v.h' line"):
        Structure("RO", 1, "fitted", True, highlights={"fresnel": True})
    # the chooser tries it where a budget has room (not at 4 lookups), and a given value constrains it
    assert not any(c.highlights.fresnel for c in structures.candidates("lighting", 4))
    cands = structures.candidates("lighting", 8)
    assert any(c.highlights.fresnel for c in cands)
    assert any(c.highlights.terms and not c.highlights.fresnel for c in cands)
    off = plan.constrained(cands, pipeline.options(max_lookups=8, advanced={"highlights": {"fresnel": False}}))
    on = plan.constrained(cands, pipeline.options(max_lookups=8, advanced={"highlights": {"fresnel": True}}))
    assert not any(c.highlights.fresnel for c in off) and any(c.highlights.terms for c in off)
    assert all(c.highlights.fresnel for c in on if c.highlights.terms) and any(not c.highlights.terms for c in on)


@pytest.fixture(scope="module")
def dielectric():
    """The dielectric under a sun of the slow Fresnel- and cosine-line tests: its grid samples drawn once, and
    ``dielectric(**highlights)`` fits one highlight term with those keys once (the Fresnel-line fit is both
    tests')."""
    env = hf.light.sun_sky(SUN, sun_radiance=3.0e3, sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6), resolution=8)
    brdf = hf.brdf.ggx(kd=0.3, ks=1.0, roughness=0.4, f0=0.04)
    target = hf.light.lighting_target(brdf, env, parametrization="RO")
    samples = hf.fit.draw_samples(target, "RO", GRID)
    kw = dict(texture_size=8, samples=samples, diffuse="fitted", nv_factor=True)
    fits = {}

    def fit(**highlights):
        key = tuple(sorted(highlights.items()))
        if key not in fits:
            fits[key] = hf.fit.factorize(target, "RO", advanced={"highlights": {"terms": 1, **highlights}}, **kw)
        return fits[key]
    return fit


@pytest.mark.slow  # a pair of fits for one line; the fast suite keeps the glossy metal's highlight-term pair
def test_a_dielectric_under_a_sun_fits_better_with_the_fresnel_line(tmp_path, dielectric):
    """The property the line is for: a dielectric's highlight rises toward grazing v.h' (F0 0.04 -> 1),
    which d(nh_dom) w(n.v) alone cannot follow; the line is fitted by the same ALS and survives a save."""
    plain = dielectric()
    fres = dielectric(fresnel=True)
    assert fres.model.lookups == plain.model.lookups + 1
    assert fres.solver["method"] == "als" and fres.solver["structure"]["highlights"]["fresnel"]
    e_plain = plain.metrics["validation"]["float"]["nrmse"]
    e_fres = fres.metrics["validation"]["float"]["nrmse"]
    assert e_fres < 0.9 * e_plain, (e_fres, e_plain)  # 0.092 against 0.104 on 375 normals x 8 views
    n, v = _pairs(500)
    fres.save(tmp_path / "out")
    back = hf.output.load(tmp_path / "out")
    np.testing.assert_allclose(np.asarray(back.model.evaluate(n, v)), np.asarray(fres.model.evaluate(n, v)),
                               rtol=1e-5, atol=1e-6)


def test_ni_dom_is_the_cosine_of_the_light_a_function_of_the_normal_zero_below_its_horizon():
    n, v = _pairs(3000)
    ctx = {"dominant": SUN, "dominant1": -SUN}
    c = np.asarray(pj.apply("ni_dom", n, v, ctx))
    np.testing.assert_allclose(c, np.clip(n @ SUN, 0, 1), atol=1e-6)
    np.testing.assert_allclose(np.asarray(pj.apply("ni_dom", n, v[::-1], ctx)), c)  # v does not matter
    assert np.all(c[n @ SUN <= 0] == 0) and np.all(c[n @ SUN > 1e-3] > 0)
    np.testing.assert_allclose(np.asarray(pj.apply("ni_dom1", n, v, ctx)), np.clip(-(n @ SUN), 0, 1), atol=1e-6)
    assert pj.get("ni_dom").scalar and pj.get("ni_dom2").context == ("dominant2",)


def test_the_cosine_line_in_the_skeleton_label_record_candidates_and_refusals():
    s = Structure("RO", 1, "fitted", True, highlights={"terms": 1, "fresnel": True, "cosine": True})
    textures, terms = structures.skeleton(s, "lighting", "lighting", "dual_paraboloid", 8)
    assert terms[-1].factors == (("nh_dom", "d1"), ("vh_dom", "f1"), ("ni_dom", "c1"), ("nv", "w1"))
    assert [t.mapper for t in textures if t.name in ("d1", "f1", "c1", "w1")] == ["line"] * 4
    assert structures.lookups(s, "lighting") == structures.lookups(s.with_highlights(cosine=False), "lighting") + 1
    assert s.label() == "E'+ROW x1+HFCW x1"
    assert Structure.of(s.record()) == s
    alone = Structure("RO", 1, "fitted", True, highlights={"terms": 1, "cosine": True})
    assert structures.skeleton(alone, "lighting", "lighting", "dual_paraboloid", 8)[1][-1].factors == (
        ("nh_dom", "d1"), ("ni_dom", "c1"), ("nv", "w1"))
    with pytest.raises(HomofacError, match="highlights: cosine: the n.i line"):
        Structure("RO", 1, "fitted", True, highlights={"cosine": True})
    # the chooser tries it with the Fresnel line where a budget has room, and a given value constrains it
    assert not any(c.highlights.cosine for c in structures.candidates("lighting", 4))
    cands = structures.candidates("lighting", 8)
    assert all(c.highlights.fresnel for c in cands if c.highlights.cosine)
    assert any(c.highlights.cosine for c in cands)
    assert any(c.highlights.fresnel and not c.highlights.cosine for c in cands)
    off = plan.constrained(cands, pipeline.options(max_lookups=8, advanced={"highlights": {"cosine": False}}))
    on = plan.constrained(cands, pipeline.options(max_lookups=8, advanced={"highlights": {"cosine": True}}))
    assert not any(c.highlights.cosine for c in off) and any(c.highlights.terms for c in off)
    assert all(c.highlights.cosine for c in on if c.highlights.terms) and any(not c.highlights.terms for c in on)
    with pytest.raises(HomofacError, match="highlights: cosine: the n.i line"):
        hf.fit.factorize(hf.light.lighting_target(hf.brdf.ggx(roughness=0.4), hf.light.sun_sky(SUN, resolution=8),
                                                  parametrization="RO"),
                         "RO", texture_size=8, diffuse="fitted", advanced={"highlights": {"cosine": True}})


@pytest.mark.slow  # a pair of fits for one line; the fast suite keeps the glossy metal's highlight-term pair
def test_a_dielectric_under_a_sun_fits_better_with_the_cosine_line(tmp_path, dielectric):
    """The property the line is for: the highlight of a light fades with its cosine n.i (the shadowing
    G1(n.i), down to 0 at its horizon), which d(nh_dom) [f(v.h')] w(n.v) cannot follow where n.i and n.v
    differ; fitted by the same ALS (two extra line blocks with the Fresnel line) and kept by a save."""
    fres = dielectric(fresnel=True)
    both = dielectric(fresnel=True, cosine=True)
    assert both.model.lookups == fres.model.lookups + 1
    assert both.solver["method"] == "als" and both.solver["structure"]["highlights"]["cosine"]
    e_fres = fres.metrics["validation"]["float"]["nrmse"]
    e_both = both.metrics["validation"]["float"]["nrmse"]
    assert e_both < 0.8 * e_fres, (e_both, e_fres)
    c = np.asarray(both.model.texture("c1").data)
    assert np.all(np.isfinite(c)) and np.ptp(c) > 0  # a fitted line, not the constant start
    n, v = _pairs(500)
    both.save(tmp_path / "out")
    back = hf.output.load(tmp_path / "out")
    np.testing.assert_allclose(np.asarray(back.model.evaluate(n, v)), np.asarray(both.model.evaluate(n, v)),
                               rtol=1e-5, atol=1e-6)
