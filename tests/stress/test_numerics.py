"""float32 against float64 on the same problems; degenerate sampling; solver non-convergence is
reported (factorization.json and console), never silent."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest
import yaml

import homofac as hf
from homofac.fit import pipeline
from homofac.target import brdf_target

GOLD = dict(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
SMALL = {"kind": "texels", "size": 8, "validation": 500, "seed": 0, "cache": False}


def _run(dtype_x64: bool):
    jax.config.update("jax_enable_x64", dtype_x64)
    try:
        env = hf.light.sun_sky(sun_direction=(0.3, 0.2, 0.9), sun_radiance=1e4, sky=0.1, resolution=6)
        target = hf.light.lighting_target(hf.brdf.cook_torrance(**GOLD), env)
        s = pipeline.draw_samples(target, "NR", SMALL, log=lambda m: None)
        fac = pipeline.factorize(target, "NR", mapper="cube", texture_size=8, samples=s,
                                 solver={"tolerance": 1e-7, "max_iterations": 3000})
        return s, fac
    finally:
        jax.config.update("jax_enable_x64", False)


@pytest.mark.slow
def test_float32_matches_float64():
    """Tolerances, and why: the lighting sum adds ~1000 positive terms of very different size (sun 1e5 x sky);
    float32 (eps 6e-8) accumulates to ~1e-6 relative per sample, asserted 1e-4. The log-space solve is
    conditioned ~1e2-1e3 (Laplacian lambda = 1), so textures agree to ~1e-4 relative, asserted 2e-3;
    the validation nrmse (the number a user reads) to 1e-3 relative."""
    s32, f32 = _run(False)
    s64, f64 = _run(True)
    assert s32.y.dtype == np.float32
    np.testing.assert_allclose(s32.y, s64.y, rtol=1e-4, atol=1e-6 * float(np.abs(s64.y).max()))
    for a, b in zip(f32.textures, f64.textures):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=2e-3, atol=2e-4)
    e32 = f32.metrics["validation"]["float"]["nrmse"]
    e64 = f64.metrics["validation"]["float"]["nrmse"]
    assert abs(e32 - e64) <= 1e-3 * e64


@pytest.mark.slow
def test_all_samples_on_one_texel():
    """Every training pair the same: the system is one row repeated; the Laplacian and the start fill
    every texel, the result is finite, and the training error there is ~0."""
    t = brdf_target(hf.brdf.cook_torrance(kd=0.1, ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34)))
    s = pipeline.draw_samples(t, "PQP", SMALL, log=lambda m: None)
    k = len(s.a) // 2
    one = s._replace(a=np.repeat(s.a[k:k + 1], 50, 0), b=np.repeat(s.b[k:k + 1], 50, 0), y=np.repeat(s.y[k:k + 1], 50, 0))
    fac = pipeline.factorize(t, "PQP", mapper="parabolic", texture_size=8, samples=one)
    assert all(np.all(np.isfinite(np.asarray(x))) for x in fac.textures)
    assert fac.metrics["train"]["float"]["avg_rel"] < 1e-3
    assert np.isfinite(fac.metrics["validation"]["float"]["nrmse"])


@pytest.mark.slow
def test_far_fewer_samples_than_texels():
    t = brdf_target(hf.brdf.cook_torrance(kd=0.1, ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34)))
    fac = pipeline.factorize(t, "PQP", mapper="parabolic", texture_size=32,
                             sampling={"kind": "random", "count": 40, "validation": 500, "cache": False})
    assert fac.counts["train"] == 40 and fac.counts["unknowns"] > 40 * 10
    assert all(np.all(np.isfinite(np.asarray(x))) for x in fac.textures)
    assert all(np.isfinite(v) for v in fac.metrics["validation"]["float"].values())


def test_non_convergence_is_reported(tmp_path, capsys):
    from homofac.app.cli import fit_main as main

    cfg = {
        "target": {"kind": "brdf", "brdf": {"model": "cook_torrance", "kd": 0.1, "ks": 1.0, "roughness": 0.3}},
        "parametrization": "PQP", "mapper": "parabolic", "texture_size": 8,
        "sampling": {"kind": "texels", "size": 8, "validation": 200},
        "solver": {"max_iterations": 2, "tolerance": 1e-9},
        "output": {"dir": "out", "preview": False, "samples": False},
    }
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    assert main([str(tmp_path / "c.yaml"), "--quiet"]) == 0
    out, err = capsys.readouterr()
    assert "NOT converged" in out
    assert "homofac: warning: solver lsmr did not converge in 2 iterations" in err
    doc = json.loads((tmp_path / "out" / "factorization.json").read_text())
    assert doc["solver"]["converged"] is False and doc["solver"]["iterations"] == 2
    assert any("did not converge" in w for w in doc["warnings"])
    assert all(np.isfinite(v) for v in doc["metrics"]["validation"]["float"].values())


@pytest.mark.parametrize("method", ["qmr", "cg", "optimistix"])
def test_non_convergence_of_every_iterative_solver_is_reported(method):
    t = brdf_target(hf.brdf.cook_torrance(kd=0.1, ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34)))
    fac = pipeline.factorize(t, "PQP", mapper="parabolic", texture_size=8, sampling=SMALL,
                             solver={"method": method, "max_iterations": 1, "tolerance": 1e-12})
    assert fac.solver["converged"] is False and fac.warnings
    assert all(np.all(np.isfinite(np.asarray(x))) for x in fac.textures)


def test_metrics_of_huge_values_do_not_overflow():
    """One environment pixel of 1e30 turned every rms and nrmse inf (null in factorization.json): float32
    squares overflow at 1.8e19. The reported metrics accumulate in float64, the jitted ones square scaled
    values; both equal a float64 reference."""
    rng = np.random.default_rng(3)
    e = (rng.uniform(0.5, 2.0, (500, 3)) * 1e30).astype(np.float32)
    a = (e * rng.uniform(0.9, 1.1, (500, 3))).astype(np.float32)
    e64, a64 = e.astype(np.float64), a.astype(np.float64)
    want_nrmse = np.mean(np.linalg.norm(a64 - e64, axis=0) / np.linalg.norm(e64, axis=0))
    want_rms = np.mean(np.sqrt(np.mean((a64 - e64) ** 2, axis=0)))
    got = hf.fit.metrics.metrics(a, e)
    assert got["nrmse"] == pytest.approx(want_nrmse, rel=1e-12) and got["rms"] == pytest.approx(want_rms, rel=1e-12)
    jitted = {k: float(v) for k, v in hf.fit.metrics.metric_arrays(a, e).items()}
    assert jitted["nrmse"] == pytest.approx(want_nrmse, rel=1e-5) and jitted["rms"] == pytest.approx(want_rms, rel=1e-5)
    # ordinary values: unchanged by the scaling
    small = hf.fit.metrics.metrics(a64 * 1e-30, e64 * 1e-30)
    assert small["nrmse"] == pytest.approx(want_nrmse, rel=1e-9)
