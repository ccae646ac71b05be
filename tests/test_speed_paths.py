"""Speed paths of issue 5 and their correctness: the sample cache (hits, and invalidation when any
input changes), target_error's choice, and sharded sampling equal to unsharded."""

from __future__ import annotations

import equinox as eqx
import numpy as np
import pytest

import homofac as hf
from homofac.fit.options import SamplingOptions
from homofac.fit import cache, pipeline
from homofac.app.run import build_target, run
from homofac.target import brdf_target

SAMPLING = {"kind": "texels", "size": 6, "validation": 300, "seed": 0}


def _lighting(roughness=0.3, env=None):
    env = env if env is not None else hf.light.load_environment("forest", resolution=4)
    return hf.light.lighting_target(hf.brdf.cook_torrance(roughness=roughness), env)


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("HOMOFAC_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


def test_cache_hit_returns_the_same_samples_and_skips_sampling(cache_dir):
    t = _lighting()
    logs = []
    first = pipeline.draw_samples(t, "NR", SAMPLING, log=logs.append)
    assert len(list(cache_dir.glob("*.npz"))) == 1
    assert not any("from cache" in m for m in logs)
    logs.clear()
    again = pipeline.draw_samples(t, "NRV", SAMPLING, log=logs.append)  # another parametrization: same samples
    assert any("from cache" in m for m in logs)
    for x, y in zip(first, again):
        np.testing.assert_array_equal(x, y)
    # a fresh but equal target (same file, same parameters) has the same key
    assert cache.key(_lighting(), SamplingOptions(**SAMPLING).model_dump(), "NR") == cache.key(
        t, SamplingOptions(**SAMPLING).model_dump(), "NR")


def test_cache_is_invalidated_by_every_input(cache_dir):
    s = SamplingOptions(**SAMPLING).model_dump()
    env = hf.light.load_environment("forest", resolution=4)
    base = cache.key(_lighting(env=env), s, "NR")
    assert base is not None
    brighter = eqx.tree_at(lambda e: e.radiance, env, env.radiance.at[3, 1].multiply(1.001))
    changed = {
        "roughness": cache.key(_lighting(roughness=0.31, env=env), s, "NR"),
        "one environment pixel": cache.key(_lighting(env=brighter), s, "NR"),
        "light resolution": cache.key(_lighting(env=hf.light.load_environment("forest", resolution=5)), s, "NR"),
        "sampling size": cache.key(_lighting(env=env), {**s, "size": 7}, "NR"),
        "validation seed": cache.key(_lighting(env=env), {**s, "seed": 1}, "NR"),
        "brdf model": cache.key(hf.light.lighting_target(hf.brdf.ggx(), env), s, "NR"),
    }
    for what, k in changed.items():
        assert k is not None and k != base, what
    assert cache.key(_lighting(env=env), {**s, "cache": False}, "NR") == base  # the switch is not an input
    assert cache.key(_lighting(env=env), s, "NRHD") == base  # lighting samples do not depend on it
    bt = brdf_target(hf.brdf.cook_torrance())
    assert cache.key(bt, s, "PQP") != cache.key(bt, s, "IV")  # BRDF texel iterators do


def test_uncacheable_targets_and_damaged_entries(cache_dir):
    t = brdf_target(lambda wi, wo: wi * 0 + 1.0)  # a plain function: no stable fingerprint
    assert cache.key(t, SamplingOptions(**SAMPLING).model_dump(), "PQP") is None
    lt = _lighting()
    k = cache.key(lt, SamplingOptions(**SAMPLING).model_dump(), "NR")
    cache_dir.mkdir(parents=True)
    (cache_dir / f"{k}.npz").write_bytes(b"not an npz")  # a damaged entry is resampled and replaced whole
    s = pipeline.draw_samples(lt, "NR", SAMPLING, log=lambda m: None)
    assert cache.load(k) is not None and len(cache.load(k).a) == len(s.a)


@pytest.mark.slow
def test_refit_from_cache_gives_the_same_factorization(cache_dir):
    t = _lighting()
    f1 = pipeline.factorize(t, "NR", texture_size=8, sampling=SAMPLING)
    f2 = pipeline.factorize(t, "NR", texture_size=8, sampling=SAMPLING)
    assert f2.timings["sample_s"] < f1.timings["sample_s"]
    for a, b in zip(f1.textures, f2.textures):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.slow
def test_target_error_picks_the_cheapest_candidate_that_meets_it(cache_dir):
    from homofac.fit import auto

    env = hf.light.load_environment("forest", resolution=4)
    t = hf.light.lighting_target(hf.brdf.phong(kd=0.3, ks=0.5, exponent=8.0), env)
    sampling = {"kind": "texels", "size": 6, "validation": 1000, "seed": 4}
    cands = auto.candidates("lighting", "cube", 16)
    assert [c["cost"] for c in cands] == sorted(c["cost"] for c in cands)
    samples = pipeline.draw_samples(t, "NR", sampling, log=lambda m: None)
    # Measured here: N 8 0.35, R 8 0.46, NR 8 0.16, NRV 8 0.17, N 16 0.35, R 16 0.46, NRHD 8 0.10.
    # A loose target is met by a cheap candidate, a stricter one needs a costlier one; both keep the
    # promise on the validation set.
    costs = {}
    for goal in (0.25, 0.13):
        fac = pipeline.factorize(t, target_error=goal, mapper="cube", texture_size=16, sampling=sampling, samples=samples)
        sel = fac.selection
        assert sel["met"], sel
        assert fac.metrics["validation"]["float"]["nrmse"] <= goal
        assert sel["chosen"] == {"parametrization": fac.parametrization, "texture_size": fac.texture_size}
        assert all(not c["met"] for c in sel["tried"][:-1]) and sel["tried"][-1]["met"]
        costs[goal] = sel["tried"][-1]["cost"]
    assert costs[0.13] > costs[0.25]
    # an impossible target returns the best tried, with a warning saying so
    fac = pipeline.factorize(t, target_error=1e-6, mapper="cube", texture_size=8, sampling=sampling, samples=samples)
    assert not fac.selection["met"] and any("no candidate" in w for w in fac.warnings)
    best = min(c["validation_nrmse"] for c in fac.selection["tried"])
    assert fac.metrics["validation"]["float"]["nrmse"] == pytest.approx(best)


@pytest.mark.slow
def test_target_error_from_the_cli_records_its_choice(cache_dir, tmp_path):
    import json

    import yaml

    from homofac.app.cli import fit_main as main

    cfg = {
        "target": {"kind": "lighting", "brdf": {"model": "lambert", "kd": 0.8},
                   "environment": {"file": "forest", "resolution": 4}},
        "mapper": "cube", "texture_size": 8, "target_error": 0.05,
        "sampling": {"kind": "texels", "size": 6, "validation": 500},
        "output": {"dir": "out", "preview": False, "samples": False},
    }
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(cfg))
    assert main([str(path), "--quiet"]) == 0
    doc = json.loads((tmp_path / "out" / "factorization.json").read_text())
    sel = doc["selection"]
    assert sel["met"] and doc["metrics"]["validation"]["float"]["nrmse"] <= 0.05
    # Lambert lighting depends on n only: the one-texture N is the cheapest that meets it
    assert doc["parametrization"] == sel["chosen"]["parametrization"] == "N"


