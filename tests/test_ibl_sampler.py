"""The glTF-IBL-Sampler peer (homofac.baselines.ibl_sampler): cube sampling, and the sampler run here at a
tiny size (constant environment, frame, irradiance)."""

from __future__ import annotations

import numpy as np
import pytest

from homofac.baselines import ibl_sampler as ibl
from homofac.light.latlong import latlong_directions
from homofac.param import mappers

AXES = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])


def _cube_of(fn, S: int) -> np.ndarray:
    """(6, S, S, C): ``fn`` at the texel-centre directions of a cube map (OpenGL face table)."""
    d = mappers.texel_directions("cube", S).astype(np.float64)  # (S, 6S, 3)
    vals = fn(d.reshape(-1, 3)).reshape(S, 6 * S, -1)
    return np.stack([vals[:, f * S:(f + 1) * S] for f in range(6)])


def _random_dirs(n: int, seed: int) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_seamless_trilinear_cube_sampling():
    """Bilinear across face edges, as GPU seamless filtering: a smooth function stored at texel centres reads
    back within O(1/S^2) inside the faces, and within less than half of what clamping each face to its edge
    misses at the edges and corners (the grid bends there, so O(1/S) remains, as on a GPU); a fractional lod
    blends the two levels linearly."""
    def g(d):
        return (d @ np.array([1.0, 2.0, 3.0]))[:, None]

    S = 16
    lv0 = _cube_of(g, S)
    d = np.concatenate([_random_dirs(4000, 0), AXES, np.array([[1.0, 1, 1], [1, -1, 0.999], [0.5, 1, -1]])])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    err = np.abs(ibl.sample_cube([lv0], d, np.zeros(len(d)))[:, 0] - g(d)[:, 0])
    face, u, v = mappers.face_uv("cube", d)
    inside = np.minimum(np.minimum(u, 1 - u), np.minimum(v, 1 - v)) * S > 1
    assert err[inside].max() < 0.015
    clamped = np.asarray(mappers.lookup("cube", np.concatenate(list(lv0), axis=1), d))[:, 0]
    assert err.max() < 0.5 * np.abs(clamped - g(d)[:, 0]).max()
    # near an edge (+X / +Z), both sides agree to O(eps)
    e = np.array([[1.0, 0.3, 1.0 - 1e-6], [1.0 - 1e-6, 0.3, 1.0]])
    a = ibl.sample_cube([lv0], e, np.zeros(2))[:, 0]
    assert abs(a[0] - a[1]) < 1e-4
    lv1 = _cube_of(lambda x: 2 * g(x), S // 2)
    mid = ibl.sample_cube([lv0, lv1], d, np.full(len(d), 0.25))
    np.testing.assert_allclose(mid, 0.75 * ibl.sample_cube([lv0], d, np.zeros(len(d)))
                               + 0.25 * ibl.sample_cube([lv1], d, np.zeros(len(d))), rtol=1e-12)


def test_lut_lookup_is_clamped_bilinear():
    t = np.arange(12.0).reshape(3, 4, 1)
    np.testing.assert_allclose(ibl.bilinear_2d(t, np.array([0.0, 1.0, 0.5]), np.array([0.0, 1.0, 0.5]))[:, 0],
                               [0.0, 11.0, 5.5])


needs_sampler = pytest.mark.skipif(ibl.available() is not None, reason=f"glTF-IBL-Sampler: {ibl.available()}")


@needs_sampler
def test_sampler_constant_environment():
    """A constant environment: every GGX level and the Lambertian map hold it (to the .hdr's RGBE rounding),
    the mip chain goes down to 2 x 2, and a white metal evaluated the Sample Viewer's way is the constant
    (its multiple-scattering term closes the furnace)."""
    L = 0.75
    b = ibl.bake(np.full((32, 64, 3), L, np.float32), size=16, lambertian_size=8, sample_count=64)
    assert b.mips == 4 and [lv.shape for lv in b.ggx] == [(6, 16 >> i, 16 >> i, 3) for i in range(4)]
    for lv in (*b.ggx, b.lambertian):
        np.testing.assert_allclose(lv, L, rtol=0.01)
    assert b.lut.shape == (16, 16, 2) and (b.lut.sum(-1) <= 1.0 + 1 / 255).all()
    assert b.lut[0, 2:].sum(-1).min() > 0.9  # smooth surfaces reflect (almost) everything
    assert b.runs["ggx"]["wall_s"] > 0 and b.runs["ggx"]["peak_rss_mb"] > 0 and b.files["ggx.ktx2"] > 0
    n = _random_dirs(200, 1)
    v = _random_dirs(200, 2)
    v = np.where(np.sum(n * v, axis=1, keepdims=True) < 0, -v, v)
    rough = np.random.default_rng(3).uniform(0, 1, 200)
    white_metal = b.evaluate(n, v, np.ones((200, 3)), np.ones(200), rough)
    np.testing.assert_allclose(white_metal, L, rtol=0.01)
    plain = b.evaluate(n, v, np.ones((200, 3)), np.ones(200), rough, formula="split_sum")
    assert plain.max() <= 1.01 * L and plain.min() < 0.9 * L  # single scattering loses energy


@needs_sampler
def test_sampler_frame_and_irradiance():
    """Coloured spots on homofac's +x, +y, +z land at SAMPLER_FRAME's lookup vectors of the GGX level 0, and
    the Lambertian map of a linear sky is its exact irradiance / pi read at the same frame."""
    H, W = 64, 128
    d = latlong_directions(H, W)
    spots = np.full((H, W, 3), 0.01, np.float32)
    for k in range(3):
        spots[..., k] += 10 * np.exp(-(1 - d[..., k]) / 0.003)
    b = ibl.bake(spots, size=16, lambertian_size=8, sample_count=32)
    dirs = mappers.texel_directions("cube", 16)
    strip = np.concatenate(list(b.ggx[0]), axis=1)
    for k in range(3):
        i = np.unravel_index(np.argmax(strip[..., k]), strip.shape[:2])
        assert dirs[i] @ (ibl.SAMPLER_FRAME @ np.eye(3)[k]) > 0.99
        assert np.argmax(b.prefiltered(AXES, np.zeros(6))[:, k]) == 2 * k
    coef = np.array([0.5, 0.3, 0.8])
    sky = (1 + d @ coef)[..., None] * np.array([1.0, 0.8, 0.6], np.float32)
    b = ibl.bake(sky.astype(np.float32), size=16, lambertian_size=16, sample_count=1024)
    n = np.concatenate([AXES, _random_dirs(50, 4)])
    exact_over_pi = (1 + (2 / 3) * n @ coef)[:, None] * np.array([1.0, 0.8, 0.6])
    np.testing.assert_allclose(b.irradiance(n), exact_over_pi, rtol=0.03, atol=0.015)  # its filtering bias: 2 % at -z
