"""Highlight terms of lights with a disc (``highlights.disc``, issue 13): the projection ``nhs_dom`` (the
highlight coordinate at the point of the light's disc closest to r), the disc's radius measured from the
environment, the structure and the chooser's disc vote."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import homofac as hf
from helpers import visible_pairs
from homofac.errors import HomofacError
from homofac.fit import pipeline, structures
from homofac.fit.options import FitOptions
from homofac.fit.structures import Structure
from homofac.param import projections as pj

SUN = np.array([0.5, -0.3, 0.81])
SUN /= np.linalg.norm(SUN)
GRID = {"kind": "grid", "size": 8, "mapper": "dual_paraboloid", "count": 8000, "validation": 1500, "cache": False}
DISC = Structure("RO", 1, "fitted", True, highlights={"terms": 1, "disc": True})


def _grazing_pair(nv: float, off_degrees: float):
    """n = +z, v at n.v = ``nv`` and the light ``off_degrees`` from r = reflect(v) out of the plane of
    incidence (about r's own in-plane perpendicular)."""
    s = np.sqrt(1 - nv * nv)
    n, v = np.array([0.0, 0.0, 1.0]), np.array([-s, 0.0, nv])
    r = 2 * nv * n - v
    t = np.radians(off_degrees)
    return n, v, np.cos(t) * r + np.sin(t) * np.array([0.0, 1.0, 0.0])


def test_nhs_dom_is_nh_dom_at_radius_zero_one_on_the_disc_and_never_below_the_point_light():
    n, v = visible_pairs(4000)
    ctx = pj.example_context()
    point = np.asarray(pj.apply("nh_dom", n, v, ctx))
    np.testing.assert_allclose(np.asarray(pj.apply("nhs_dom", n, v, {**ctx, "radius": 0.0})), point, atol=1e-6)
    disc = np.asarray(pj.apply("nhs_dom", n, v, ctx))
    assert np.all(disc >= point - 1e-6) and np.any(disc > point + 1e-3)
    # views whose reflection falls on the disc read the peak
    i = ctx["dominant"]
    jitter = np.random.default_rng(1).normal(size=(4000, 3)) * 0.4 * ctx["radius"]
    r = i + jitter - (jitter @ i)[:, None] * i  # within 0.4 R (x a few) of i, tangentially
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    on = (np.sum(n * r, 1) > 0.05) & (r @ i > np.sqrt(1 - 0.9 * ctx["radius"] ** 2))
    v_on = 2 * np.sum(n * r, 1, keepdims=True) * n - r
    assert on.sum() > 1000
    np.testing.assert_allclose(np.asarray(pj.apply("nhs_dom", n[on], v_on[on], ctx)), 1.0, atol=1e-3)
    for j, (name, key, radius) in enumerate(pj.HIGHLIGHT_DISCS):
        assert pj.get(name).scalar and pj.get(name).context == (key, radius)
        assert pj.HIGHLIGHTS[j][1] == key


def test_nhs_dom_reads_the_peak_where_a_grazing_point_light_half_vector_swings_away():
    """At n.v = 0.01 a light 0.8 degrees off r puts the point light's n.h' at 0.88 (its coordinate near
    0.4, the line's tail); a disc of 1 degree covers r there, and its coordinate is the peak."""
    n, v, i = _grazing_pair(0.01, 0.8)
    ctx = {"dominant": i, "radius": float(np.sin(np.radians(1.0)))}
    point = float(pj.apply("nh_dom", n[None], v[None], ctx)[0])
    disc = float(pj.apply("nhs_dom", n[None], v[None], ctx)[0])
    assert point < 0.6 and disc > 1 - 1e-4, (point, disc)
    # out of the disc the coordinate falls again, continuously
    far = [float(pj.apply("nhs_dom", n[None], v[None], {"dominant": _grazing_pair(0.01, d)[2],
                                                          "radius": ctx["radius"]})[0]) for d in (1.2, 2.0, 4.0)]
    assert disc >= far[0] >= far[1] >= far[2] and far[2] < point


def test_nhs_dom_has_finite_gradients_also_where_r_is_the_light():
    n, v = visible_pairs(200, seed=7)
    r = 2 * np.sum(n * v, 1, keepdims=True) * n - v
    ctx = {"dominant": r[0], "radius": 0.05}  # pair 0 reflects exactly to the light's centre (c = 0)
    f = lambda vv: jnp.sum(pj.apply("nhs_dom", jnp.asarray(n, jnp.float32), vv, ctx))  # noqa: E731
    g = jax.grad(f)(jnp.asarray(v, jnp.float32))
    assert bool(jnp.all(jnp.isfinite(g)))


def test_light_radii_measure_the_sun_disc_and_read_zero_where_a_cap_holds_no_power():
    radii = []
    for diameter in (3.0, 8.0):
        env = hf.light.sun_sky(SUN, sun_radiance=3.0e3, sun_angle_deg=diameter, sky=(0.0, 0.0, 0.0), resolution=64)
        found = hf.light.brightest_directions(env, 1)
        r = hf.light.light_radii(env, np.concatenate([found, -found]))
        assert r.dtype == np.float32 and r.shape == (2,) and r[1] == 0.0
        radii.append(np.degrees(np.arcsin(float(r[0]))))
    # within about a texel (1.2 degrees at resolution 64) of the discs' radii, 1.5 and 4 degrees
    assert abs(radii[0] - 1.5) < 1.2 and abs(radii[1] - 4.0) < 1.2, radii


def test_the_disc_in_the_skeleton_label_record_options_and_refusals():
    _, terms = structures.skeleton(DISC, "lighting", "lighting", "dual_paraboloid", 8)
    assert terms[-1].factors == (("nhs_dom", "d1"), ("nv", "w1"))
    two = DISC.with_highlights(terms=2, fresnel=True, table=True)
    _, terms = structures.skeleton(two, "lighting", "lighting", "dual_paraboloid", 8)
    assert [t.factors[0][0] for t in terms[-2:]] == ["nhs_dom", "nhs_dom1"]
    assert structures.lookups(two, "lighting") == structures.lookups(two.with_highlights(disc=False), "lighting")
    assert "+HS" in DISC.label() and "+HS" not in DISC.with_highlights(disc=False).label()
    assert "+HSFT x2" in two.label()
    assert DISC.record()["highlights"]["disc"] is True and Structure.of(DISC.record()) == DISC
    flat = {"parametrization": "RO", "terms": 1, "diffuse": "fitted", "nv_factor": True, "highlight_terms": 1}
    assert Structure.of({**flat, "highlight_disc": None}) == DISC.with_highlights(disc=False)  # older records
    assert Structure.of({**flat, "highlight_disc": True}) == DISC
    assert structures.tabled(structures.lined(two)) == two  # the table's round trip keeps the disc
    with pytest.raises(HomofacError, match="highlights: disc: the disc's coordinate"):
        Structure("RO", 1, "fitted", True, highlights={"disc": True})
    assert FitOptions(advanced={"highlights": {"disc": True}}).is_sum
    with pytest.raises(HomofacError, match="highlights.disc"):
        pipeline.options(advanced={"highlights": {"disc": "maybe"}})


def test_a_fit_with_the_disc_reads_the_measured_radius_and_survives_a_save(tmp_path):
    env = hf.light.sun_sky(SUN, sun_radiance=3.0e3, sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6), resolution=16)
    brdf = hf.brdf.ggx(kd=0.0, ks=1.0, roughness=0.15, f0=(0.95, 0.93, 0.88))
    target = hf.light.lighting_target(brdf, env, parametrization="RO")
    res = hf.fit.factorize(target, "RO", texture_size=8, sampling=GRID, diffuse="fitted", nv_factor=True,
                           advanced={"highlights": {"terms": 1, "disc": True}})
    assert res.solver["structure"] == DISC.record()
    ctx = res.model.context
    assert set(ctx) == {"dominant", "radius", "shift"}
    assert ctx["radius"] == pytest.approx(float(hf.light.light_radii(env, np.asarray(ctx["dominant"])[None])[0]))
    assert 0 < ctx["radius"] < 0.5
    res.save(tmp_path / "out")
    back = hf.output.load(tmp_path / "out")
    n, v = visible_pairs(500)
    np.testing.assert_allclose(np.asarray(back.model.evaluate(n, v)), np.asarray(res.model.evaluate(n, v)),
                               rtol=1e-5, atol=1e-6)
    assert back.model.context["radius"] == pytest.approx(ctx["radius"])