SHARD_SCRIPT = r"""
import json, sys
import numpy as np
import jax
import homofac as hf
from homofac.fit import pipeline
env = hf.light.load_environment("forest", resolution=4)
t = hf.light.lighting_target(hf.brdf.cook_torrance(), env)
s = pipeline.draw_samples(t, "NR", {"kind": "texels", "size": 7, "validation": 301, "cache": False}, log=lambda m: None)
np.savez(sys.argv[1], y=s.y, val_y=s.val_y, a=s.a)
print(json.dumps({"devices": jax.device_count()}))
"""


@pytest.mark.slow
def test_sharded_sampling_equals_unsharded(tmp_path):
    """Sampling with the normals split over 2 (forced CPU) devices gives the unsharded values."""
    import json
    import os
    import subprocess
    import sys

    out = {}
    for n in (1, 2):
        flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={n}".strip()
        env = {**os.environ, "XLA_FLAGS": flags}
        r = subprocess.run([sys.executable, "-c", SHARD_SCRIPT, str(tmp_path / f"{n}.npz")], env=env,
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr[-2000:]
        assert json.loads(r.stdout.strip().splitlines()[-1])["devices"] == n
        out[n] = np.load(tmp_path / f"{n}.npz")
    np.testing.assert_array_equal(out[1]["a"], out[2]["a"])
    for k in ("y", "val_y"):
        assert out[1][k].shape == out[2][k].shape and len(out[1][k]) > 0
        # equal up to float32 rounding: split over devices, a batch is cut at other places, and XLA CPU
        # evaluates exp / pow in vector code with a scalar remainder loop, so a value computed on the other
        # path moves by a few float32 ulps of its terms (seen: 4e-6 relative on 6 of 8214 values); a shard
        # lost, repeated or out of order moves values by O(1)
        np.testing.assert_allclose(out[2][k], out[1][k], rtol=2e-5, atol=1e-6)


@pytest.mark.slow
def test_light_culling_from_the_config_is_recorded_and_bounded(cache_dir, tmp_path):
    """target.environment.cull drops the weakest lights; factorization.json records what was dropped, and the
    samples differ from the unculled ones by at most max f x dropped power (Lambert: kd/pi)."""
    from homofac.app import config as cfgmod

    def cfg(cull):
        return cfgmod.parse({
            "target": {"kind": "lighting", "brdf": {"model": "lambert", "kd": 0.8},
                       "environment": {"file": "studio", "resolution": 8, **({"cull": cull} if cull else {})}},
            "mapper": "cube", "texture_size": 8, "parametrization": "N",
            "sampling": {"kind": "texels", "size": 6, "validation": 300},
            "output": {"preview": False},
        })

    full, _ = build_target(cfg(None), tmp_path)
    culled, info = build_target(cfg(1e-3), tmp_path)
    c = info["environment"]["culling"]
    assert c["dropped"] > 0 and c["kept"] == culled.fn.env.directions.shape[0]
    s_full = pipeline.draw_samples(full, "N", {"size": 6, "validation": 300}, log=lambda m: None)
    s_cull = pipeline.draw_samples(culled, "N", {"size": 6, "validation": 300}, log=lambda m: None)
    bound = 0.8 / np.pi * np.asarray(c["dropped_power"])
    diff = s_full.y - s_cull.y
    assert np.all(diff >= -1e-6) and np.all(diff <= bound + 1e-6)
    fac, out = run(cfg(1e-3), tmp_path, str(tmp_path / "out"))
    import json

    doc = json.loads((out / "factorization.json").read_text())
    assert doc["target"]["environment"]["culling"]["dropped"] == c["dropped"]


@pytest.mark.slow
@pytest.mark.parametrize("model", ["phong", "blinn_phong", "modified_phong"])
def test_lobe_culling_stays_under_its_bound(model, monkeypatch):
    """Sampling with lobe culling differs from the full sum by at most the stated bound
    delta x sum_m |colour_m| peak_m x E(n), never upwards; too few slots are detected and rerun."""
    from homofac.fit import sampling
    from homofac.fit.samples import evaluate_grouped
    from homofac.light.lighting import Lighting

    env = hf.light.load_environment("studio", resolution=8)
    b = hf.brdf.make(model, kd=0.05, ks=0.5, exponent=300.0)
    full = hf.light.lighting_target(b, env)
    cul = hf.light.lighting_target(b, env, lobe_tolerance=1e-4)
    assert cul.fn.culls_lobes and not full.fn.culls_lobes
    g = sampling.grouped_pairs("texels", 8, mapper="dual_paraboloid")
    y_full = np.asarray(evaluate_grouped(full, g))
    y_cul = np.asarray(evaluate_grouped(cul, g))
    bound = np.broadcast_to(np.asarray(cul.fn.lobe_bound(g.normals))[:, None, :], g.mask.shape + (3,))[g.mask]
    diff = y_full - y_cul
    assert np.all(diff >= -1e-5 * y_full.max()) and np.all(diff <= bound + 1e-5 * y_full.max())
    assert np.abs(diff).max() > 0  # something was culled
    # a first guess of 4 slots is too small here: detected and rerun with enough, same values
    monkeypatch.setattr(Lighting, "lobe_slots", lambda self: 4)
    np.testing.assert_allclose(np.asarray(evaluate_grouped(cul, g)), y_cul, rtol=1e-5, atol=1e-7)


def test_lobe_culling_is_refused_where_it_has_no_support():
    env = hf.light.load_environment("studio", resolution=4)
    t = hf.light.lighting_target(hf.brdf.cook_torrance(), env, lobe_tolerance=1e-4)
    assert not t.fn.culls_lobes  # microfacet lobes: no support cone, the full sum is used
    with pytest.raises(hf.HomofacError, match="lobe_cull"):
        hf.light.lighting_target(hf.brdf.phong(), env, lobe_tolerance=2.0)


def test_unwritable_cache_never_fails_a_run(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    monkeypatch.setenv("HOMOFAC_CACHE_DIR", str(blocker / "cache"))  # parent is a file: mkdir fails
    s = pipeline.draw_samples(_lighting(), "NR", SAMPLING, log=lambda m: None)
    assert len(s.a) > 0 and blocker.read_text() == "x"
