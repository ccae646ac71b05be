"""The NumPy baseline of the benchmarks computes the same lighting as homofac (so its speed ratio is fair)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import homofac as hf
from homofac.fit import sampling

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
import baseline_numpy as bn  # noqa: E402


def test_numpy_baseline_equals_homofac_lighting_on_point_lights():
    env = bn.delta_env(hf.light.load_environment("forest", resolution=4))  # centre-sampled cosines, as NumPy
    brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    pairs = sampling.grouped_pairs("texels", 6, mapper="dual_paraboloid").flatten()
    want = np.asarray(hf.light.lighting(brdf, env, pairs.a, pairs.b), np.float64)
    power = np.asarray(env.radiance * env.solid_angle[:, None], np.float64)
    got = bn.lighting(bn.numpy_brdf(brdf), np.asarray(env.directions, np.float64), power,
                      pairs.a.astype(np.float64), pairs.b.astype(np.float64))
    assert want.shape == got.shape and np.all(want >= 0) and want.max() > 0
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6 * want.max())
