"""Texture precision (thesis §4.3): normalization, correction split, prescale (§4.3.1), alpha trick
(§4.3.2, eq. 57-58), 8-bit RGBA encoding and the quantized metrics (RMS II)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import homofac as hf
from homofac.errors import HomofacError
from homofac.factorization import Factorization, evaluate_quantized
from homofac.fit import pipeline, precision
from homofac.fit.result import Result
from homofac.param import mappers
from homofac.param import parametrizations as pz
from homofac.param.mappers.geometry import directions64


def _random_textures(rng, param, mapper, S, lo=1e-3, hi=5.0):
    shape = mappers.texture_shape(mapper, S)
    return [np.exp(rng.uniform(np.log(lo), np.log(hi), shape + (3,))) for _ in range(param.T)]


def _centres64(S):
    """float64 texel-centre directions (the public ones are float32: bilinear weights off by ~1e-7)."""
    return np.asarray(directions64("parabolic", S))


def _model(name, textures, correction=(1.0, 1.0, 1.0)):
    """The one-term model of a BRDF parametrization on parabolic textures."""
    S = np.asarray(textures[0]).shape[0]
    return Factorization.product("brdf", "brdf", name, "parabolic", S, [jnp.asarray(t) for t in textures],
                                 jnp.asarray(correction))


def _decode_unrounded(model, rgba, colour_scale, a, b):
    """The thesis' decode rule (eq. 50) on float RGBA textures: c * prod_j bilerp(rgb_j) * bilerp(alpha_j)."""
    out = jnp.broadcast_to(jnp.asarray(colour_scale, a.dtype), a.shape)
    index = {t.name: k for k, t in enumerate(model.textures)}
    for f in model.terms[0].factors:
        d = hf.param.projections.apply(f.projection, a, b, model.context)
        v = mappers.lookup("parabolic", jnp.asarray(rgba[index[f.texture]], a.dtype), d)
        out = out * v[..., :3] * v[..., 3:4]
    return out


def _pairs(kind, n, seed):
    p = hf.fit.sampling.random_pairs(kind, n, seed)
    return jnp.asarray(p.a, jnp.float64), jnp.asarray(p.b, jnp.float64)


@pytest.mark.parametrize("name", ["PQP", "IV", "NRV"])
def test_prescale_factors_keep_the_product(name):
    p = pz.get(name)
    f = tuple(len(p.uses(k)) for k in range(p.T))
    rng = np.random.default_rng(1)
    for _ in range(5):
        w = np.exp(rng.normal(0, 2, p.T + 1))
        s = precision.prescale_factors(w, f)
        assert s[0] * np.prod(s[1:] ** np.asarray(f)) == pytest.approx(1.0, rel=1e-12)
        # only ratios matter: scaling all weights together gives the same factors up to the constraint
        assert np.all(s > 0)
    assert np.allclose(precision.prescale_factors(np.ones(p.T + 1), f), 1.0)
    s = precision.prescale_factors([0.25, 1.0, 4.0], (2, 1)) if name == "PQP" else None
    if s is not None:  # weights that already satisfy the constraint are returned unchanged
        assert np.allclose(s, [0.25, 1.0, 4.0])


def test_prescale_rejects_bad_weights():
    with pytest.raises(HomofacError, match="needs 3 weights"):
        precision.prescale_factors([1.0, 2.0], (2, 1))
    with pytest.raises(HomofacError, match="> 0"):
        precision.prescale_factors([1.0, 0.0, 2.0], (2, 1))


@pytest.mark.parametrize("corr", [[18.3, 15.0, 8.2], [0.3, 0.2, 0.1], [4.0, 1.0, 0.5], [1.0, 1.0, 1.0], [1e-4, 2e-4, 0]])
def test_split_correction(corr):
    colour, z = precision.split_correction(np.asarray(corr))
    assert np.all(colour <= 1.0) and z >= 1.0
    assert np.log2(z) == int(np.log2(z))  # a power of two
    assert np.array_equal(colour * z, np.asarray(corr, np.float64))  # exact: z is a power of two
    if max(corr) > 1:
        assert 0.5 < max(colour) <= 1.0


