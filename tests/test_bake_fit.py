"""A layer's fit (:func:`homofac.bake.build.layer_fit`): the I_B weights are recovered as well as I_A's."""

from __future__ import annotations

import numpy as np

import homofac as hf
from homofac.bake import kernels as kn
from homofac.bake.build import filtered, layer_fit, texel_radius
from homofac.param import mappers

RHO = 0.6
SIZE = 8


def _layer():
    env = hf.light.load_environment("studio", 8)  # lamps: the lobes' shapes matter
    x = kn.nv_centres(8)
    k = kn.smooth(kn.calibrate(kn.specular_kernels(RHO, x), kn.albedos(RHO, x)).reshape(2 * len(x), -1), texel_radius(env))
    # the fit's data: each kernel's filter normalized by the reference kernel's discrete mass (as layer_fit's)
    data = filtered(np.concatenate([k, k.sum(0, keepdims=True)]), SIZE, env, None, np.zeros(len(k), bool))  # (T, 2X, 3)
    return env, k, data


def _fit(env, k, rank):
    _, w, p, _ = layer_fit(k, SIZE, env, rank, SIZE)
    return w, p


def test_full_rank_products_read_every_lobe():
    """With as many terms as the data's columns, P W reads the fit's data of every kernel, I_B's (up to 30x
    smaller than I_A's) within 1 % of its own size: the weights of I_B are R^-1 V of the material mix."""
    env, k, data = _layer()
    w, p = _fit(env, k, len(k))
    got = np.einsum("tkc,jk->tjc", p, w)
    err = np.linalg.norm(got - data, axis=(0, 2)) / np.linalg.norm(data, axis=(0, 2))
    assert np.all(err < 0.01), err


def test_two_term_weights_are_least_squares_on_the_maps():
    """At K = 2, every column's weights (I_A's and I_B's) are within 2 % of the least-squares weights on the two
    maps at the same texels (solid-angle measure; Eckart-Young): I_B's large relative error at facing views
    (docs/notes/bake.md, "The rough layers' I_A and I_B alone") is the span of two maps, not the weights."""
    env, k, data = _layer()
    w, p = _fit(env, k, 2)
    sw = np.sqrt(mappers.texel_solid_angles("cube", SIZE).reshape(-1))[:, None, None]
    a = np.moveaxis(p * sw, 2, 1).reshape(-1, p.shape[1])  # (T 3, K)
    y = np.moveaxis(data * sw, 2, 1).reshape(-1, data.shape[1])  # (T 3, 2X)
    best, *_ = np.linalg.lstsq(a, y, rcond=None)
    res = np.linalg.norm(a @ w.T - y, axis=0)
    res_best = np.linalg.norm(a @ best - y, axis=0)
    assert np.all(res <= 1.02 * res_best + 1e-9 * np.linalg.norm(y, axis=0)), res / res_best
