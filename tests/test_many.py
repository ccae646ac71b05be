"""Material libraries (issue 15): one layout, many right-hand sides; each result equals its own full run."""

from __future__ import annotations

import numpy as np
import pytest

import homofac as hf
from homofac.errors import HomofacError

KW = dict(texture_size=16, sampling={"kind": "texels", "size": 8, "validation": 2000, "cache": False})


@pytest.fixture(scope="module")
def env():
    return hf.light.load_environment("forest", resolution=8)


def _close(a: dict, b: dict, tol: float = 0.01):
    for split in b:
        for kind in b[split]:
            for name, y in b[split][kind].items():
                assert abs(a[split][kind][name] - y) <= tol * max(abs(y), 1e-12), (split, kind, name, a[split][kind][name], y)


@pytest.mark.slow
def test_library_equals_full_runs(env):
    brdfs = [hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34)),
             hf.brdf.cook_torrance(kd=(0.3, 0.1, 0.1), ks=0.5, roughness=0.3, f0=(0.04, 0.04, 0.04)),  # same shape
             hf.brdf.cook_torrance(kd=0.0, ks=1.0, roughness=0.55, f0=(0.95, 0.64, 0.54)),
             hf.brdf.phong(kd=0.1, ks=0.5, exponent=30.0),
             hf.brdf.lambert(kd=(0.8, 0.5, 0.3))]
    targets = [hf.light.lighting_target(b, env) for b in brdfs]
    logs = []
    lib = hf.fit.factorize_many(targets, "NR", log=logs.append, **KW)
    assert len(lib) == len(targets)
    assert any("3 materials (2 lobe shapes)" in m for m in logs), logs  # the two Cook-Torrance shapes shared
    for t, r in zip(targets, lib):
        full = hf.fit.factorize(t, "NR", **KW)
        _close(r.metrics, full.metrics)
        assert r.counts["library"] == len(targets)
        assert r.target is t
    # every result can be refitted on the shared layout
    again = hf.fit.refit(lib[2], environment=hf.light.load_environment("city", resolution=8))
    assert again.metrics["validation"]["float"]["nrmse"] > 0


@pytest.mark.slow
def test_library_of_sums_fits_each_target(env):
    kw = dict(texture_size=8, terms=1, diffuse="exact", advanced={"linear": {"iterations": 4}},
              sampling={"count": 4000, "validation": 500, "cache": False})
    brdfs = [hf.brdf.cook_torrance(roughness=r) for r in (0.3, 0.5)]
    targets = [hf.light.lighting_target(b, env) for b in brdfs]
    lib = hf.fit.factorize_many(targets, "NR", **kw)
    for t, r in zip(targets, lib):
        _close(r.metrics, hf.fit.factorize(t, "NR", **kw).metrics)
    np.testing.assert_array_equal(lib[0].state.train.a, lib[1].state.train.a)  # one layout


def test_library_refuses_bad_input(env):
    t = hf.light.lighting_target(hf.brdf.cook_torrance(), env)
    with pytest.raises(HomofacError, match="at least one"):
        hf.fit.factorize_many([], "NR")
    with pytest.raises(HomofacError, match="one kind"):
        hf.fit.factorize_many([t, hf.fit.brdf_target(hf.brdf.cook_torrance())], "NR")
    with pytest.raises(HomofacError, match="per target"):
        hf.fit.factorize_many([t], "NR", config={})
    with pytest.raises(HomofacError, match="texture_sise"):
        hf.fit.factorize_many([t], "NR", texture_sise=8)
    with pytest.raises(HomofacError, match="not a homofac Target"):
        hf.fit.factorize_many([t, "gold"], "NR")


@pytest.mark.slow
def test_measure_many_equals_measure_per_result(env):
    """The library's one vmapped measurement (:func:`homofac.fit.footprints.measure_many`) gives every
    result the metrics :func:`homofac.fit.footprints.measure` gives it alone (float and 8-bit, both splits)."""
    from homofac.fit import footprints as fp

    targets = [hf.light.lighting_target(hf.brdf.cook_torrance(roughness=0.3, f0=c), env)
               for c in ((1.0, 0.78, 0.34), (0.04, 0.04, 0.04), (0.95, 0.64, 0.54))]
    kw = dict(texture_size=8, sampling={"kind": "texels", "size": 6, "validation": 500, "cache": False})
    lib = hf.fit.factorize_many(targets, "NR", keep_samples=True, **kw)
    s0 = lib[0].samples
    train, val = fp.footprints(lib[0].model, s0.a, s0.b), fp.footprints(lib[0].model, s0.val_a, s0.val_b)
    many = fp.measure_many(lib, targets, [r.samples for r in lib], train, val)
    assert len({r.metrics["validation"]["float"]["nrmse"] for r in lib}) == 3  # three different fits
    for r, t, m in zip(lib, targets, many):
        one = fp.measure(r, t, r.samples, train, val)
        for split in one:
            for kind in one[split]:
                for name, y in one[split][kind].items():
                    assert m[split][kind][name] == pytest.approx(y, rel=1e-5, abs=1e-9), (split, kind, name)
        _close(r.metrics, one, tol=1e-5)
