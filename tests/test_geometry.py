"""Exact cosine-weighted texel solid angles (homofac.light.geometry)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from homofac.light.cubemap import cube_texels as _cube_texels
from homofac.light.geometry import cosine_weights, cube_corners, light_geometry, straddler_count, vector_solid_angle


def normals(count, seed=0):
    n = np.random.default_rng(seed).normal(size=(count, 3))
    extra = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0], [1, 1, 0], [1, 1, 1], [0, 1, 1], [1, -1, 1]], float)
    n = np.concatenate([n, extra])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


@pytest.mark.slow
@pytest.mark.parametrize("r", [4, 8, 16])
def test_weights_sum_to_pi_and_match_supersampling(x64, r):
    d, w = _cube_texels(r)
    geom = light_geometry(jnp.asarray(d), jnp.asarray(w), jnp.asarray(cube_corners(r)), r)
    n = normals(60)
    W = np.asarray(cosine_weights(jnp.asarray(n), geom))
    np.testing.assert_allclose(W.sum(axis=1), np.pi, atol=1e-12)
    k = 32
    dd, ww = _cube_texels(r * k)
    ref = (np.maximum(n @ dd.T, 0) * ww).reshape(len(n), r, k, 6 * r, k).sum(axis=(2, 4)).reshape(len(n), -1)
    np.testing.assert_allclose(W, ref, rtol=2e-3, atol=1e-5)  # the 32x32 supersampled reference is itself approximate
    # the compacted (select) path gives the same weights
    Ws = np.asarray(cosine_weights(jnp.asarray(n), geom, select=True))
    np.testing.assert_allclose(Ws, W, atol=1e-12)
    # far from the horizon the weight is the texel-centre form to second order in the texel size
    centre = np.maximum(n @ d.T, 0) * w
    far = np.abs(n @ d.T) > 0.5
    assert np.abs(W - centre)[far].max() < 1.0 / r**2 * w.max()


def test_vector_solid_angle_length_is_near_solid_angle():
    d, w = _cube_texels(8)
    m = np.asarray(vector_solid_angle(jnp.asarray(cube_corners(8))))
    assert np.all(np.linalg.norm(m, axis=1) <= w + 1e-12)
    np.testing.assert_allclose(np.linalg.norm(m, axis=1), w, rtol=0.01)
    cos = np.sum(m * d, axis=1) / np.linalg.norm(m, axis=1)
    assert np.all(cos > 0.999)


@pytest.mark.parametrize("r", [4, 16, 32])
def test_straddler_bound_holds(r):
    d, w = _cube_texels(r)
    geom = light_geometry(jnp.asarray(d, jnp.float32), jnp.asarray(w, jnp.float32),
                          jnp.asarray(cube_corners(r), jnp.float32), r)
    counts = np.asarray(straddler_count(jnp.asarray(normals(3000, seed=r), jnp.float32), geom))
    assert counts.max() <= geom.max_straddlers, (counts.max(), geom.max_straddlers)


def test_delta_lights_use_the_point_form():
    dirs = jnp.asarray([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    geom = light_geometry(dirs, jnp.asarray([2.0, 1.0]), jnp.zeros((2, 4, 3)), 0)
    n = jnp.asarray([[0.0, 0.6, 0.8]])
    np.testing.assert_allclose(np.asarray(cosine_weights(n, geom)), [[1.6, 0.0]], atol=1e-6)
