"""The plan (issue 41): presets set values, overrides replace them, the plan says what will run.

The plans of lighting targets here are built with ``advanced.validation_light`` given at the
environment's own resolution (:func:`_plan`): a chooser's plan otherwise decides it by doubling the light
resolution (fit/validation.py), which evaluates the target at up to 8 times its light resolution, 5 to 30 s
of CPU a target; no property checked here reads it, and the decision has its own tests
(tests/test_validation_light.py). The CLI's ``--plan`` below and test_validation_light.py's plan tests
build plans that decide it."""

from __future__ import annotations

import dataclasses

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from jax._src import compiler
from hypothesis import strategies as st

import homofac as hf
from homofac.app import cli
from homofac.app.config import parse, parse_record
from homofac.errors import HomofacError
from homofac.fit import plan, validation
from homofac.fit.options import DEFAULT_PRESET, FitOptions, recorded_fit_options
from homofac.fit.structures import Structure

GOLD = {"model": "cook_torrance", "kd": [0.05, 0.04, 0.02], "ks": 1.0, "roughness": 0.3, "f0": [1.0, 0.78, 0.34]}


@pytest.fixture(scope="module")
def envs():
    return {"sun": hf.light.sun_sky((0.3, 0.2, 0.9), sun_radiance=300.0, sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6),
                                    resolution=8),
            "interior": hf.light.load_environment("interior", 8)}


def _plan(target, preset=None, overrides=None, **kw):
    """``plan.build_plan`` with the validation light given at the environment's resolution (module docstring)."""
    over = dict(overrides or {})
    env = validation.environment(target)
    if env is not None:
        over["advanced"] = {"validation_light": int(env.info["resolution"]), **over.get("advanced", {})}
    return plan.build_plan(target, preset, over, **kw)


def _gold(env):
    return hf.light.lighting_target(hf.brdf.cook_torrance(**{k: v for k, v in GOLD.items() if k != "model"}), env)


def test_each_preset_is_a_named_lookup_budget_whose_candidates_fit_it(envs):
    t = _gold(envs["sun"])
    budgets = []
    for name in ("fast", "balanced", "best"):
        p = _plan(t, name)
        budgets.append(p.max_lookups)
        assert p.mode == "choose" and p.preset == name and p.candidates
        assert all(hf.fit.structures.lookups(c, "lighting") <= p.max_lookups for c in p.candidates)
        assert [v.name for v in p.votes if v.name != "race"][0] == "structure"
        assert str(p).startswith(f"plan: choose (preset {name})") and name in plan.dumps(p)
    assert budgets == [4, 8, 16]


def test_an_override_replaces_the_presets_value_and_nothing_else(envs):
    t = _gold(envs["sun"])
    best = _plan(t, "best")
    assert best.ridge > 0 and best.disc_vote and len(best.line_sizes) == 2 and best.linear.nv_balance == 0
    less = _plan(t, "best", {"sampling": {"count": 1000, "validation": 500},
                                       "advanced": {"line_size": 48, "linear": {"ridge": 0, "nv_balance": 0.5},
                                                    "highlights": {"disc": False}}})
    assert (less.grid_count, less.validation, less.line_sizes, less.ridge) == (1000, 500, (48,), 0)
    assert less.linear.nv_balance == 0.5 and not less.disc_vote
    assert [v.name for v in less.votes if v.name != "race"] == ["structure", "polish"]  # no line vote, no disc vote
    assert less.candidates == best.candidates  # the candidates were not overridden
    assert _plan(t, "best", {"max_lookups": 6}).max_lookups == 6
    fewer = _plan(t, "balanced", {"advanced": {"highlights": {"terms": 0}}})
    assert fewer.candidates and not any(c.highlights.terms for c in fewer.candidates)


