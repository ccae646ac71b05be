"""The two-level light sum (homofac.light.tree, Lighting.grouped with a tree): it equals the full sum of
eq. 10 where every cell is refined, stays close where few are, for a lobe-form model and a measured
(table) one alike, and is what the plan's validation lighting uses above the fit's light resolution."""

from __future__ import annotations

import numpy as np
import pytest

import homofac as hf
from homofac.brdf.measured import merl, tabulate_merl
from homofac.fit import plan, sampling, validation
from homofac.fit.metrics import metrics
from homofac.fit.samples import evaluate_blocked, evaluate_grouped
from homofac.light.tree import cube_texel, light_tree
from homofac.target import Target

GLOSSY = dict(kd=0.1, ks=1.0, roughness=0.3, f0=(0.9, 0.7, 0.4))


def _env():
    """A small map with a bright spot and a delta light (its own cell)."""
    img = 0.2 + np.random.default_rng(0).random((16, 32, 3))
    img[3:5, 10:12] = 40.0
    env = hf.light.from_latlong(img, 8)
    return hf.light.with_lights(env, [{"type": "directional", "direction": [0.3, 0.2, 0.9], "irradiance": 5.0}])


def _values(brdf, env, groups, tree=None):
    fn = hf.light.Lighting(brdf, env, tree=tree)
    return np.asarray(evaluate_grouped(Target("lighting", fn, "lighting"), groups), np.float64)


def test_the_tree_holds_every_light_once_and_each_delta_light_alone():
    env = _env()
    tree = light_tree(env, 2, 4)
    ch = np.asarray(tree.children)
    real = ch[ch < env.num_lights]
    assert sorted(real.tolist()) == list(range(env.num_lights))
    assert tree.cells == 6 * 4 + 1 and tree.width == 16  # a texel of face size 2 holds 4 x 4 of face size 8
    assert np.sum(ch[-1] < env.num_lights) == 1 and ch[-1, 0] == env.num_lights - 1  # the delta light
    d = np.asarray(env.directions)[:6 * 64]
    np.testing.assert_array_equal(cube_texel(d, 2), hf.light.refine.parents(2, 8))  # the pinned layout


def _groups():
    return sampling.grouped_random(400, 3, views=8)


def test_refining_every_cell_is_the_full_sum_for_a_lobe_model_and_a_measured_table():
    """Equal to float32 rounding: the two programs add the 6 * 64 + 1 positive terms in different orders, each
    within about n * 2**-24 = 2.3e-5 of the sum (under the suite's -O0 they differ by up to 4e-5 of it,
    docs/notes/speed.md; compiled with XLA's optimizations this test took twice the CPU)."""
    env, groups = _env(), _groups()
    ct = hf.brdf.cook_torrance(**GLOSSY)
    for brdf in (ct, merl(table=tabulate_merl(ct, (16, 16, 32)))):
        full = _values(brdf, env, groups)
        every = _values(brdf, env, groups, light_tree(env, 4, 10_000))  # refine >= the visible cells
        np.testing.assert_allclose(every, full, rtol=6e-5, atol=1e-6 * np.abs(full).max())


def test_few_refined_cells_stay_close_to_the_full_sum_and_more_get_closer():
    env, groups = _env(), _groups()
    brdf = hf.brdf.cook_torrance(**GLOSSY)
    full = _values(brdf, env, groups)
    errs = [metrics(_values(brdf, env, groups, light_tree(env, 4, k)), full)["nrmse"] for k in (4, 16)]
    assert errs[0] < 0.05 and errs[1] < 0.005 and errs[1] < errs[0] / 4, errs


def test_the_plan_sums_the_validation_lighting_by_a_tree_only_where_it_has_many_more_lights():
    assert validation.light_sum(32, 32, 10**6) is None and validation.light_sum(8, 32, 10**6) is None  # R = r; too few
    assert validation.light_sum(32, 128, 39232) == (32, validation.REFINED_LIGHTS // 16)  # the interior at 128
    assert validation.light_sum(32, 64, 6576) is None  # the studio at 64: the full sum is cheaper


def test_the_validation_lighting_summed_by_a_tree_is_within_its_tolerance_and_recorded():
    env = hf.light.load_environment("studio", 16)
    target = hf.light.lighting_target(hf.brdf.ggx(kd=0.1, ks=1.0, roughness=0.2, f0=0.9), env)
    groups = _groups()
    tree = validation.lighting_at(target, 32, (16, 64))
    full = validation.lighting_at(target, 32, None)
    assert tree.fn.tree is not None and full.fn.tree is None and tree.fn.env.num_lights == full.fn.env.num_lights
    err = metrics(evaluate_blocked(tree, groups), evaluate_blocked(full, groups))["nrmse"]
    assert err < 0.003, err  # far below the decision's tolerance
    given = validation.ValidationLight(32, 16, "given", (), False, validation.TOLERANCE, 100, (16, 64))
    assert given.record()["light_sum"] == {"coarse": 16, "refined": 64} and "light tree" in given.describe()
    assert plan.build_plan(target, "fast", {"advanced": {"validation_light": 32}}).validation_light == validation.given(target, 32)
