"""The converged reference of the bake's integrals (homofac.light.reference): analytic cases (uniform light: the
directional albedos, and their mirror limit at roughness 0.045; one small light: the BRDF at its direction times
its power) and agreement with the pinned light sum where that converges (rough materials)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import homofac as hf
from homofac.brdf.gltf import gltf_lobes_at
from homofac.errors import HomofacError
from homofac.io.exr import read_exr
from homofac.light.integrals import integrals
from homofac.light.latlong import latlong_directions, latlong_solid_angles
from homofac.light.reference import reference_integrals, source_map
from helpers import visible_pairs


def nrmse(a, e):
    return float(np.linalg.norm(np.asarray(a) - np.asarray(e)) / np.linalg.norm(np.asarray(e)))


#: One shape for every call (8 pairs, 2048 samples, 64 x 128 maps; forest 128 x 256 at 2048 and 4096): each new
#: shape costs a ~3 s compilation.
PAIRS, SAMPLES = 8, 2048
UNIFORM = np.ones((64, 128, 3))


def views(cosines):
    x = np.asarray(cosines, np.float64)
    return np.tile([0.0, 0.0, 1.0], (len(x), 1)), np.stack([np.sqrt(1 - x * x), 0 * x, x], -1)


def test_uniform_light_gives_the_directional_albedos():
    """Constant radiance 1: I_A + I_B is the white metal's albedo, I_B the black metal's, 0.96 I_d + 0.04 I_A + I_B
    the white dielectric's (Gauss-Legendre quadrature, :func:`homofac.brdf.albedo`)."""
    n, v = views(np.linspace(0.1, 1.0, PAIRS))
    parts = reference_integrals(UNIFORM, n, v, 0.5, samples=SAMPLES)
    wo = jnp.asarray(v)
    alb = lambda c, m: np.asarray(hf.brdf.albedo(hf.brdf.gltf(base_color=c, metallic=m, roughness=0.5), wo, n=128))[:, 0]  # noqa: E731
    np.testing.assert_allclose(parts[:, 1, 0] + parts[:, 2, 0], alb(1.0, 1.0), atol=1e-3)
    np.testing.assert_allclose(parts[:, 2, 0], alb(0.0, 1.0), atol=1e-3)
    np.testing.assert_allclose(0.96 * parts[:, 0, 0] + 0.04 * parts[:, 1, 0] + parts[:, 2, 0], alb(1.0, 0.0), atol=1e-3)
    np.testing.assert_allclose(parts[:, :, 1:], np.repeat(parts[:, :, :1], 2, 2), rtol=1e-12)


def test_uniform_light_at_the_lowest_roughness_is_the_mirror_limit():
    """Roughness 0.045 (alpha 0.002, a lobe far narrower than any light texel): the lobes collapse onto the
    mirror direction, so I_A -> 1 - (1 - n.v)^5 and I_B -> (1 - n.v)^5 (Schlick at h = n, masking -> 1)."""
    x = np.linspace(0.3, 1.0, PAIRS)
    n, v = views(x)
    parts = reference_integrals(UNIFORM, n, v, 0.045, samples=SAMPLES)
    np.testing.assert_allclose(parts[:, 1, 0], 1 - (1 - x) ** 5, atol=2e-3)
    np.testing.assert_allclose(parts[:, 2, 0], (1 - x) ** 5, atol=2e-3)


def test_one_small_light_gives_the_brdf_at_its_direction_times_its_power():
    """One bright pixel of a 64 x 128 map (2.8 degrees) under lobes of roughness 0.8: each integral is the lobe at
    the pixel's direction times n.l times the pixel's power (the BRDF varies little over the light)."""
    img = np.zeros((64, 128, 3))
    img[20, 40] = (100.0, 50.0, 25.0)
    d = latlong_directions(64, 128)[20, 40]
    power = img[20, 40] * latlong_solid_angles(64, 128)[20]
    rng = np.random.default_rng(1)
    n = d + 0.6 * rng.normal(size=(PAIRS, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    v = rng.normal(size=(PAIRS, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v = np.where(np.sum(n * v, 1, keepdims=True) < 0, -v, v)
    parts = reference_integrals(img, n, v, 0.8, samples=SAMPLES)
    t, b, nn = (np.asarray(a) for a in hf.sphere.frame(jnp.asarray(n)))
    wi = tuple(a @ d for a in (t, b, nn))
    wo = tuple(np.sum(a * v, 1) for a in (t, b, nn))
    lobes = np.stack([np.asarray(g) * np.maximum(wi[2], 0) for g in gltf_lobes_at(0.8, wi, wo)], 1)
    expected = lobes[:, :, None] * power
    assert nrmse(parts, expected) < 0.01


def test_agrees_with_the_pinned_light_sum_where_it_converges():
    """Rough lobes under the bundled forest: the pinned light sum at resolution 32 (within 0.2 % of 64 there) and
    the reference agree within 1 % per integral."""
    img = read_exr(hf.light.bundled("forest"))
    n, v = visible_pairs(PAIRS, seed=5)
    rough = 0.7
    parts = reference_integrals(source_map(img), n, v, rough, samples=2 * SAMPLES)
    env = hf.light.load_environment("forest", 32)
    light_sum = np.asarray(integrals(env, jnp.asarray(n, jnp.float32), jnp.asarray(v, jnp.float32), rough), np.float64)
    for k in range(3):
        assert nrmse(parts[:, k], light_sum[:, k]) < 0.01, k


def test_doubling_the_samples_refines_the_same_estimate():
    """Sobol' prefixes: 2 S points hold the S points, so the estimate converges: a narrow lobe (roughness 0.1)
    under forest moves by < 0.5 % from 2048 to 4096 samples, where the light sum moves by 7-26 % from 64 to 128."""
    img = read_exr(hf.light.bundled("forest"))
    m = source_map(img)
    n, v = visible_pairs(PAIRS, seed=6)
    a = reference_integrals(m, n, v, 0.1, samples=SAMPLES)
    b = reference_integrals(m, n, v, 0.1, samples=2 * SAMPLES)
    assert nrmse(a[:, 1:], b[:, 1:]) < 0.005


def test_refuses_what_it_cannot_integrate():
    with pytest.raises(HomofacError, match="2:1 lat-long"):
        source_map(np.ones((8, 8, 3)))
    with pytest.raises(HomofacError, match="all zero"):
        source_map(np.zeros((8, 16, 3)))
    with pytest.raises(HomofacError, match="power of two"):
        reference_integrals(UNIFORM, *views([0.5]), 0.5, samples=1000)
