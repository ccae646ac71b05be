"""Never crash on a valid config (issue 41): a drawn config, at tiny sizes, either runs or is refused in
one line before any compute (the plan is built first; a refusal is a one-line HomofacError)."""

from __future__ import annotations

import functools

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import homofac as hf
from homofac.errors import HomofacError
from homofac.fit import plan

@functools.cache
def _target():
    env = hf.light.load_environment("interior", 4)
    return hf.light.lighting_target(hf.brdf.ggx(kd=0.2, ks=1.0, roughness=0.4, f0=0.04), env)


TINY = {"texture_size": 4}
TINY_LINEAR = {"iterations": 2, "inner_iterations": 5, "polish_size": 4}

configs = st.fixed_dictionaries({}, optional={
    "preset": st.sampled_from(["fast", "balanced"]),
    "parametrization": st.sampled_from(["NR", "NRO", "RO", "R", "N", "NRW", "split_sum"]),
    "mapper": st.sampled_from(["dual_paraboloid", "cube", "octahedral"]),
    "sampling": st.fixed_dictionaries({"kind": st.sampled_from(["auto", "texels", "grid", "random"])}),
    "terms": st.integers(1, 2),
    "diffuse": st.sampled_from(["exact", "fitted"]),
    "nv_factor": st.booleans(),
    "highlight_terms": st.integers(0, 1),  # advanced.highlights.terms
    "max_lookups": st.integers(2, 4),
})


def _tiny(cfg: dict) -> dict:
    """``cfg`` at tiny sizes: 4-texel textures, a few thousand pairs, two iterations."""
    s = {"size": 4, "count": 3000, "validation": 300, "cache": False, **cfg.get("sampling", {})}
    out = {**TINY, **{k: v for k, v in cfg.items() if k != "highlight_terms"}, "sampling": s}
    advanced = {"linear": TINY_LINEAR}
    if "highlight_terms" in cfg:
        advanced["highlights"] = {"terms": cfg["highlight_terms"]}
    if cfg.get("parametrization") == "split_sum" and not any(
            k in cfg for k in ("preset", "terms", "diffuse", "nv_factor", "highlight_terms", "max_lookups")):
        advanced.pop("linear")
    out["advanced"] = advanced
    return out


@pytest.mark.slow  # each drawn config compiles its fits: about 10-60 s an example
@settings(max_examples=8, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(configs)
def test_a_valid_config_runs_or_is_refused_in_one_line_before_compute(cfg):
    target = _target()
    kw = _tiny(cfg)
    try:
        the_plan = plan.build_plan(target, None, kw)
    except HomofacError as e:
        assert "\n" not in str(e)
        return
    fac = hf.fit.execute(the_plan, target)
    assert fac.metrics["validation"]["float"]["nrmse"] >= 0