def test_normalize_prescale_alpha_leave_the_float_product_unchanged(x64):
    rng = np.random.default_rng(0)
    p = pz.get("PQP")
    raw = _random_textures(rng, p, "parabolic", 8)
    a, b = _pairs("brdf", 400, 3)
    ref = np.asarray(_model("PQP", raw).evaluate(a, b))
    assert np.all(ref > 0)

    model = precision.normalize(_model("PQP", raw))
    norm, corr = [t.data for t in model.textures], model.terms[0].correction
    assert all(float(jnp.max(t)) == pytest.approx(1.0) for t in norm)
    np.testing.assert_allclose(np.asarray(model.evaluate(a, b)), ref, rtol=1e-6)

    tex, c2, s = precision.prescale(precision.texture_uses(model), norm, corr, weights=[0.1, 3.0, 0.5])
    assert not np.allclose(s, 1.0)
    v = np.asarray(_model("PQP", tex, c2).evaluate(a, b))
    np.testing.assert_allclose(v, ref, rtol=1e-6)

    colour, z = precision.split_correction(c2)
    for t in tex:
        rgb, alpha = precision.alpha_split(np.minimum(t, 1.0), colour, z)
        np.testing.assert_allclose(rgb * alpha[..., None], np.minimum(t, 1.0), rtol=1e-12)
        assert rgb.max() <= 1.0 + 1e-12 and alpha.max() <= 1.0 and alpha.min() >= 0.0


def test_alpha_split_product_at_texel_centres(x64):
    """IV at texel centres: the decode rule of eq. 50 on unrounded rgb/alpha equals the float product."""
    rng = np.random.default_rng(5)
    p = pz.get("IV")
    S = 8
    raw = _random_textures(rng, p, "parabolic", S, lo=1e-4)
    model = precision.normalize(_model("IV", raw))
    norm, corr = [t.data for t in model.textures], model.terms[0].correction
    colour, z = precision.split_correction(np.asarray(corr))
    rgba = []
    for t in norm:
        rgb, alpha = precision.alpha_split(np.asarray(t), colour, z)
        assert np.any(alpha < 1.0)  # the trick is active on this high-dynamic-range data
        rgba.append(jnp.asarray(np.concatenate([rgb, alpha[..., None]], -1)))
    d = _centres64(S).reshape(-1, 3)
    ok = mappers.inside_mask("parabolic", S).reshape(-1) & (d[:, 2] > 0.05)
    d = jnp.asarray(d[ok])
    a, b = d, d[::-1]
    v_float = np.asarray(model.evaluate(a, b))
    v_alpha = np.asarray(_decode_unrounded(model, rgba, colour * z, a, b))
    np.testing.assert_allclose(v_alpha, v_float, rtol=1e-6)


def test_encode_is_eight_bit_and_decodes_by_its_rule(x64):
    rng = np.random.default_rng(2)
    p = pz.get("IV")
    S = 8
    raw = _random_textures(rng, p, "parabolic", S, lo=1e-3)
    model = precision.normalize(_model("IV", raw))
    norm = [t.data for t in model.textures]
    for alpha in (False, True):
        enc = precision.encode(model, alpha=alpha)
        assert all(q.dtype == np.uint8 and q.shape == (S, S, 4) for q in enc.rgba)
        if not alpha:
            assert all(np.all(q[..., 3] == 255) for q in enc.rgba)
        # per texel: rgb * alpha reproduces the texture to 8-bit precision (absolute 1/255 at most)
        for t, q in zip(norm, enc.rgba):
            d = precision.decode_rgba8(q).astype(np.float64)
            err = np.abs(d[..., :3] * d[..., 3:] - np.asarray(t))
            assert err.max() <= 0.5 / 255 + 1e-9
        # Result.evaluate(quantized=True) is the decode rule, recomputed here by hand in numpy
        fac = Result(model, encoding={"alpha": alpha})
        d = _centres64(S)
        ij = np.argwhere(mappers.inside_mask("parabolic", S) & (d[..., 2] > 0.05))
        i0, i1 = ij, ij[::-1]
        a, b = jnp.asarray(d[i0[:, 0], i0[:, 1]]), jnp.asarray(d[i1[:, 0], i1[:, 1]])
        got = np.asarray(fac.evaluate(a, b, quantized=True))
        q0, q1 = (np.asarray(q, np.float64) for q in enc.rgba)
        t0 = q0[i0[:, 0], i0[:, 1]]
        t1 = q1[i1[:, 0], i1[:, 1]]
        c = np.asarray(enc.rule["colour"]) * enc.rule["scale"]
        np.testing.assert_allclose(enc.corrections[0], c)
        want = c * t0[:, :3] * t0[:, 3:] * t1[:, :3] * t1[:, 3:] / 255.0**4
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-12)


