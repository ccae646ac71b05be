"""The validation lighting's values: the plan's decision and the validation values share their pairs and
their program (homofac.fit.levels), and decide what the light blocks' sums decided."""

from __future__ import annotations

import logging

import jax
import numpy as np

import homofac as hf
from homofac.fit import draw, levels, sampling, validation
from homofac.fit.metrics import metrics
from homofac.fit.options import SamplingOptions
from homofac.fit.samples import evaluate_blocked
from homofac.light.refine import difference_blocks

ROUGH = dict(kd=0.8, ks=0.2, roughness=0.9, f0=0.04)


def test_the_decision_reads_the_blocks_values_and_the_validation_values_reuse_its_pairs(monkeypatch):
    monkeypatch.setattr(validation, "MAX_DOUBLINGS", 1)
    t = hf.light.lighting_target(hf.brdf.ggx(**ROUGH), hf.light.gradient_sky(1.0, 0.5, 4))
    count, seed = 2400, 5
    v = validation._decide(t, validation.environment(t), count, seed, lambda m: None)
    pairs = validation.decision_pairs(count, seed)
    y = {r: evaluate_blocked(validation.lighting_at(t, r), pairs) for r in (4, 8)}
    (r, change), = v.changes  # the change the light blocks' sums give at every level (to float rounding)
    np.testing.assert_allclose(change, float(metrics(y[4], y[8])["nrmse"]), rtol=1e-4)
    assert v.resolution == (4 if change < validation.TOLERANCE else 8) == 4  # a rough BRDF under a smooth sky: its own lights

    vt = validation.lighting_at(t, v.resolution)
    groups = sampling.grouped_random(count, seed, views=draw.VALIDATION_VIEWS)
    evaluated = []
    real = levels.evaluate
    monkeypatch.setattr(levels, "evaluate", lambda tg, g, ref, *a: evaluated.append(len(g.normals)) or real(tg, g, ref, *a))
    got = levels.values(vt, groups, refined=False)
    assert evaluated == [len(groups.normals) - min(validation.DECISION_NORMALS, len(groups.normals))]
    np.testing.assert_allclose(got, real(vt, groups, False), rtol=1e-5, atol=1e-7)
    # the sampled validation values are those values (float32), in the validation pairs' order
    s = draw.draw_samples(t, "NR", SamplingOptions(kind="grid", size=4, count=2000, validation=count, seed=seed - 1,
                                                   cache=False), validation_target=vt, validation_light=v.resolution)
    np.testing.assert_allclose(s.val_y, got.astype(np.float32), rtol=1e-5, atol=1e-7)


def test_a_refined_level_is_the_fit_lighting_plus_its_texels_difference_in_the_fit_program(caplog, monkeypatch):
    """levels.refined: the lighting with the bright texels refined (every light summed) is the fit's own
    values plus the fine-minus-coarse lights of those texels, in blocks the fit's compiled program
    evaluates: the values of the refined lighting's own evaluation, and no program compiled for them."""
    t = hf.light.lighting_target(hf.brdf.ggx(kd=0.1, ks=1.0, roughness=0.2, f0=0.9),
                                 hf.light.sun_sky(resolution=8, sun_radiance=300.0, sun_angle_deg=4.0))
    env, pairs = t.fn.env, validation.decision_pairs(400, 3)
    y = levels.evaluate(t, pairs, refined=False)  # compiles the fit's own program
    fine = validation.lighting_at(t, 16, None)  # the brightest texels at 16, every light summed
    for b in difference_blocks(env, fine.fn.env, 100):  # the fit's shapes and static data, every block
        assert b.info == env.info and b.directions.shape == env.directions.shape
    monkeypatch.setattr(levels, "VALUE_BLOCKS", 64)
    caplog.set_level(logging.WARNING, logger="jax")
    with jax.log_compiles():
        got = levels.refined(t, fine, pairs, y, max_blocks=64)
        values = levels.evaluate(fine, pairs, refined=True, start=t)  # the validation values' path
    assert not [r for r in caplog.records if "Finished XLA compilation of jit(_eval_groups" in r.getMessage()]
    want = evaluate_blocked(fine, pairs)
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5 * float(np.abs(want).max()))
    np.testing.assert_allclose(values, got, rtol=1e-6, atol=1e-7 * float(np.abs(want).max()))
    assert float(metrics(y, want)["nrmse"]) > 1e-3  # the refinement moves the values: the test can fail
    assert levels.refined(t, fine, pairs, y, max_blocks=0) is None  # more blocks than allowed
