"""The ``line`` textures of a sum (issue 13, grazing views): ``line_size``, its quality-mode rule, the
refusal for a single product, and that every line of a fit, its polish, its save and its refit keep
the size."""

from __future__ import annotations

import numpy as np
import pytest

import homofac as hf
from homofac.fit import plan
from homofac.errors import HomofacError
from homofac.fit import pipeline, structures, sums
from homofac.fit.options import FitOptions

SUN = np.array([0.5, -0.3, 0.81])
SUN /= np.linalg.norm(SUN)
GRID = {"kind": "grid", "size": 8, "mapper": "dual_paraboloid", "count": 20000, "validation": 3000, "cache": False}


def _lines(model) -> dict:
    return {t.name: t.size for t in model.textures if t.mapper == "line"}


def test_the_line_sizes_rule_given_vote_and_default():
    """Given, it is the only size; with a budget above balanced's (the ``best`` preset's line vote) the
    candidates get the 32-texel lines and the kept structure is tried again with a multiple of
    ``texture_size`` that grows with it (no vote where that multiple is 32 too); otherwise the 32 of every
    earlier fit."""
    q = plan.budget_of(FitOptions(preset="balanced"))
    line = structures.LINE_SIZE
    vote32, vote16 = plan.line_sizes(FitOptions(max_lookups=q + 1)), plan.line_sizes(FitOptions(max_lookups=16, texture_size=16))
    assert vote32[0] == vote16[0] == line and len(vote32) == len(vote16) == 2
    assert vote32[1] == 2 * vote16[1] and vote32[1] % 32 == 0 and vote32[1] > line  # k x texture_size, k fixed
    assert plan.line_sizes(FitOptions(max_lookups=16, texture_size=line * 16 // vote16[1])) == (line,)  # k x S = 32
    assert plan.line_sizes(FitOptions(target_error=0.1, terms=2)) == vote32  # the ladder's budget is best's
    assert plan.line_sizes(FitOptions(max_lookups=q)) == (line,)
    assert plan.line_sizes(FitOptions(terms=3, nv_factor=True)) == (line,)
    assert plan.line_sizes(FitOptions(max_lookups=16, advanced={"line_size": 48})) == (48,)
    assert plan.line_sizes(FitOptions(terms=2, advanced={"line_size": 48})) == (48,)


@pytest.mark.parametrize("bad", [1, 0, 5000, 2.5, "many"])
def test_a_bad_line_size_is_refused_in_one_line(bad):
    with pytest.raises(HomofacError) as e:
        pipeline.options("NR", terms=2, advanced={"line_size": bad})
    assert "line_size" in str(e.value) and "\n" not in str(e.value)


def test_line_size_is_refused_for_a_single_log_space_product():
    env = hf.light.sun_sky(SUN, sun_radiance=300.0, sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6), resolution=8)
    target = hf.light.lighting_target(hf.brdf.ggx(kd=0.3, ks=1.0, roughness=0.4, f0=0.04), env)
    with pytest.raises(HomofacError, match="line_size sizes the line textures of a sum"):
        hf.fit.factorize(target, "NRW", texture_size=8, advanced={"line_size": 64}, sampling=GRID)


@pytest.mark.slow  # a polished fit, a save and a refit (about 45 s of compiling); the fast suite checks the rule and refusals
def test_every_line_of_a_sum_its_polish_save_and_refit_keep_the_line_size(tmp_path):
    """A sum with w(n.v) lines and a highlight term with its Fresnel and cosine lines, at 64 texels:
    every line has 64 (the maps keep texture_size), the split sum's computed W too; the polish, the
    saved directory and a refit to another environment keep them."""
    env = hf.light.sun_sky(SUN, sun_radiance=300.0, sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6), resolution=8)
    brdf = hf.brdf.ggx(kd=0.3, ks=1.0, roughness=0.4, f0=0.04)
    target = hf.light.lighting_target(brdf, env)
    kw = dict(texture_size=8, sampling=GRID, diffuse="fitted", nv_factor=True)
    fac = hf.fit.factorize(target, "NR", advanced={"prefiltered": True, "line_size": 64,
                                                   "highlights": {"terms": 1, "fresnel": True, "cosine": True},
                                                   "linear": {"polish": 2, "polish_size": 6}}, **kw)
    lines = _lines(fac.model)
    assert set(lines) == {"W", "w0", "d1", "f1", "c1", "w1"} and set(lines.values()) == {64}
    assert {t.size for t in fac.model.textures if t.mapper != "line"} == {8}
    assert fac.solver["polish"]["steps"] == 2 and sums.line_size_of(fac.model) == 64
    fac.save(tmp_path / "out")
    back = hf.output.load(tmp_path / "out")
    assert _lines(back.model) == lines
    n = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]], np.float32)
    v = np.array([[0.0, 0.6, 0.8], [0.0, 0.0, 1.0]], np.float32)
    np.testing.assert_allclose(np.asarray(back.model.evaluate(n, v)), np.asarray(fac.model.evaluate(n, v)),
                               rtol=1e-5, atol=1e-6)
    other = hf.light.lighting_target(brdf, hf.light.sun_sky(-SUN * np.array([1, 1, -1]), sun_radiance=300.0,
                                                            sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6), resolution=8))
    again = hf.fit.refit(fac, target=other)
    assert _lines(again.model) == lines


@pytest.mark.slow
def test_the_quality_mode_votes_on_the_line_size_of_the_structure_it_keeps():
    """Above 8 lookups the chooser fits its candidates with 32-texel lines, then the kept structure with
    4 x texture_size; ``selection.lines`` records both validation errors and the kept size is the one of
    the lower, which the result's lines and validation error are (the polish off, to see the vote alone:
    without a polish there are no ridge pairs, so the vote reads the plain validation nrmse, as the plan says)."""
    env = hf.light.sun_sky(SUN, sun_radiance=300.0, sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6), resolution=8)
    target = hf.light.lighting_target(hf.brdf.ggx(kd=0.3, ks=1.0, roughness=0.4, f0=0.04), env)
    fac = hf.fit.factorize(target, "NR", texture_size=16, max_lookups=9, advanced={"linear": {"polish": 0}},
                           sampling={"count": 30000, "validation": 4000, "cache": False})
    note = fac.selection["lines"]
    assert note["sizes"] == [32, 64]
    errs = note["validation_nrmse"]
    assert fac.selection["metric"] == "validation.float.nrmse"
    k = int(np.argmin(errs))
    assert note["kept"] == note["sizes"][k]
    assert errs[0] == pytest.approx(fac.selection["chosen"]["validation_nrmse"])
    assert fac.metrics["validation"]["float"]["nrmse"] == pytest.approx(errs[k])
    lines = _lines(fac.model)
    assert lines and set(lines.values()) == {note["kept"]}
    assert "polish" not in fac.selection
