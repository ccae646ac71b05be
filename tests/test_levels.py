"""The validation lighting's values: the plan's decision and the validation values share their pairs and
their program (homofac.fit.levels), and decide what the light blocks' sums decided."""

from __future__ import annotations

import numpy as np

import homofac as hf
from homofac.fit import draw, levels, sampling, validation
from homofac.fit.metrics import metrics
from homofac.fit.options import SamplingOptions
from homofac.fit.samples import evaluate_blocked

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
    monkeypatch.setattr(levels, "evaluate", lambda tg, g, ref: evaluated.append(len(g.normals)) or real(tg, g, ref))
    got = levels.values(vt, groups, refined=False)
    assert evaluated == [len(groups.normals) - min(validation.DECISION_NORMALS, len(groups.normals))]
    np.testing.assert_allclose(got, real(vt, groups, False), rtol=1e-5, atol=1e-7)
    # the sampled validation values are those values (float32), in the validation pairs' order
    s = draw.draw_samples(t, "NR", SamplingOptions(kind="grid", size=4, count=2000, validation=count, seed=seed - 1,
                                                   cache=False), validation_target=vt, validation_light=v.resolution)
    np.testing.assert_allclose(s.val_y, got.astype(np.float32), rtol=1e-5, atol=1e-7)