def test_polish_given_runs_on_every_candidate_and_the_kept_structure_gets_no_second_polish(envs):
    t = _gold(envs["interior"])
    p = _plan(t, "fast", {"advanced": {"linear": {"polish": 3}}})
    assert p.linear.polish == 3 and p.polish == 0 and "polish" not in [v.name for v in p.votes]
    off = _plan(t, "fast", {"advanced": {"linear": {"polish": 0}}})
    assert off.linear.polish == 0 and off.polish == 0
    lm = _plan(t, "fast", {"advanced": {"linear": {"method": "levenberg_marquardt"}}})
    assert lm.polish == 0  # the polish follows an ALS fit


def test_the_candidates_balance_the_nv_bins_only_where_the_brdf_has_a_diffuse_part(envs):
    env = envs["interior"]
    plastic = hf.light.lighting_target(hf.brdf.cook_torrance(kd=0.3, ks=1.0, roughness=0.6, f0=0.04), env)
    mirror = hf.light.lighting_target(hf.brdf.ggx(kd=0.0, ks=1.0, roughness=0.1, f0=0.9), env)
    brdf = hf.fit.brdf_target(hf.brdf.cook_torrance(kd=0.3, ks=1.0, roughness=0.6, f0=0.04))
    assert _plan(plastic, "balanced").linear.nv_balance == plan.PRESETS["balanced"].nv_balance > 0
    assert _plan(mirror, "balanced").linear.nv_balance == 0
    bp = _plan(brdf, "balanced")
    assert bp.parametrization == "PQP" and bp.linear.nv_balance == 0 and bp.polish == 0 and bp.ridge == 0
    assert _plan(plastic, "balanced", {"advanced": {"linear": {"nv_balance": 0.0}}}).linear.nv_balance == 0.0
    with pytest.raises(HomofacError, match="nv_balance"):
        _plan(brdf, "balanced", {"advanced": {"linear": {"nv_balance": 0.5}}})


