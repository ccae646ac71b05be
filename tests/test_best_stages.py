"""The line and disc votes read a short fit first (the plan's ``vote_screen``): the alternative of the kept
structure is fitted in full only where its short fit's figure is below the kept structure's."""

from __future__ import annotations

import logging

import jax
import numpy as np
import pytest

import homofac as hf
from homofac.fit import pipeline, plan, polish, sums, validation
from homofac.fit.structures import Structure

LINED = Structure.of({"parametrization": "RO", "terms": 2, "diffuse": "fitted", "nv_factor": True,
                      "highlights": {"terms": 1, "fresnel": True}})


class _Voted:
    """The part of a Result the votes read: its validation nrmse, its ridge score, a model context, selection."""

    def __init__(self, plain: float, ridge: float, selection: dict | None = None, radius: float = 0.05):
        self.metrics = {"validation": {"float": {"nrmse": plain}}}
        self.ridge, self.selection = ridge, selection or {}
        self.model = type("M", (), {"context": {"radius": radius, "radius1": radius, "radius2": radius}})()
        self.solver = {"structure": LINED.record()}

    def replace(self, selection):
        return _Voted(self.metrics["validation"]["float"]["nrmse"], self.ridge, selection)


def _never(*args):
    raise AssertionError("fitted in full although its short fit read higher")


def test_the_line_vote_fits_the_other_size_in_full_only_where_its_short_fit_reads_lower():
    first = _Voted(0.062, 0.128, {"metric": sums.RIDGE_METRIC})
    asked = []

    def quick(figures):
        def q(structure, size):
            asked.append((structure, size))
            return figures[size], None
        return q

    kept, line = pipeline._line_vote(first, LINED, (32, 128), _never, lambda m: None, lambda r: r.ridge,
                                     quick({32: 0.10, 128: 0.11}), 10)
    assert line == 32 and kept.ridge == 0.128
    note = kept.selection["lines"]
    assert note["sizes"] == [32] and note["kept"] == 32 and note[sums.RIDGE_METRIC] == [0.128]
    assert note["screen"]["sweeps"] == 10 and note["screen"]["figures"] == [0.10, 0.11]
    assert set(asked) == {(LINED, 32), (LINED, 128)}
    # lower on the short fit: fitted in full, and the full figures decide (here the full fit reads higher)
    full = {128: _Voted(0.06, 0.130)}
    kept, line = pipeline._line_vote(first, LINED, (32, 128), lambda s, n: full[n], lambda m: None,
                                     lambda r: r.ridge, quick({32: 0.10, 128: 0.09}), 10)
    assert line == 32 and kept.selection["lines"]["sizes"] == [32, 128]
    assert kept.selection["lines"][sums.RIDGE_METRIC] == [0.128, 0.130]
    full = {128: _Voted(0.06, 0.120)}
    kept, line = pipeline._line_vote(first, LINED, (32, 128), lambda s, n: full[n], lambda m: None,
                                     lambda r: r.ridge, quick({32: 0.10, 128: 0.09}), 10)
    assert line == 128 and kept.ridge == 0.120


def test_the_disc_vote_keeps_the_point_light_without_a_full_fit_where_the_disc_reads_higher_short():
    first = _Voted(0.07, 0.09, {"metric": sums.RIDGE_METRIC})
    disc = LINED.with_highlights(disc=True)
    shorts = {LINED: (0.10, None), disc: (0.12, _Voted(0.2, 0.2, radius=0.04))}
    kept = pipeline._disc_vote(first, LINED, 32, _never, lambda m: None, lambda r: r.ridge,
                               lambda s, n: shorts[s], 10)
    note = kept.selection["disc"]
    assert note["kept"] is False and note["labels"] == [LINED.label()] and note[sums.RIDGE_METRIC] == [0.09]
    assert note["radii"] == [0.04] and note["screen"]["figures"] == [0.10, 0.12]
    assert note["screen"]["tried"] == [LINED.label(), disc.label()]


def test_best_plans_the_short_fits_of_its_votes_and_balanced_has_no_such_votes():
    env = hf.light.sun_sky((0.3, 0.2, 0.9), sun_radiance=300.0, sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6), resolution=8)
    t = hf.light.lighting_target(hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3,
                                                       f0=(1.0, 0.78, 0.34)), env)
    over = {"advanced": {"validation_light": int(validation.environment(t).info["resolution"])}}
    best = plan.build_plan(t, "best", over)
    assert best.vote_screen == plan.PRESETS["best"].vote_screen > 0 and best.vote_stride == best.race_stride
    # the kept candidate, and a vote's alternative fitted in full, continue from their short fits
    assert best.race_continue and best.to_dict()["race"]["continue"] and "continues on every pair" in str(best)
    votes = {v.name: v.reads for v in best.votes}
    assert all(f"{best.vote_screen}-sweep" in votes[n] for n in ("lines", "disc"))
    assert plan.dumps(best) and '"vote_screen"' in plan.dumps(best)
    assert plan.build_plan(t, "balanced", over).vote_screen == 0
    # a linear fit too short for a short fit, or no line or disc vote: no vote screen
    short = plan.build_plan(t, "best", {**over, "advanced": {**over["advanced"], "linear": {"iterations": 5}}})
    assert short.vote_screen == 0
    single = plan.build_plan(t, "best", {**over, "advanced": {**over["advanced"], "line_size": 32,
                                                               "highlights": {"disc": False}}})
    assert single.vote_screen == 0 and "lines" not in [v.name for v in single.votes]
    assert np.isfinite(best.race_margin)


