"""The candidate loop's shared work: a warm start keeps its highlight terms, a fit continued from a strided short
fit (``sums.continued``) is that short fit carried on every pair, and the candidates' figures are evaluated
factor by factor in lookup programs every structure shares (``evaluate_by_factor``)."""

from __future__ import annotations

import logging

import jax
import numpy as np
import pytest

import homofac as hf
from homofac.factorization import _factor_lookup, evaluate_by_factor
from homofac.fit import sums
from homofac.fit.options import LinearOptions
from homofac.fit.structures import Structure

SUN = np.array([0.5, -0.3, 0.81]) / np.linalg.norm([0.5, -0.3, 0.81])
GRID = {"kind": "grid", "size": 8, "mapper": "dual_paraboloid", "count": 6000, "validation": 500, "cache": False}
OPTS = LinearOptions(iterations=4, tolerance=0.0)
HIGHLIGHT = Structure("RO", 1, "fitted", True, reflection=True, highlights={"terms": 1})
PLAIN = Structure("RO", 1, "fitted", True, reflection=True)


@pytest.fixture(scope="module")
def sun():
    env = hf.light.sun_sky(SUN, sun_radiance=3.0e3, sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6), resolution=8)
    target = hf.light.lighting_target(hf.brdf.ggx(kd=0.3, ks=1.0, roughness=0.3, f0=0.04), env, parametrization="RO")
    return target, hf.fit.draw_samples(target, "RO", GRID)


def _fit(sun, structure, opts=OPTS, **kw):
    target, samples = sun
    return sums.fit_sum(target, structure, "dual_paraboloid", 8, samples, opts, **kw)


def test_a_warm_start_keeps_the_highlight_terms(sun):
    """A fit begun from a model (``previous``) starts at that model: before any sweep it reads as the model
    (its highlight terms are not started again on the data alone, which would undo the warm start)."""
    target, samples = sun
    first = _fit(sun, HIGHLIGHT)
    run = sums.begin(target, HIGHLIGHT, "dual_paraboloid", 8, samples, OPTS, previous=first.model)
    assert run.sweeps == 0
    again = sums.finish(run)
    a, b = np.asarray(samples.val_a), np.asarray(samples.val_b)
    want = np.asarray(first.model.evaluate(a, b))
    np.testing.assert_allclose(np.asarray(again.model.evaluate(a, b)), want, rtol=1e-4,
                               atol=1e-5 * float(np.max(np.abs(want))))


TABLE = Structure("RO", 1, "fitted", True, reflection=True, highlights={"terms": 1, "fresnel": True, "table": True})


def test_a_table_fit_continued_from_its_short_fit_starts_where_the_short_fit_stopped(sun):
    """``best``'s kept candidate continues from its race fit (``race_continue``): for a structure whose highlight
    terms read a table T(n.i, n.v) the ALS carries the lines the table was made of, so the head's table is
    separated again (:func:`homofac.fit.table.separate`) and tabulated at the end. Before any sweep the continued
    fit keeps the head's accuracy (to the two interpolations: within 2 % of its validation nrmse), and its sweeps on
    every pair lower the training error from there."""
    target, samples = sun
    head = sums.fit_sum(target, TABLE, "dual_paraboloid", 8, sums.strided(samples, 3),
                        OPTS.model_copy(update={"iterations": 3}))
    run = sums.begin(target, TABLE, "dual_paraboloid", 8, samples, OPTS, previous=head.model)
    assert run.sweeps == 0
    again = sums.finish(run)
    out = sums.continued(target, TABLE, "dual_paraboloid", 8, samples, OPTS, stride=3, sweeps=3, head=head)

    def nrmse(model, a, b, y) -> float:
        d = np.asarray(model.evaluate(np.asarray(a), np.asarray(b)), np.float64) - np.asarray(y, np.float64)
        return float(np.mean(np.linalg.norm(d, axis=0) / np.linalg.norm(np.asarray(y, np.float64), axis=0)))

    val = (samples.val_a, samples.val_b, samples.val_y)
    assert abs(nrmse(again.model, *val) / nrmse(head.model, *val) - 1.0) < 0.02
    train = (samples.a, samples.b, samples.y)
    assert out.solver["structure"] == TABLE.record() and nrmse(out.model, *train) < nrmse(head.model, *train)


def test_a_fit_continued_from_its_strided_short_fit_carries_it_on_every_pair(sun):
    """``continued``: the short fit on every 3rd pair, then the fit on every pair from its model; the record
    names the head (stride, sweeps, its start) and the start rule of the head, and the short fit given (the
    race's) is the one it computes."""
    target, samples = sun
    head = sums.fit_sum(target, HIGHLIGHT, "dual_paraboloid", 8, sums.strided(samples, 3),
                        OPTS.model_copy(update={"iterations": 2}))
    assert len(sums.strided(samples, 3).a) == len(samples.a[::3]) and len(sums.strided(samples, 3).val_a) == 500
    out = sums.continued(target, HIGHLIGHT, "dual_paraboloid", 8, samples, OPTS, stride=3, sweeps=2)
    given = sums.continued(target, HIGHLIGHT, "dual_paraboloid", 8, samples, OPTS, stride=3, sweeps=2, head=head)
    alone = _fit(sun, HIGHLIGHT, previous=head.model)
    assert out.solver["head"] == {"stride": 3, "sweeps": 2, "start": head.solver["start"], "ran": 2}
    assert sums.recorded_head(out.solver) == out.solver["head"] and sums.recorded_head(alone.solver) is None
    assert out.solver["start"] == head.solver["start"] != "previous"
    for x, y, z in zip(out.model.textures, given.model.textures, alone.model.textures):
        np.testing.assert_array_equal(np.asarray(x.data), np.asarray(y.data))
        # the continued fit sums its normal equations in blocks of the short fit's pairs: float rounding apart
        scale = float(np.max(np.abs(np.asarray(z.data))))
        np.testing.assert_allclose(np.asarray(x.data), np.asarray(z.data), rtol=1e-4, atol=1e-5 * scale)


def test_the_figures_evaluated_factor_by_factor_equal_the_models_and_share_their_programs(sun, caplog):
    """``evaluate_by_factor`` gives ``evaluate``'s values to float rounding, and a second structure whose
    factors the first has (the same projections on textures of the same mappers and sizes) compiles no
    lookup program of its own."""
    target, samples = sun
    fits = [_fit(sun, s) for s in (HIGHLIGHT, PLAIN)]
    a, b = np.asarray(samples.val_a), np.asarray(samples.val_b)
    caplog.set_level(logging.WARNING, logger="jax")
    _factor_lookup.clear_cache()
    counts = []
    with jax.log_compiles():
        for f in fits:
            caplog.clear()
            got = evaluate_by_factor(f.model, a, b)
            counts.append(sum("compilation of jit(_factor_lookup)" in r.getMessage() for r in caplog.records))
            want = np.asarray(f.model.evaluate(a, b))
            scale = float(np.max(np.abs(want)))
            np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6 * scale)
    m = fits[0].model
    programs = {(x.projection, m.texture(x.texture).mapper, m.texture(x.texture).size) for t in m.terms for x in t.factors}
    assert counts[0] == len(programs) < sum(len(t.factors) for t in m.terms)  # two lines, two maps of r_off: shared
    assert counts[1] == 0
