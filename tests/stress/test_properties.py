"""Property tests (hypothesis): mapper round trips, bilinear partition of unity, scale equivariance,
PQP reciprocity, and invariance under a permutation of the samples.

Shapes are fixed (one direction, or one small problem) so JAX compiles once per test and the examples
are cheap; ``max_examples`` is small and ``deadline`` off for the first, compiling example.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import homofac as hf
from homofac.fit import pipeline
from homofac.target import brdf_target
from homofac.param import mappers

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
FIT_SETTINGS = settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.too_slow])

coord = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)


@st.composite
def directions(draw, hemisphere=False):
    d = np.array([draw(coord), draw(coord), draw(coord)], np.float64)
    n = np.linalg.norm(d)
    if n < 1e-3:
        d, n = np.array([0.0, 0.0, 1.0]), 1.0
    d = d / n
    if hemisphere and d[2] < 0:
        d[2] = -d[2]
    return d


MAPPER_NAMES = sorted(mappers.MAPPERS)


def _inputs(m):
    """What a mapper maps: directions (of its domain), or scalars in [0, 1] for the line mapper."""
    if m.scalar:
        return st.floats(0.0, 1.0, allow_nan=False).map(lambda x: np.float64(x))
    return directions(hemisphere=not m.covers_sphere)


@pytest.mark.parametrize("name", MAPPER_NAMES)
@SETTINGS
@given(data=st.data())
def test_mapper_round_trip(name, data):
    m = mappers.get(name)
    d = data.draw(_inputs(m))
    f, u, v = m.to_face_uv(d)
    assert 0 <= int(f) < m.faces and 0 <= float(u) <= 1 and 0 <= float(v) <= 1
    back = np.asarray(m.from_face_uv(f, u, v))
    assert np.linalg.norm(back - d) < 1e-5


@pytest.mark.parametrize("name", MAPPER_NAMES)
@SETTINGS
@given(data=st.data(), size=st.sampled_from([4, 7, 16, 33]))
def test_bilinear_is_a_partition_of_unity_on_valid_texels(name, data, size):
    m = mappers.get(name)
    d = data.draw(_inputs(m))
    idx, w = mappers.bilinear(m, np.asarray(d, np.float32)[None], size)
    idx, w = np.asarray(idx)[0], np.asarray(w)[0]
    assert abs(w.sum() - 1.0) < 1e-5 and np.all(w >= -1e-7)
    valid = np.asarray(mappers.valid_mask(m, size)).reshape(-1)
    assert np.all(valid[idx[w > 0]])


GOLD = dict(kd=0.1, ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))


@pytest.fixture(scope="module")
def small_problem():
    target = brdf_target(hf.brdf.cook_torrance(**GOLD), "brdf_cos")
    samples = pipeline.draw_samples(target, "PQP", {"kind": "texels", "size": 8, "validation": 400, "cache": False},
                                    log=lambda m: None)
    fit = dict(mapper="parabolic", texture_size=8, solver={"tolerance": 1e-7, "max_iterations": 2000})
    base = pipeline.factorize(target, "PQP", samples=samples, **fit)
    return target, samples, fit, base


@FIT_SETTINGS
@given(c=st.floats(1e-3, 1e3))
def test_scaling_the_target_scales_the_product(small_problem, c):
    """log((c y + eps c alpha) / (c alpha)) is the same system: same textures, correction times c."""
    target, s, fit, base = small_problem
    scaled = s._replace(y=s.y * np.float32(c), val_y=s.val_y * np.float32(c))
    fac = pipeline.factorize(target, "PQP", samples=scaled, **fit)
    a, b = s.val_a[:200], s.val_b[:200]
    np.testing.assert_allclose(np.asarray(fac.evaluate(a, b)), c * np.asarray(base.evaluate(a, b)), rtol=2e-4,
                               atol=1e-6 * c * float(np.abs(np.asarray(base.evaluate(a, b))).max()))


@FIT_SETTINGS
@given(data=st.data())
def test_pqp_is_reciprocal(small_problem, data):
    """p(wi) q(h) p(wo) is symmetric in (wi, wo) by construction."""
    *_, base = small_problem
    wi = data.draw(directions(hemisphere=True))
    wo = data.draw(directions(hemisphere=True))
    a = np.stack([wi, wo]).astype(np.float32)
    ab = np.asarray(base.evaluate(a, a[::-1]))
    np.testing.assert_allclose(ab[0], ab[1], rtol=1e-5, atol=1e-7)


@FIT_SETTINGS
@given(seed=st.integers(0, 2**31 - 1))
def test_permuting_the_samples_does_not_change_the_result(small_problem, seed):
    target, s, fit, base = small_problem
    perm = np.random.default_rng(seed).permutation(len(s.a))
    shuffled = s._replace(a=s.a[perm], b=s.b[perm], y=s.y[perm])
    fac = pipeline.factorize(target, "PQP", samples=shuffled, **fit)
    # float32 sums in another order: the log textures agree to about 1e-5
    for t1, t2 in zip(base.textures, fac.textures):
        np.testing.assert_allclose(np.asarray(t2), np.asarray(t1), rtol=1e-3, atol=1e-5)
    assert abs(fac.metrics["validation"]["float"]["nrmse"] - base.metrics["validation"]["float"]["nrmse"]) < 1e-4
