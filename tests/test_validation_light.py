"""The validation lighting (issue 41 item 3): the votes read validation values at a light resolution
decided by doubling until converged (homofac.fit.validation), refined from the environment's source
(homofac.light.refine); a plan value, printed and recorded."""

from __future__ import annotations

import json

import numpy as np
import pytest

import homofac as hf
from homofac.errors import HomofacError
from homofac.fit import plan, sampling, validation
from homofac.fit.samples import evaluate_blocked, evaluate_grouped
from homofac.light import refine

GLOSSY = dict(kd=0.1, ks=1.0, roughness=0.4, f0=0.9)


def _target(env):
    return hf.light.lighting_target(hf.brdf.ggx(**GLOSSY), env)


def test_each_environment_is_refined_by_its_most_faithful_route_with_its_power():
    for env, how in ((hf.light.load_environment("studio", 4), "source"),
                     (hf.light.sun_sky(resolution=4, sun_angle_deg=3.0), "synthetic"),
                     (hf.light.preetham_sky(resolution=4), "synthetic"),
                     (hf.light.painted_lights([((0, 0, 1), 10.0, 5.0)], 4, background=0.1), "synthetic"),
                     (hf.light.from_latlong(np.random.default_rng(0).random((8, 16, 3)), 4), "texels")):
        fine = refine.at_resolution(env, 8)
        assert refine.route(env) == how and fine.info["refined"] == how and fine.info["resolution"] == 8
        assert fine.num_lights == 6 * 64
        np.testing.assert_allclose(hf.light.total_power(fine), hf.light.total_power(env), rtol=2e-3)


def test_split_texels_keep_the_radiance_field_so_the_irradiance_is_unchanged():
    env = hf.light.from_latlong(np.random.default_rng(1).random((8, 16, 3)) ** 4, 4)
    split = refine.split_texels(env, 16)
    n = sampling.random_directions(np.random.default_rng(2), 50, False).astype(np.float32)
    np.testing.assert_allclose(hf.light.irradiance(split, n), hf.light.irradiance(env, n), rtol=1e-4)
    with pytest.raises(HomofacError, match="multiple"):
        refine.split_texels(env, 6)


def test_the_lighting_summed_over_light_blocks_is_the_lighting():
    t = _target(hf.light.sun_sky(resolution=8, sun_angle_deg=3.0))
    g = validation.decision_pairs(400, 3)
    np.testing.assert_allclose(evaluate_blocked(t, g), np.asarray(evaluate_grouped(t, g)), rtol=2e-4, atol=1e-6)


def test_a_sharp_environment_needs_a_finer_validation_lighting_than_a_smooth_one(monkeypatch):
    monkeypatch.setattr(validation, "MAX_DOUBLINGS", 2)  # 4 -> 16 at most: the sun stops there, the sky before
    sharp = validation.decide(_target(hf.light.sun_sky(resolution=4, sun_radiance=3000.0, sun_angle_deg=1.0)), 800, 1)
    smooth = validation.decide(_target(hf.light.gradient_sky(1.0, 0.5, 4)), 800, 1)
    assert sharp.resolution > smooth.resolution >= 4
    for v in (sharp, smooth):
        # doubling from the fit's resolution: every change but the last is above the tolerance
        assert [r for r, _ in v.changes] == [4 * 2 ** i for i in range(len(v.changes))]
        assert all(c >= validation.TOLERANCE for _, c in v.changes[:-1])
        assert v.converged == (v.changes[-1][1] < validation.TOLERANCE)
        assert v.resolution == (v.changes[-1][0] if v.converged else 2 * v.changes[-1][0])
    assert smooth.converged and smooth.resolution < 16 and sharp.changes[-1][1] > smooth.changes[-1][1]


def test_the_plan_prints_the_validation_lighting_and_refuses_a_size_it_cannot_refine_to():
    t = _target(hf.light.load_environment("interior", 4))
    p = plan.build_plan(t, "fast", {"advanced": {"validation_light": 16}})
    assert p.validation_light.resolution == 16 and p.validation_light.start == 4
    assert "validation lighting: the lights holding 90% of the power at resolution 16, the rest at 4" in str(p)
    assert json.loads(plan.dumps(p))["validation_light"]["resolution"] == 16
    assert plan.build_plan(t, None, {"parametrization": "NR"}).validation_light is None  # a product holds no vote
    with pytest.raises(HomofacError, match="validation_light must be the light resolution 4 times a power of 2"):
        plan.build_plan(t, "fast", {"advanced": {"validation_light": 12}})


@pytest.mark.slow
def test_a_saved_record_keeps_the_validation_lighting_its_votes_read(tmp_path):
    t = _target(hf.light.sun_sky(resolution=4, sun_angle_deg=3.0))
    fac = hf.fit.factorize(t, "NR", target_error=0.9, texture_size=8,
                           sampling={"kind": "texels", "size": 4, "validation": 200, "cache": False},
                           advanced={"validation_light": 16})
    fac.save(tmp_path / "out")
    doc = json.loads((tmp_path / "out" / "factorization.json").read_text())
    assert doc["selection"]["validation_light"]["resolution"] == 16
    assert doc["selection"]["validation_light"]["lights"] == fac.selection["validation_light"]["lights"]