def test_best_plans_one_polish_stage_the_ridge_pairs_from_the_als_fit_and_its_vote_records_it_as_the_third():
    """``polish_direct``: the plan's polish vote is between the ALS fit and the ridge stage straight from it;
    ``_polish_vote`` records that stage as the third of ``polish_stages`` (what a refit's ``recorded_direct``
    reads), kept only where its figure is below the ALS fit's."""
    env = hf.light.sun_sky((0.3, 0.2, 0.9), sun_radiance=300.0, sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6), resolution=8)
    t = hf.light.lighting_target(hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3,
                                                       f0=(1.0, 0.78, 0.34)), env)
    over = {"advanced": {"validation_light": int(validation.environment(t).info["resolution"])}}
    best = plan.build_plan(t, "best", over)
    assert best.polish_direct and best.ridge > 0 and best.to_dict()["polish_direct"]
    votes = {v.name: v.choices for v in best.votes}
    assert votes["polish"] == ("ALS fit", "polish + ridge pairs from the ALS fit") and "from the ALS fit" in str(best)
    no_ridge = plan.build_plan(t, "best", {**over, "advanced": {**over["advanced"], "linear": {"ridge": 0}}})
    assert not no_ridge.polish_direct and no_ridge.ridge == 0 and len({v.name: v for v in no_ridge.votes}["polish"].choices) == 2
    assert not plan.build_plan(t, "balanced", over).polish_direct
    als = _Voted(0.07, 0.10, {"metric": sums.RIDGE_METRIC})
    for after, kept in ((0.09, True), (0.11, False)):
        got = pipeline._polish_vote(als, [_Voted(0.068, after)], lambda r: r.ridge, 8, 20000, "X", lambda m: None,
                                    4, (2,))
        note = got.selection["polish"]
        assert note["kept"] is kept and got.ridge == (after if kept else 0.10)
        assert [(st["ridge"], st["start"]) for st in note["stages"]] == [(20000, polish.STAGE_STARTS[2])]
        assert (note["stage"], note["ridge"], note["start"]) == ((2, 20000, "als") if kept else (None, 0, None))


if __name__ == "__main__":
    pytest.main([__file__, "-q"])


def test_the_ridge_score_in_padded_calls_is_the_score_of_every_pair_evaluated_once():
    """``polish.ridge_nrmse`` evaluates the model in calls of ``metrics.CHUNK`` pairs (the last padded, the
    program shape the metrics compiled): the same figure as every pair evaluated in one call."""
    env = hf.light.sun_sky((0.3, 0.2, 0.9), sun_radiance=300.0, sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6), resolution=8)
    t = hf.light.lighting_target(hf.brdf.ggx(kd=0.1, ks=1.0, roughness=0.3, f0=0.9), env)
    fac = hf.fit.factorize(t, "split_sum", texture_size=8, sampling={"kind": "texels", "size": 4, "validation": 700,
                                                                     "cache": False})
    smp = hf.fit.draw_samples(t, "NR", {"kind": "texels", "size": 4, "validation": 700, "cache": False})
    rv = polish.ridge_validation(t, smp, 300, 1)
    got = polish.ridge_nrmse(fac, smp, rv)
    small = polish.ridge_nrmse(fac, smp, rv, chunk=256)  # three calls, the last padded
    approx = np.asarray(fac.evaluate(smp.val_a, smp.val_b), np.float64)
    ridge = np.asarray(fac.evaluate(rv.pairs.a, rv.pairs.b), np.float64)
    want = hf.fit.ridge.stratified_nrmse(approx, np.asarray(smp.val_y, np.float64), rv.inside, ridge, rv.y,
                                         rv.pairs.weight)
    assert np.isfinite(want) and got == pytest.approx(want, rel=1e-5) and small == pytest.approx(want, rel=1e-5)

    # another structure on the same textures (one more term): its figure reads the lookup programs already
    # compiled (one per projection, mapper and texture shape), not a program of its own
    more = hf.factorization.Factorization(fac.model.kind, fac.model.quantity, fac.model.textures,
                                          fac.model.terms + (fac.model.terms[0],), fac.model.context)
    with jax.log_compiles():
        logging.getLogger("jax").setLevel(logging.WARNING)
        handler = _Count()
        logging.getLogger("jax").addHandler(handler)
        try:
            other = polish.ridge_nrmse(more, smp, rv)
        finally:
            logging.getLogger("jax").removeHandler(handler)
    approx = np.asarray(more.evaluate(smp.val_a, smp.val_b), np.float64)
    ridge = np.asarray(more.evaluate(rv.pairs.a, rv.pairs.b), np.float64)
    want = hf.fit.ridge.stratified_nrmse(approx, np.asarray(smp.val_y, np.float64), rv.inside, ridge, rv.y,
                                         rv.pairs.weight)
    assert other == pytest.approx(want, rel=1e-5) and other != pytest.approx(got, rel=1e-3)
    assert handler.compiles == 0


class _Count(logging.Handler):
    """Counts JAX's compile messages (``jax.log_compiles``)."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.compiles = 0

    def emit(self, record):
        self.compiles += "compilation of jit(" in record.getMessage()

