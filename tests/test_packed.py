"""The grouped lighting's packing (homofac.fit.samples.packed): the same pairs, values and order in rows
of one compiled width."""

from __future__ import annotations

import numpy as np

import homofac as hf
from homofac.fit import sampling
from homofac.fit.samples import evaluate_grouped, packed
from homofac.target import evaluate


def test_packed_rows_hold_the_same_pairs_in_the_same_order_and_give_the_same_values():
    g = sampling.grouped_grid("dual_paraboloid", 8, 3000, 0)
    p = packed(g)
    width = p.views.shape[1]
    assert width & (width - 1) == 0 and width < g.views.shape[1]  # a power of 2, narrower than the largest group
    assert p.mask.sum() == g.mask.sum() and p.mask.mean() > g.mask.mean()  # less padding
    for x, y in zip(g.flatten(), p.flatten()):
        np.testing.assert_array_equal(x, y)
    brdf = hf.brdf.cook_torrance(kd=0.2, ks=1.0, roughness=0.3, f0=0.5)
    target = hf.light.lighting_target(brdf, hf.light.load_environment("forest", 4))
    grouped = np.asarray(evaluate_grouped(target, g))
    pairs = g.flatten()
    pick = np.random.default_rng(0).choice(len(pairs.a), 300, replace=False)
    direct = np.asarray(evaluate(target, pairs.a[pick], pairs.b[pick]))
    np.testing.assert_allclose(grouped[pick], direct, rtol=2e-4, atol=1e-6)
