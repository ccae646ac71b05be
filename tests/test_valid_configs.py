"""Never crash on a valid config (issue 41): a drawn config, at tiny sizes, either runs or is refused in
one line before any compute (the plan is built first; a refusal is a one-line HomofacError).

The values are drawn from the registries, so a new preset, parametrization, baseline, mapper or sampling
kind is drawn too: every preset, every lighting parametrization and baseline, every texture mapper (the
BRDF-only ones must be refused), every sampling kind but ``scene`` (which needs a mesh and cameras;
tests/test_scene.py), and every structure key of a sum. Two tests share the draw:

- the plan of 300 drawn configs (no fit: building a plan reads the options and the target), each
  built or refused in one line. It covers every value of every key and every plan mode (about 11 s of CPU,
  of which about 7 s the one validation-light decision its chooser plans share: fit/validation.py).
- the execution of 8 drawn configs (slow: each compiles its fits, 10-60 s), each of which must run once
  its plan is built: a valid config refused after compute, or crashing, fails it. It draws the keys a
  user sets and the presets ``fast`` and ``balanced`` (see RUN_KEYS): ``best`` and the research keys
  are planned, not run, here.
"""

from __future__ import annotations

import functools
import typing

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import homofac as hf
from homofac import baselines
from homofac.errors import HomofacError
from homofac.fit import plan
from homofac.fit.options import PresetName, SamplingOptions
from homofac.param import mappers
from homofac.param import parametrizations as pz


@functools.cache
def _target():
    env = hf.light.load_environment("interior", 4)
    return hf.light.lighting_target(hf.brdf.ggx(kd=0.2, ks=1.0, roughness=0.4, f0=0.04), env)


TINY_LINEAR = {"iterations": 2, "inner_iterations": 5, "polish_size": 4}
#: The drawn keys that live under ``advanced:`` and their place there (the draw names them flat).
ADVANCED = {"reflection": ("reflection",), "prefiltered": ("prefiltered",), "rw_terms": ("rw_terms",),
            "line_size": ("line_size",), "highlight_terms": ("highlights", "terms"),
            "highlight_fresnel": ("highlights", "fresnel"), "highlight_cosine": ("highlights", "cosine"),
            "highlight_table": ("highlights", "table"), "highlight_disc": ("highlights", "disc")}
PRESETS = list(typing.get_args(PresetName))
PARAMETRIZATIONS = [n for n in pz.names() if pz.get(n).kind == "lighting"] + list(baselines.BASELINES)
MAPPERS = [n for n, m in mappers.MAPPERS.items() if not m.scalar]
KINDS = [k for k in typing.get_args(SamplingOptions.model_fields["kind"].annotation) if k != "scene"]


def configs(presets=PRESETS, keys=None):
    """Configs drawing each key or leaving it out; ``keys``: only those (all when None)."""
    options = {
        "preset": st.sampled_from(presets),
        "parametrization": st.sampled_from(PARAMETRIZATIONS),
        "mapper": st.sampled_from(MAPPERS),
        "sampling": st.fixed_dictionaries({"kind": st.sampled_from(KINDS)}),
        "terms": st.integers(1, 2),
        "diffuse": st.sampled_from(["exact", "fitted"]),
        "nv_factor": st.booleans(),
        "reflection": st.booleans(),
        "prefiltered": st.booleans(),
        "rw_terms": st.integers(0, 1),
        "highlight_terms": st.integers(0, 1),
        "highlight_fresnel": st.booleans(),
        "highlight_cosine": st.booleans(),
        "highlight_table": st.booleans(),
        "highlight_disc": st.booleans(),
        "max_lookups": st.integers(2, 4),
        "line_size": st.sampled_from([8, 16]),
        "target_error": st.sampled_from([0.05, 0.5]),
    }
    return st.fixed_dictionaries({}, optional={k: v for k, v in options.items() if keys is None or k in keys})


#: What the execution test draws: the keys a user sets (the research keys are planned above), and the
#: presets whose tiny fits take seconds (``best``'s 16-lookup candidates take minutes even at 4 texels).
RUN_KEYS = ("preset", "parametrization", "mapper", "sampling", "terms", "diffuse", "nv_factor",
            "highlight_terms", "max_lookups")


#: Keys that make a fitted sum (or name its preset): without them a named parametrization is a single
#: log-space product (or a baseline, or target_error's ladder of products), which takes no ``linear``.
SUM_KEYS = ("preset", "terms", "diffuse", "nv_factor", "reflection", "prefiltered", "rw_terms", "highlight_terms",
            "highlight_fresnel", "highlight_cosine", "highlight_table", "highlight_disc", "max_lookups", "line_size")


def _tiny(cfg: dict) -> dict:
    """``cfg`` at tiny sizes: 4-texel textures, a few thousand pairs, two iterations."""
    s = {"size": 4, "count": 3000, "validation": 300, "cache": False, **cfg.get("sampling", {})}
    out = {"texture_size": 4, "sampling": s}
    advanced: dict = {"linear": dict(TINY_LINEAR)}
    for key, value in cfg.items():
        place = ADVANCED.get(key)
        if key == "sampling":
            continue
        if place is None:
            out[key] = value
        elif len(place) == 1:
            advanced[place[0]] = value
        else:
            advanced.setdefault(place[0], {})[place[1]] = value
    if "parametrization" in cfg and not any(k in cfg for k in SUM_KEYS):
        advanced.pop("linear")
    out["advanced"] = advanced
    return out


def _plan(cfg: dict):
    """The plan of ``cfg`` at tiny sizes, or None when it is refused (in one line)."""
    try:
        return plan.build_plan(_target(), None, _tiny(cfg))
    except HomofacError as e:
        assert "\n" not in str(e), str(e)
        return None


#: Every key, or only the keys of a single product, a baseline or target_error's ladder (with every key
#: drawn almost every config names a sum; 300 examples plan every mode: product, baseline, auto, sum, choose).
ANY_CONFIG = st.one_of(configs(), configs(keys=("parametrization", "mapper", "sampling", "target_error")))


@settings(max_examples=300, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(ANY_CONFIG)
def test_a_valid_config_is_planned_or_refused_in_one_line(cfg):
    the_plan = _plan(cfg)
    if the_plan is not None:
        assert the_plan.texture_size == 4 and str(the_plan)  # a plan prints (what --plan shows)


@pytest.mark.slow  # each drawn config compiles its fits: about 10-60 s an example
@settings(max_examples=8, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(configs(presets=["fast", "balanced"], keys=RUN_KEYS))
def test_a_valid_config_runs_or_is_refused_in_one_line_before_compute(cfg):
    the_plan = _plan(cfg)
    if the_plan is None:
        return
    fac = hf.fit.execute(the_plan, _target())
    assert fac.metrics["validation"]["float"]["nrmse"] >= 0