def test_alpha_keeps_relative_precision_of_small_values(x64):
    """Thesis §4.3.2 / fig. 8: with the alpha channel small texture values keep more bits."""
    p = pz.get("IV")
    t = np.exp(np.linspace(np.log(1e-3), 0.0, 64 * 64))[:, None] * np.array([1.0, 0.78, 0.34])
    t = t.reshape(64, 64, 3)
    corr = np.array([12.0, 9.0, 4.0])  # a typical HDR correction: z = 16
    rel = {}
    model = Factorization.product("brdf", "brdf", "IV", "parabolic", 64, [t, t], corr)
    for alpha in (False, True):
        enc = precision.encode(model, alpha=alpha)
        d = precision.decode_rgba8(enc.rgba[0]).astype(np.float64)
        rel[alpha] = np.mean(np.abs(d[..., :3] * d[..., 3:] - t) / t)
    assert rel[True] < 0.5 * rel[False]


def test_prescale_clamps_and_is_recorded(x64):
    rng = np.random.default_rng(4)
    p = pz.get("PQP")
    raw = _random_textures(rng, p, "parabolic", 8)
    enc = precision.encode(precision.normalize(_model("PQP", raw)), weights=[0.01, 1.0, 100.0])
    rule = enc.rule
    assert rule["clamped"][1] > 0 and rule["clamped"][0] == 0
    assert not np.allclose(rule["prescale"], 1.0) and rule["alpha"] is True
    assert rule["scale"] >= 1 and len(rule["colour"]) == 3


@pytest.fixture(scope="module")
def gold_pqp():
    """Cook-Torrance gold (high dynamic range) with PQP on a small parabolic map (thesis §4.3.2)."""
    target = hf.fit.brdf_target(hf.brdf.cook_torrance(kd=0.1, ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34)))
    fac = hf.fit.factorize(target, "PQP", mapper="parabolic", texture_size=16,
                           sampling={"kind": "texels", "size": 12, "validation": 2000}, keep_samples=True)
    return target, fac


@pytest.mark.slow
def test_alpha_trick_lowers_eight_bit_error_on_hdr_brdf(gold_pqp):
    target, fac = gold_pqp
    assert float(np.max(np.asarray(fac.correction))) > 4  # a high-dynamic-range case: z > 1
    m = {}
    for alpha in (False, True):
        f = fac.replace(encoding={"alpha": alpha})
        m[alpha] = pipeline.measure(f, target, fac.samples)
    # the metrics stored by factorize are those of the default encoding (alpha on)
    assert fac.metrics["validation"]["quantized"]["avg_rel"] == pytest.approx(m[True]["validation"]["quantized"]["avg_rel"], rel=1e-6)
    for split in ("train", "validation"):
        assert m[True][split]["quantized"]["avg_rel"] < m[False][split]["quantized"]["avg_rel"]
    print("8-bit validation avg_rel without alpha", m[False]["validation"]["quantized"]["avg_rel"],
          "with alpha", m[True]["validation"]["quantized"]["avg_rel"],
          "float", m[True]["validation"]["float"]["avg_rel"])

    # the precision part of the gain: rounding to 8 bits costs much less with the alpha channel.
    s = fac.samples
    a, b = jnp.asarray(s.val_a), jnp.asarray(s.val_b)
    colour, z = precision.split_correction(fac.correction)
    unrounded = []
    for t in fac.textures:
        rgb, al = precision.alpha_split(np.asarray(t), colour, z)
        unrounded.append(jnp.asarray(np.concatenate([rgb, al[..., None]], -1), jnp.float32))
    v_split = np.asarray(_decode_unrounded(fac.model, unrounded, jnp.asarray(colour * z, jnp.float32), a, b))
    v_float = np.asarray(fac.evaluate(a, b))
    v_q = {al: np.asarray(fac.replace(encoding={"alpha": al}).evaluate(a, b, quantized=True)) for al in (False, True)}
    pos = v_float > 1e-3 * v_float.mean()
    cost_alpha = np.mean(np.abs(v_q[True] - v_split)[pos] / v_split[pos])
    cost_plain = np.mean(np.abs(v_q[False] - v_float)[pos] / v_float[pos])
    assert cost_alpha < 0.5 * cost_plain


@pytest.mark.slow
def test_quantized_differs_from_naive_rounding(gold_pqp):
    """evaluate(quantized=True) is the RGBA8 decode, not rounding of the normalized textures."""
    _, fac = gold_pqp
    s = fac.samples
    a, b = jnp.asarray(s.val_a[:200]), jnp.asarray(s.val_b[:200])
    naive = fac.model.replace_data(precision.quantize(list(fac.textures))).evaluate(a, b)
    q = fac.evaluate(a, b, quantized=True)
    assert not np.allclose(np.asarray(q), np.asarray(naive))
    q_plain = fac.replace(encoding={"alpha": False}).evaluate(a, b, quantized=True)
    np.testing.assert_allclose(np.asarray(q_plain), np.asarray(naive), rtol=2e-5, atol=1e-7)
