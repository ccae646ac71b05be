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


def test_float32_straddler_weights_and_centroids_match_float64_with_one_atan2_per_arc(x64):
    """The selected straddlers' exact clip in float32 (the lighting programs' precision) equals the float64
    clip of the same texels to 1e-6 of a weight (texels at r = 32 are about 4e-3 sr), every row still sums
    to pi, the centroids are the float64 ones where the visible part is not a sliver, and the clip is
    traced with five atan2 (one per edge's visible arc, the horizon arc's), not one per edge and case."""
    import jax

    r = 32
    d, w = _cube_texels(r)
    n = normals(200, seed=3)[:200]  # random normals (horizons through texel edges: the test below)
    out = {}
    for dt in (jnp.float32, jnp.float64):
        geom = light_geometry(jnp.asarray(d, dt), jnp.asarray(w, dt), jnp.asarray(cube_corners(r), dt), r)
        out[dt] = jax.jit(lambda x, g=geom: cosine_weights(x, g, select=True, centroids=True))(jnp.asarray(n, dt))
    (w32, (i32, c32)), (w64, (i64, c64)) = out[jnp.float32], out[jnp.float64]
    w32, w64 = np.asarray(w32, np.float64), np.asarray(w64)
    assert np.abs(w32 - w64).max() < 1e-6
    np.testing.assert_allclose(w32.sum(axis=1), np.pi, atol=2e-6)
    i32, i64 = np.asarray(i32), np.asarray(i64)  # slots of straddlers with a visible part (L: none)
    big = (i32 == i64) & (i64 < w64.shape[1]) & (np.take_along_axis(w64, np.minimum(i64, w64.shape[1] - 1), 1) > 1e-4)
    assert big.sum() > 1000
    assert np.abs(np.asarray(c32, np.float64) - np.asarray(c64))[big].max() < 2e-4
    geom = light_geometry(jnp.asarray(d, jnp.float32), jnp.asarray(w, jnp.float32), jnp.asarray(cube_corners(r), jnp.float32), r)
    jaxpr = str(jax.make_jaxpr(lambda x: cosine_weights(x, geom, select=True, centroids=True))(jnp.asarray(n[:4], jnp.float32)))
    assert jaxpr.count("atan2") == 5


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_compiled_weights_where_the_horizon_runs_along_texel_edges_sum_to_pi(x64, dtype):
    """Normals whose horizon contains texel edges (cube edges: n = (1, 1, 0) / sqrt 2; a face's inner
    edges: n = (1, 2, 0) / sqrt 5 meets face x = 1 at its texel line y = -1/2 for r = 4, 8, 16) put
    corners on the horizon, where compiled programs round n . p to +-1e-8: every path's compiled weights
    still sum to pi, stay within a texel's solid angle, and equal the float64 weights computed op by op."""
    import jax

    dt = jnp.dtype(dtype)
    n = np.array([[1, 1, 0], [1, -1, 0], [1, 2, 0], [0, 1, -2], [2, 2, 1]], float)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    for r in (4, 16):
        d, w = _cube_texels(r)
        geom = light_geometry(jnp.asarray(d, dt), jnp.asarray(w, dt), jnp.asarray(cube_corners(r), dt), r)
        ref = np.asarray(cosine_weights(jnp.asarray(n), light_geometry(jnp.asarray(d), jnp.asarray(w),
                                                                     jnp.asarray(cube_corners(r)), r)))
        for select, centroids in ((False, False), (True, False), (True, True)):
            got = jax.jit(lambda x: cosine_weights(x, geom, select=select, centroids=centroids))(jnp.asarray(n, dt))
            got = np.asarray(got[0] if centroids else got, np.float64)
            np.testing.assert_allclose(got.sum(axis=1), np.pi, atol=1e-5)
            assert got.max() <= w.max() * (1 + 1e-5)
            np.testing.assert_allclose(got, ref, atol=1e-6)
