"""The plan (issue 41): presets set values, overrides replace them, the plan says what will run."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import homofac as hf
from homofac.app import cli
from homofac.app.config import parse
from homofac.errors import HomofacError
from homofac.fit import plan
from homofac.fit.options import DEFAULT_PRESET, FitOptions
from homofac.fit.structures import Structure

GOLD = {"model": "cook_torrance", "kd": [0.05, 0.04, 0.02], "ks": 1.0, "roughness": 0.3, "f0": [1.0, 0.78, 0.34]}


@pytest.fixture(scope="module")
def envs():
    return {"sun": hf.light.sun_sky((0.3, 0.2, 0.9), sun_radiance=300.0, sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6),
                                    resolution=8),
            "interior": hf.light.load_environment("interior", 8)}


def _gold(env):
    return hf.light.lighting_target(hf.brdf.cook_torrance(**{k: v for k, v in GOLD.items() if k != "model"}), env)


def test_each_preset_is_a_named_lookup_budget_whose_candidates_fit_it(envs):
    t = _gold(envs["sun"])
    budgets = []
    for name in ("fast", "balanced", "best"):
        p = plan.build_plan(t, name)
        budgets.append(p.max_lookups)
        assert p.mode == "choose" and p.preset == name and p.candidates
        assert all(hf.fit.structures.lookups(c, "lighting") <= p.max_lookups for c in p.candidates)
        assert [v.name for v in p.votes][0] == "structure"
        assert str(p).startswith(f"plan: choose (preset {name})") and name in plan.dumps(p)
    assert budgets == [4, 8, 16]


def test_an_override_replaces_the_presets_value_and_nothing_else(envs):
    t = _gold(envs["sun"])
    best = plan.build_plan(t, "best")
    assert best.ridge > 0 and best.disc_vote and len(best.line_sizes) == 2 and best.linear.nv_balance == 0
    less = plan.build_plan(t, "best", {"sampling": {"count": 1000, "validation": 500}, "line_size": 48,
                                       "linear": {"ridge": 0, "nv_balance": 0.5}, "highlight_disc": False})
    assert (less.grid_count, less.validation, less.line_sizes, less.ridge) == (1000, 500, (48,), 0)
    assert less.linear.nv_balance == 0.5 and not less.disc_vote
    assert [v.name for v in less.votes] == ["structure", "polish"]  # no line vote (one size), no disc vote
    assert less.candidates == best.candidates  # the candidates were not overridden
    assert plan.build_plan(t, "best", {"max_lookups": 6}).max_lookups == 6
    fewer = plan.build_plan(t, "balanced", {"highlight_terms": 0})
    assert fewer.candidates and not any(c.highlight_terms for c in fewer.candidates)


def test_polish_given_runs_on_every_candidate_and_the_kept_structure_gets_no_second_polish(envs):
    t = _gold(envs["interior"])
    p = plan.build_plan(t, "fast", {"linear": {"polish": 3}})
    assert p.linear.polish == 3 and p.polish == 0 and "polish" not in [v.name for v in p.votes]
    off = plan.build_plan(t, "fast", {"linear": {"polish": 0}})
    assert off.linear.polish == 0 and off.polish == 0
    lm = plan.build_plan(t, "fast", {"linear": {"method": "levenberg_marquardt"}})
    assert lm.polish == 0  # the polish follows an ALS fit


def test_the_candidates_balance_the_nv_bins_only_where_the_brdf_has_a_diffuse_part(envs):
    env = envs["interior"]
    plastic = hf.light.lighting_target(hf.brdf.cook_torrance(kd=0.3, ks=1.0, roughness=0.6, f0=0.04), env)
    mirror = hf.light.lighting_target(hf.brdf.ggx(kd=0.0, ks=1.0, roughness=0.1, f0=0.9), env)
    brdf = hf.fit.brdf_target(hf.brdf.cook_torrance(kd=0.3, ks=1.0, roughness=0.6, f0=0.04))
    assert plan.build_plan(plastic, "balanced").linear.nv_balance == plan.PRESETS["balanced"].nv_balance > 0
    assert plan.build_plan(mirror, "balanced").linear.nv_balance == 0
    bp = plan.build_plan(brdf, "balanced")
    assert bp.parametrization == "PQP" and bp.linear.nv_balance == 0 and bp.polish == 0 and bp.ridge == 0
    assert plan.build_plan(plastic, "balanced", {"linear": {"nv_balance": 0.0}}).linear.nv_balance == 0.0
    with pytest.raises(HomofacError, match="nv_balance"):
        plan.build_plan(brdf, "balanced", {"linear": {"nv_balance": 0.5}})


def test_no_preset_and_no_naming_key_is_the_default_preset_and_a_named_parametrization_a_single_product(envs):
    t = _gold(envs["sun"])
    assert FitOptions().preset == DEFAULT_PRESET == "balanced"
    assert plan.build_plan(t).preset == "balanced"
    assert plan.build_plan(t, None, {"parametrization": "NR"}).mode == "product"
    assert plan.build_plan(t, None, {"terms": 2, "nv_factor": True}).mode == "sum"
    assert plan.build_plan(t, None, {"parametrization": "split_sum"}).mode == "baseline"
    # max_lookups alone keeps the settings its budget always had: the smallest preset that holds it
    assert [plan.build_plan(t, None, {"max_lookups": n}).preset for n in (3, 4, 6, 8, 12, 16, 40)] == \
        ["fast", "fast", "balanced", "balanced", "best", "best", "best"]


def test_a_config_naming_only_a_brdf_an_environment_and_a_preset_is_complete(tmp_path, capsys):
    cfg = parse({"target": {"brdf": GOLD, "environment": {"file": "interior", "resolution": 8}}, "preset": "fast"})
    assert cfg.preset == "fast" and cfg.is_sum
    bare = parse({"target": {"brdf": GOLD, "environment": {"file": "interior"}}})
    assert bare.preset == DEFAULT_PRESET
    brdf = parse({"target": {"kind": "brdf", "brdf": GOLD}})
    assert brdf.preset == DEFAULT_PRESET and brdf.parametrization == "PQP"
    old = parse({"target": {"brdf": GOLD, "environment": {"file": "interior"}}, "parametrization": "NR"})
    assert old.preset is None and not old.is_sum
    with pytest.raises(HomofacError, match="preset"):
        parse({"target": {"brdf": GOLD}, "preset": "fastest"})
    path = tmp_path / "c.yaml"
    path.write_text("target:\n  brdf: {model: ggx, roughness: 0.3}\n  environment: {file: interior, resolution: 8}\n"
                    "preset: best\n")
    assert cli.fit_main([str(path), "--plan"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("plan: choose (preset best)") and "16 lookups" in out and "vote lines" in out
    assert not (tmp_path / "out").exists()  # nothing ran


def test_the_plan_refuses_in_one_line_before_any_compute(envs):
    t = _gold(envs["sun"])
    for bad, words in ((({"parametrization": "split_sum", "preset": "fast"}), "baseline"),
                       ({"parametrization": "NR", "terms": 2, "linear": {"ridge": 10, "polish": 0}}, "ridge"),
                       ({"parametrization": "PQP", "max_lookups": 4}, "PQP")):
        with pytest.raises(HomofacError, match=words) as e:
            plan.build_plan(t, None, bad)
        assert "\n" not in str(e.value)


_PARAMS = ("N", "R", "NR", "NRV", "NRHD", "NRO", "RO", "IV", "GSHD", "PQP")


@settings(max_examples=300, deadline=None)
@given(st.builds(Structure, st.sampled_from(_PARAMS + ("NRW",)), st.integers(1, 40),
                 st.sampled_from([None, "exact", "fitted"]), st.booleans(), st.booleans(), st.booleans(),
                 st.integers(0, 5), st.integers(0, 3), st.booleans(), st.booleans(), st.booleans(), st.booleans()))
def test_a_structure_label_parses_back_to_the_structure(s):
    back = Structure.parse(s.label())
    assert back.label() == s.label()
    if s.highlight_terms and s.parametrization != "NRW":  # (without highlight terms the label drops their lines)
        assert back == s


def test_a_string_that_is_no_label_is_refused_in_one_line():
    for bad in ("", "NR", "NR x0", "E'+XYZ x1", "E'+NRW x2+H x1", 3):
        with pytest.raises(HomofacError) as e:
            Structure.parse(bad)
        assert "\n" not in str(e.value)


def test_the_presets_try_the_candidates_of_their_grid_directions_and_trial_the_polish_without_ridge_pairs(envs):
    """A preset's candidates lie on its grid directions (one grid of training pairs to draw); a named
    parametrization's samples given decide the direction instead. The polish trial is planned where the
    polish has no ridge stage (whose benefit a short polish without ridge pairs cannot show)."""
    t = _gold(envs["interior"])
    grid = FitOptions().sampling.model_copy(update={"kind": "grid"})
    for name, p in plan.PRESETS.items():
        got = plan.build_plan(t, name)
        dirs = {hf.fit.draw.grid_projection("lighting", c.parametrization, grid) for c in got.candidates}
        assert dirs <= set(p.directions or dirs)
        assert got.polish_trial == (p.polish_trial if got.polish and not got.ridge else 0)
        assert ("trial" in str(got)) == bool(got.polish_trial)
    assert plan.build_plan(t, "fast", {"linear": {"polish": 4}}).polish_trial == 0  # every candidate polished
    given_r = plan.build_plan(t, "fast", samples_given="r")
    assert {hf.fit.draw.grid_projection("lighting", c.parametrization, grid) for c in given_r.candidates} == {"r"}


def test_a_polish_trial_that_did_not_lower_the_figure_is_summarised_as_no_polish():
    before, after = {"validation_nrmse": 0.2141}, {"validation_nrmse": 0.2143}
    note = {"steps": 8, "validation_nrmse_before": 0.2141, "validation_nrmse_after": 0.2143, "stages": [],
            "rule": "vote", "kept": False, "stage": None, "ridge": 0, "start": None,
            "trial": {"steps": 2, "falls": False, "before": before, "after": after}}
    line = cli.polish_line(note)
    assert "2-step trial" in line and "0.2141 -> 0.2143" in line and "none run" in line