def test_no_preset_and_no_naming_key_is_the_default_preset_and_a_named_parametrization_a_single_product(envs):
    t = _gold(envs["sun"])
    assert FitOptions().preset == DEFAULT_PRESET == "balanced"
    assert _plan(t).preset == "balanced"
    assert _plan(t, None, {"parametrization": "NR"}).mode == "product"
    assert _plan(t, None, {"terms": 2, "nv_factor": True}).mode == "sum"
    assert _plan(t, None, {"parametrization": "split_sum"}).mode == "baseline"
    # max_lookups alone keeps the settings its budget always had: the smallest preset that holds it
    assert [_plan(t, None, {"max_lookups": n}).preset for n in (3, 4, 6, 8, 12, 16, 40)] == \
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
    path.write_text("target:\n  brdf: {model: ggx, roughness: 0.3}\n  environment: {file: interior, resolution: 4}\n"
                    "preset: best\n")
    assert cli.fit_main([str(path), "--plan"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("plan: choose (preset best)") and "16 lookups" in out and "vote lines" in out
    assert not (tmp_path / "out").exists()  # nothing ran


def test_the_plan_refuses_in_one_line_before_any_compute(envs):
    t = _gold(envs["sun"])
    for bad, words in ((({"parametrization": "split_sum", "preset": "fast"}), "baseline"),
                       ({"parametrization": "NR", "terms": 2,
                         "advanced": {"linear": {"ridge": 10, "polish": 0}}}, "ridge"),
                       ({"parametrization": "PQP", "max_lookups": 4}, "PQP")):
        with pytest.raises(HomofacError, match=words) as e:
            _plan(t, None, bad)
        assert "\n" not in str(e.value)


_PARAMS = ("N", "R", "NR", "NRV", "NRHD", "NRO", "RO", "IV", "GSHD", "PQP", "NRW")


@st.composite
def _highlights(draw):
    """Valid highlights: the flags only with highlight terms, a table or the cosine line, not both."""
    terms = draw(st.integers(0, 3))
    if not terms:
        return {"terms": 0}
    table = draw(st.booleans())
    return {"terms": terms, "fresnel": draw(st.booleans()), "cosine": not table and draw(st.booleans()),
            "table": table, "disc": draw(st.booleans())}


_STRUCTURES = st.builds(lambda p, k, d, w, r, ss, rw, h: Structure(p, k, d, w, reflection=r, prefiltered=ss,
                                                                  rw_terms=rw, highlights=h),
                        st.sampled_from(_PARAMS), st.integers(1, 40), st.sampled_from([None, "exact", "fitted"]),
                        st.booleans(), st.booleans(), st.booleans(), st.integers(0, 5), _highlights())


@settings(max_examples=300, deadline=None)
@given(_STRUCTURES)
def test_a_structure_label_parses_back_to_the_structure_and_its_record_reads_back(s):
    back = Structure.parse(s.label())
    # one identity: NRW products read as NR products with the n.v factor (the same sum)
    assert back == (s.replace(parametrization="NR") if s.parametrization == "NRW" else s)
    assert back.label() == s.label()
    assert Structure.of(s.record()) == s and hash(Structure.of(s.record())) == hash(s)
    assert Structure.of(json.loads(json.dumps(s.record()))) == s  # as factorization.json holds it


def test_records_of_the_flat_layout_read_as_the_nested_structure():
    flat = {"parametrization": "RO", "terms": 3, "diffuse": "fitted", "nv_factor": True, "reflection": True,
            "prefiltered": False, "rw_terms": 0, "highlight_terms": 2, "highlight_fresnel": True,
            "highlight_cosine": False, "highlight_table": True, "highlight_disc": None}
    s = Structure.of(flat)
    assert s.label() == "E'+ROW x3+R+HFT x2" and s.highlights.terms == 2 and not s.highlights.disc
    assert Structure.of(s.record()) == s and "highlights" in s.record()


def test_an_inconsistent_structure_is_refused_in_one_line():
    for kw in ({"highlights": {"disc": True}}, {"highlights": {"terms": 1, "table": True, "cosine": True}},
               {"highlights": {"terms": 4}}, {"terms": 0}, {"diffuse": "half"}):
        with pytest.raises(HomofacError) as e:
            Structure("NR", **kw)
        assert "\n" not in str(e.value)
    with pytest.raises(HomofacError, match="parametrization"):
        Structure("XYZ")
    with pytest.raises(HomofacError, match="highlights.terms"):
        Structure("RO", highlights={"terms": 1}).with_highlights(terms=0, fresnel=True)


def test_a_structure_gives_the_keywords_that_fit_it(envs):
    s = Structure.parse("E'+NROW x2+R+HSFT x1")
    kw = s.keywords()
    assert set(kw) == {"parametrization", "terms", "diffuse", "nv_factor", "advanced"}
    p = _plan(_gold(envs["sun"]), None, kw)
    assert p.mode == "sum" and p.candidates == (s,)
    d = p.to_dict()["candidates"][0]
    assert d["label"] == s.label() and Structure.of(d["structure"]) == s and d["structure"]["highlights"]["disc"]
    assert f"structure: {s.label()} (NRO products x2" in str(p)
    assert "highlights {terms 1, fresnel, table, disc}" in str(p)
    fast = _plan(_gold(envs["sun"]), "fast")
    chosen = fast.to_dict()["candidates"]
    assert all(Structure.of(c["structure"]).label() == c["label"] for c in chosen)
    assert all(f"    {c.label()} ({c.describe()})" in str(fast).splitlines() for c in fast.candidates)


def test_research_keys_live_under_advanced_and_their_old_spellings_name_the_new_place(tmp_path, capsys):
    for key, place in (("highlight_disc", "advanced.highlights.disc"), ("linear", "advanced.linear"),
                       ("rw_terms", "advanced.rw_terms"), ("line_size", "advanced.line_size")):
        with pytest.raises(HomofacError) as e:
            parse({"target": {"brdf": GOLD}, key: 1}, "c.yaml")
        assert str(e.value) == f"c.yaml: {key} is an advanced key: write it under advanced: ({place})"
        with pytest.raises(HomofacError, match=f"{key} is an advanced key"):
            hf.fit.factorize(_gold(hf.light.sun_sky((0, 0, 1), resolution=4)), **{key: 1})
    path = tmp_path / "c.yaml"
    path.write_text("target:\n  brdf: {model: ggx, roughness: 0.3}\n  environment: {file: interior, resolution: 8}\n"
                    "highlight_terms: 1\n")
    assert cli.fit_main([str(path), "--plan"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("highlight_terms is an advanced key: write it under advanced: (advanced.highlights.terms)")
    assert err.startswith("homofac: error:") and "\n" not in err
    # the pinned keys stay at the top level; the research keys are under advanced
    top = set(FitOptions.model_fields)
    assert {"preset", "max_lookups", "terms", "diffuse", "nv_factor"} <= top
    assert not top & {"linear", "line_size", "reflection", "highlight_terms", "analysis", "baseline"}
    cfg = parse({"target": {"brdf": GOLD}, "advanced": {"highlights": {"terms": 1, "fresnel": True},
                                                        "linear": {"polish": 0}}})
    assert cfg.preset is None and cfg.is_sum and cfg.structure().label() == "NR x1+HFW x1"


def test_a_config_recorded_before_the_advanced_section_reads_in_todays_layout():
    old = {"target": {"brdf": GOLD}, "parametrization": "NR", "terms": 2, "reflection": True, "rw_terms": 0,
           "highlight_terms": 1, "highlight_fresnel": None, "highlight_disc": True, "line_size": None,
           "linear": {"iterations": 4}, "baseline": None, "analysis": None}
    cfg = parse_record(old)
    assert cfg.advanced.reflection and cfg.advanced.highlights.terms == 1 and cfg.advanced.highlights.disc
    assert cfg.advanced.linear.iterations == 4 and cfg.structure().label() == "NR x2+R+HSW x1"
    assert recorded_fit_options(old)["advanced"] == {"reflection": True, "rw_terms": 0,
                                                     "highlights": {"terms": 1, "disc": True},
                                                     "linear": {"iterations": 4}}
    assert parse_record(cfg.model_dump(mode="json")) == cfg  # today's records read as they are


def test_the_config_has_fewer_top_level_keys_than_before_and_docs_say_how_many():
    """docs/config.md counts the keys: the top level, and the keys of the reference outside and under
    ``advanced`` (without the BRDF parameters, materials, cameras and extra lights)."""
    import sys
    from homofac.app.config import Config
    root = Path(__file__).resolve().parents[1]
    sys.path.insert(0, str(root / "docs"))
    import hooks
    keys = len(Config.model_fields)
    skip = {"cameras[]", "lights[]", "materials[]"}
    sections = [(m, k) for m, k in hooks.config_sections() if not skip & set(k.split("."))]
    outside = sum(len(m.model_fields) for m, k in sections if not k.startswith("advanced"))
    under = sum(len(m.model_fields) for m, k in sections if k.startswith("advanced"))
    text = " ".join((root / "docs" / "config.md").read_text().split())
    assert keys <= 16 and f"{keys} top-level keys" in text
    assert f"there are {outside} outside `advanced` and {under} under it" in text


def test_a_string_that_is_no_label_is_refused_in_one_line():
    for bad in ("", "NR", "NR x0", "E'+XYZ x1", "E'+NRW x2+H x1", "NR x1+HSW x4", "NR x1+HFCT x1", 3):
        with pytest.raises(HomofacError) as e:
            Structure.parse(bad)
        assert "\n" not in str(e.value)


def test_the_presets_try_the_candidates_of_their_grid_directions_and_say_how_they_polish(envs):
    """A preset's candidates lie on its grid directions (one grid of training pairs to draw); a named
    parametrization's samples given decide the direction instead. The plan says on which pairs the kept
    structure is polished (every k-th), and a polish of every candidate (given) plans none."""
    t = _gold(envs["interior"])
    grid = FitOptions().sampling.model_copy(update={"kind": "grid"})
    for name, p in plan.PRESETS.items():
        got = _plan(t, name)
        dirs = {hf.fit.draw.grid_projection("lighting", c.parametrization, grid) for c in got.candidates}
        assert dirs <= set(p.directions or dirs)
        assert got.polish == p.polish and got.polish_stride == (p.polish_stride if got.polish else 1)
        assert got.to_dict()["polish_stride"] == got.polish_stride
        assert (f"every {got.polish_stride}th grid pair" in str(got)) == (got.polish_stride > 1)
    given = _plan(t, "balanced", {"advanced": {"linear": {"polish": 4}}})  # every candidate polished
    assert (given.polish, given.polish_stride) == (0, 1) and given.linear.polish == 4
    given_r = _plan(t, "fast", samples_given="r")
    assert {hf.fit.draw.grid_projection("lighting", c.parametrization, grid) for c in given_r.candidates} == {"r"}


def test_a_preset_does_not_try_its_dropped_candidates_unless_a_constraint_leaves_only_those(envs):
    """``balanced`` drops the candidates its race never keeps (plan.BALANCED_DROPPED): they are among the
    8-lookup structures of its grid direction (structures.candidates), not among its candidates (nor among
    those of ``max_lookups: 8``, which is balanced's budget); a constraint that only they meet keeps them."""
    t = _gold(envs["interior"])
    grid = FitOptions().sampling.model_copy(update={"kind": "grid"})
    every = {c.label() for c in hf.fit.structures.candidates("lighting", 8, parametrization="NR")
             if hf.fit.draw.grid_projection("lighting", c.parametrization, grid) in plan.PRESET_DIRECTIONS}
    got = {c.label() for c in _plan(t, "balanced").candidates}
    dropped = set(plan.PRESETS["balanced"].dropped)
    assert dropped and dropped <= every and got == every - dropped
    assert {c.label() for c in _plan(t, None, {"max_lookups": 8}).candidates} == got  # the 8-lookup preset's
    only = _plan(t, "balanced", {"diffuse": "fitted", "advanced": {"highlights": {"terms": 0}},
                                 "parametrization": "RO"}).candidates
    assert [c.label() for c in only] == ["E'+ROW x3+R"]


def test_a_polish_trial_that_did_not_lower_the_figure_is_summarised_as_no_polish():
    before, after = {"validation_nrmse": 0.2141}, {"validation_nrmse": 0.2143}
    note = {"steps": 8, "validation_nrmse_before": 0.2141, "validation_nrmse_after": 0.2143, "stages": [],
            "rule": "vote", "kept": False, "stage": None, "ridge": 0, "start": None,
            "trial": {"steps": 2, "falls": False, "before": before, "after": after}}
    line = cli.polish_line(note)
    assert "2-step trial" in line and "0.2141 -> 0.2143" in line and "none run" in line


def test_split_sum_candidates_only_for_models_with_a_split_sum():
    """A gltf target has no registered microfacet split sum: no candidate of any budget carries the
    ``prefiltered`` term (it failed mid-fit at max_lookups 8), while a Cook-Torrance target on the same grid
    direction is offered it."""
    env = hf.light.load_environment("forest", 4)
    gltf = hf.light.lighting_target(hf.brdf.gltf(base_color=(0.8, 0.5, 0.3), metallic=0.5, roughness=0.4), env)
    ct = hf.light.lighting_target(hf.brdf.cook_torrance(kd=(0.1, 0.1, 0.1), ks=1.0, roughness=0.3,
                                                         f0=(0.9, 0.7, 0.3)), env)
    for budget in (4, 8, 16):
        cands = _plan(gltf, None, {"max_lookups": budget}, samples_given="r").candidates
        assert cands and not any(c.prefiltered for c in cands)
    assert any(c.prefiltered for c in _plan(ct, None, {"max_lookups": 8}, samples_given="r").candidates)


def test_the_race_is_planned_where_the_preset_chooses_by_the_lowest_figure(envs):
    """A preset that races runs every candidate's first sweeps and continues only its lowest; its rounds
    lie below the linear fit's sweeps and each keeps fewer than it ranks. A ``target_error`` (the first
    candidate that meets it) or a linear fit too short for a round plans no race."""
    t = _gold(envs["interior"])
    raced = []
    for name, p in plan.PRESETS.items():
        got = _plan(t, name)
        assert ("race" in [v.name for v in got.votes]) == bool(got.race) == ("race:" in str(got))
        assert got.to_dict()["race"]["sweeps"] == list(got.race)
        left = len(got.candidates)
        for j, (sweeps, keep) in enumerate(zip(got.race, got.race_keep)):
            # below the full fit's sweeps; a first round on every k-th pair (k > 1: fits of their own) up to them
            # (a race_strided plan: every round on those pairs, a round before the last may keep all its margin admits)
            assert 0 < sweeps <= got.linear.iterations - ((j > 0 and not got.race_strided) or got.race_stride == 1)
            assert 1 <= keep < left or (got.race_strided and j + 1 < len(got.race) and keep <= left)
            left = keep
        if got.race:
            raced.append(name)
            assert _plan(t, name, {"target_error": 0.1}).race == ()
            assert _plan(t, name, {"advanced": {"linear": {"iterations": 2}}}).race == ()
    assert raced
    assert plan.race_of(plan.Preset(4, 1, 1, 0, False, False, 0.0, 0, 0, False, race=(2, 5), race_keep=(3, 1)),
                        hf.fit.options.LinearOptions(iterations=30), 3) == ((5,), (1,))  # keeping 3 of 3 is no round
    # a round of the full fit's sweeps is no round, unless it is a first round on every k-th pair (k > 1)
    whole = plan.Preset(4, 1, 1, 0, False, False, 0.0, 0, 0, False, race=(30,), race_keep=(1,))
    assert plan.race_of(whole, hf.fit.options.LinearOptions(iterations=30), 3) == ((), ())
    assert plan.race_of(whole._replace(race_stride=4), hf.fit.options.LinearOptions(iterations=30), 3) == ((30,), (1,))
    assert plan.race_of(whole._replace(race_stride=4), hf.fit.options.LinearOptions(iterations=20), 3) == ((), ())
    # a strided race (every round on every k-th pair): its later rounds may reach the full fit's sweeps, and a
    # round before the last that drops by its margin is a round even where its keep admits every candidate
    strided = whole._replace(race=(10, 30), race_keep=(5, 1), race_stride=4, race_strided=True,
                             race_margins=(0.2, 0.0))
    assert plan.race_of(strided, hf.fit.options.LinearOptions(iterations=30), 3) == ((10, 30), (3, 1))
    assert plan.race_of(strided._replace(race_strided=False), hf.fit.options.LinearOptions(iterations=30), 3) == (
        (30,), (1,))  # unstrided, a keep of 5 of 3 is no round
    assert plan.race_margins_of(strided, (10, 30)) == (0.2, 0.0)
    assert plan.race_margins_of(strided._replace(race_margins=(), race_margin=0.05), (30,)) == (0.05,)
    assert plan.race_of(strided, hf.fit.options.LinearOptions(iterations=30), 1) == ((), ())


def test_the_race_continues_the_lowest_and_those_within_its_margin_round_by_round():
    """``pipeline._race`` on candidates whose figure after k sweeps is given: each round brings the ones
    still in to its sweeps (the first on every stride-th pair), keeps the lowest and those within the margin, at most its keep,
    in the candidates' order; the record holds every round's labels, figures, sweeps run and kept."""
    figures = {"A": {3: 0.30, 8: 0.25}, "B": {3: 0.20, 8: 0.19}, "C": {3: 0.21, 8: 0.185}, "D": {3: 0.50}}
    cands = [Structure.parse(f"NROW x{k}") for k in (1, 2, 3, 4)]
    name = dict(zip(cands, "ABCD"))
    calls = []

    def to(structure, sweeps, stride):
        calls.append((name[structure], sweeps, stride))
        f = figures[name[structure]][sweeps]
        return hf.fit.Result(None, solver={"iterations": sweeps - (name[structure] == "B")},
                             metrics={"validation": {"float": {"nrmse": f}}})

    kept, note = hf.fit.pipeline._race(cands, to, (3, 8), (3, 1), 0.1, None, lambda m: None, stride=4)
    # A (0.30 > 0.22) and D out after the first round, which alone fits every 4th pair
    assert calls == [("A", 3, 4), ("B", 3, 4), ("C", 3, 4), ("D", 3, 4), ("B", 8, 1), ("C", 8, 1)]
    assert kept == [cands[2]] and note["kept"] == [cands[2].label()]
    first, second = note["rounds"]
    assert first["kept"] == [cands[1].label(), cands[2].label()] and first["validation_nrmse"] == [0.3, 0.2, 0.21, 0.5]
    assert first["ran"] == [3, 2, 3, 3] and second["sweeps"] == 8 and second["labels"] == first["kept"]
    assert note["stride"] == 4
    # a strided race with a margin per round: every round on every 4th pair; the first drops only A and D
    # (more than 30 % behind B), keeping C too though its keep would admit 4
    calls.clear()
    kept, note = hf.fit.pipeline._race(cands, to, (3, 8), (4, 1), (0.3, 0.0), None, lambda m: None, stride=4,
                                       strided=True)
    assert calls == [("A", 3, 4), ("B", 3, 4), ("C", 3, 4), ("D", 3, 4), ("B", 8, 4), ("C", 8, 4)]
    assert kept == [cands[2]] and note["strided"] and [r["margin"] for r in note["rounds"]] == [0.3, 0.0]
    assert note["rounds"][0]["kept"] == [cands[1].label(), cands[2].label()]


@pytest.mark.slow
def test_the_race_keeps_the_structure_that_full_fits_of_every_candidate_keep():
    """On a tiny fit of a racing preset held to 4 lookups (3 candidates) whose full fits differ clearly (by
    more than 10 %): the race keeps the lowest of the full fits, continued from the race to the same fit,
    records every candidate's figure after its first round, and the structure vote reads only those it kept."""
    t = _gold(hf.light.load_environment("forest", 4))
    name = next(n for n, p in plan.PRESETS.items() if p.race)
    kw = {"texture_size": 8, "max_lookups": 4, "sampling": {"count": 6000, "validation": 600},
          "advanced": {"linear": {"polish": 0}, "validation_light": 4}}
    p = plan.build_plan(t, name, kw)
    assert p.race
    full = hf.fit.execute(dataclasses.replace(p, race=(), race_keep=()), t)  # every candidate fitted in full
    assert "race" not in full.selection
    errs = sorted(r["validation_nrmse"] for r in full.selection["tried"])
    assert errs[1] > 1.1 * errs[0]
    fac = hf.fit.execute(p, t)
    assert fac.parametrization == full.parametrization
    assert fac.metrics["validation"]["float"]["nrmse"] == pytest.approx(
        full.metrics["validation"]["float"]["nrmse"], rel=1e-5)
    rec = fac.selection["race"]
    assert rec["rounds"][0]["labels"] == [c.label() for c in p.candidates]
    assert [r["label"] for r in fac.selection["tried"]] == rec["kept"]


def test_the_strided_polish_pairs_are_every_kth_view_of_the_polish_pairs_with_the_same_values(envs):
    """A strided polish's off-grid pairs (``polish_pairs(stride=k)``) are a subset of the full one's, about 1/k of
    them, each with the value the polish's draw gives it (only the subset is evaluated)."""
    t = hf.light.with_context(_gold(envs["sun"]), "NRO")
    lin = hf.fit.options.LinearOptions(polish_size=6)
    full = hf.fit.polish.polish_pairs(t, "NRO", lin, 0, False, lambda m: None)
    part = hf.fit.polish.polish_pairs(t, "NRO", lin, 0, False, lambda m: None, stride=4)
    assert 0.15 < len(part.a) / len(full.a) < 0.35 and len(part.val_a) == 0
    key = {tuple(np.round(np.concatenate([a, b]), 5)): y for a, b, y in zip(full.a, full.b, full.y)}
    got = np.array([key[tuple(np.round(np.concatenate([a, b]), 5))] for a, b in zip(part.a, part.b)])
    np.testing.assert_allclose(part.y, got, rtol=1e-4, atol=1e-6)  # float32 sums in another row packing


def test_the_polish_pairs_in_rows_of_the_grids_width_run_its_lighting_program(envs, monkeypatch):
    """The off-grid pairs of a strided polish packed at the training grid's row width (``row_width_of`` its
    flattened normals, the width ``packed`` gave it) are the same pairs with the same values, and their lighting
    compiles no program after the grid's."""
    t = hf.light.with_context(_gold(envs["sun"]), "NRO")
    lin = hf.fit.options.LinearOptions(polish_size=12)  # 28 views a normal every 4th; 8 at polish_size 6
    own = hf.fit.polish.polish_pairs(t, "NRO", lin, 0, False, lambda m: None, stride=4)
    g = hf.fit.sampling.grouped_grid("dual_paraboloid", 8, 3000, 0)
    width = hf.fit.samples.row_width_of(g.flatten().a)
    assert width == hf.fit.samples.packed(g).views.shape[1] > hf.fit.samples.QUICK_WIDTH
    # rows of 32 for groups of 28 views: 1.09x their own work, shared; for groups of 8: 2x, not shared
    assert hf.fit.polish.shared_width(np.ones((10, 28), bool), width) == width
    assert hf.fit.polish.shared_width(np.ones((10, 8), bool), width) is None
    hf.fit.samples.evaluate_grouped(t, g)
    names = []
    backend_compile = compiler.backend_compile_and_load

    def recording(backend, module, *args, **kwargs):
        names.append(str(module.operation.attributes["sym_name"]))
        return backend_compile(backend, module, *args, **kwargs)

    monkeypatch.setattr(compiler, "backend_compile_and_load", recording)
    part = hf.fit.polish.polish_pairs(t, "NRO", lin, 0, False, lambda m: None, stride=4, width=width)
    assert not [n for n in names if "eval_groups" in n], names
    np.testing.assert_array_equal(part.a, own.a)
    np.testing.assert_array_equal(part.b, own.b)
    np.testing.assert_allclose(part.y, own.y, rtol=1e-4, atol=1e-6)  # float32 sums in another row packing


def test_best_drops_the_lined_highlight_candidates_whose_table_twin_it_tries(envs):
    """``best`` (``table_twins``) drops each highlight candidate on lines (``HFW``) whose table twin (``HFT``: the same
    terms at the same lookups, a function class holding the lined one's) is among its candidates; without tables
    there is no twin and the lined candidates are tried."""
    t = _gold(envs["interior"])
    grid = FitOptions().sampling.model_copy(update={"kind": "grid"})
    every = {c.label() for c in hf.fit.structures.candidates("lighting", 16, parametrization="NR", table=True)
             if hf.fit.draw.grid_projection("lighting", c.parametrization, grid) in plan.PRESET_DIRECTIONS}
    got = {c.label() for c in _plan(t, "best").candidates}
    named = set(plan.PRESETS["best"].dropped)  # plan.BEST_DROPPED: dropped by name, not as twins
    assert named and named <= every - got and not any("HFW" in d or "HFT" in d for d in named)
    dropped = every - got - named
    assert plan.PRESETS["best"].table_twins and len(dropped) == 3
    assert all("HFW" in d and d.replace("HFW", "HFT") in got for d in dropped)
    assert not any("HFW" in c and c.replace("HFW", "HFT") in got for c in got)
    lined = {c.label() for c in _plan(t, "best", {"advanced": {"highlights": {"table": False}}}).candidates}
    assert dropped <= lined and not any("HFT" in c for c in lined)