@pytest.mark.slow  # a chooser run with its disc vote; the fast suite fits the disc once (above)
def test_the_disc_vote_keeps_the_structure_of_lower_validation_error_and_records_both():
    """The vote of the quality mode on a small fit: the kept structure is fitted again read at its light's
    disc and the lower validation error wins; ``selection.disc`` records the labels, radii and errors."""
    env = hf.light.sun_sky(SUN, sun_radiance=3.0e3, sun_angle_deg=6.0, sky=(0.3, 0.4, 0.6), resolution=16)
    brdf = hf.brdf.ggx(kd=0.0, ks=1.0, roughness=0.2, f0=(0.95, 0.93, 0.88))
    target = hf.light.lighting_target(brdf, env, parametrization="RO")
    samples = hf.fit.draw_samples(target, "RO", GRID)
    point = DISC.with_highlights(disc=False)

    def fit(structure, line):
        kw = structure.keywords()
        return hf.fit.factorize(target, texture_size=8, samples=samples,
                                **{**kw, "advanced": {**kw["advanced"], "line_size": line}})

    first = fit(point, 32)
    logged = []
    kept = pipeline._disc_vote(first, point, 32, fit, logged.append)
    note = kept.selection["disc"]
    errs = note["validation_nrmse"]
    assert note["labels"] == [point.label(), DISC.label()] and len(errs) == 2
    assert note["kept"] == (errs[1] < errs[0])
    assert Structure.of(kept.solver["structure"]).highlights.disc == note["kept"]
    assert note["radii"][0] == pytest.approx(float(hf.light.light_radii(env, np.asarray(kept.model.context["dominant"])[None])[0]))
    assert any("disc vote" in line and "kept" in line for line in logged)

