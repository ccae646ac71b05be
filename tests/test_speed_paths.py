"""Speed paths of issue 5 and their correctness: the sample cache (hits, and invalidation when any
input changes), target_error's choice, and sharded sampling equal to unsharded."""

from __future__ import annotations

import equinox as eqx
import numpy as np
import pytest

import homofac as hf
from homofac.fit import cache, pipeline
from homofac.fit.target import brdf_target

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
    assert cache.key(_lighting(), {**pipeline.DEFAULT_SAMPLING, **SAMPLING}, "NR") == cache.key(
        t, {**pipeline.DEFAULT_SAMPLING, **SAMPLING}, "NR")


def test_cache_is_invalidated_by_every_input(cache_dir):
    s = {**pipeline.DEFAULT_SAMPLING, **SAMPLING}
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
    assert cache.key(t, {**pipeline.DEFAULT_SAMPLING, **SAMPLING}, "PQP") is None
    lt = _lighting()
    k = cache.key(lt, {**pipeline.DEFAULT_SAMPLING, **SAMPLING}, "NR")
    cache_dir.mkdir(parents=True)
    (cache_dir / f"{k}.npz").write_bytes(b"not an npz")  # a damaged entry is resampled and replaced whole
    s = pipeline.draw_samples(lt, "NR", SAMPLING, log=lambda m: None)
    assert cache.load(k) is not None and len(cache.load(k).a) == len(s.a)


def test_refit_from_cache_gives_the_same_factorization(cache_dir):
    t = _lighting()
    f1 = pipeline.factorize(t, "NR", texture_size=8, sampling=SAMPLING)
    f2 = pipeline.factorize(t, "NR", texture_size=8, sampling=SAMPLING)
    assert f2.timings["sample_s"] < f1.timings["sample_s"]
    for a, b in zip(f1.textures, f2.textures):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
