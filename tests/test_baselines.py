"""The baselines fail when they are wrong: furnace, the DFG table, the mirror limit, Kautz-McCool under
its own assumptions, and Mahajan's rank-1 analysis of a separable target."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import homofac as hf
from homofac import baselines
from homofac.baselines import kautz_mccool, split_sum
from homofac.errors import HomofacError
from homofac.fit import sampling
from homofac.fit.result import Result
from homofac.param import mappers
from homofac.shader import LANGUAGES
from homofac.target import Target


def _pairs(n=2000, seed=0):
    p = sampling.random_pairs("lighting", n, seed)
    return p.a, p.b


def test_furnace_white_lambert_under_uniform_light_is_one():
    env = hf.light.uniform(1.0, 8)
    target = hf.light.lighting_target(hf.brdf.lambert(1.0), env)
    a, b = _pairs()
    for name in ("kautz_mccool",):
        model = baselines.build(name, target, "dual_paraboloid", 16)
        np.testing.assert_allclose(np.asarray(model.evaluate(a, b)), 1.0, rtol=1e-5)
    # split-sum needs a microfacet model: a "white Lambert" Cook-Torrance (ks = 0)
    ct = hf.light.lighting_target(hf.brdf.cook_torrance(kd=1.0, ks=0.0), env)
    model = baselines.build("split_sum", ct, "dual_paraboloid", 16)
    np.testing.assert_allclose(np.asarray(model.evaluate(a, b)), 1.0, rtol=1e-5)
    assert model.lookups == 3 and [t.kind for t in model.terms] == ["irradiance", "prefiltered"]


def _hemisphere_integral(brdf, x: float, n_theta: int = 200, n_phi: int = 400) -> np.ndarray:
    """int f(wi, wo) cos(theta_i) dwi by Gauss-Legendre in cos(theta_i) and the trapezoid in phi (independent
    of brdf.albedo's lobe-centred scheme). 200 x 400 nodes agree with 800 x 1600 to 1.2e-5 relative at roughness
    0.4 (cook_torrance and ggx), a hundredth of the tests' 1e-3."""
    c, wc = np.polynomial.legendre.leggauss(n_theta)
    c, wc = 0.5 * (c + 1), 0.5 * wc  # cos theta_i in (0, 1)
    phi = 2 * np.pi * np.arange(n_phi) / n_phi
    s = np.sqrt(1 - c * c)
    wi = np.stack([s[:, None] * np.cos(phi), s[:, None] * np.sin(phi), np.broadcast_to(c[:, None], (n_theta, n_phi))], -1)
    wo = np.array([np.sqrt(1 - x * x), 0.0, x])
    f = np.asarray(brdf(jnp.asarray(wi.reshape(-1, 3), jnp.float32), jnp.asarray(wo, jnp.float32)), np.float64)
    f = f.reshape(n_theta, n_phi, 3)
    return np.sum(f * (c * wc)[:, None, None], axis=(0, 1)) * (2 * np.pi / n_phi)


@pytest.mark.xla_optimized  # long-running integrals: XLA at -O0 doubles their CPU (25 s against 14 s)
@pytest.mark.parametrize("model", ["cook_torrance", "ggx"])
def test_dfg_table_is_the_integral_of_f_cos_under_a_constant_environment(model):
    """Under a constant environment P = 1, so the split sum at n.v = x is kd + ks (F0 A(x) + B(x)): it must
    equal the hemisphere integral of f cos within 1e-3 at the line texels (independent quadrature)."""
    brdf = hf.brdf.make(model, kd=(0.2, 0.1, 0.05), ks=0.9, roughness=0.4, f0=(0.9, 0.6, 0.3))
    target = hf.light.lighting_target(brdf, hf.light.uniform(1.0, 4))
    fac = baselines.build("split_sum", target, "dual_paraboloid", 8, {"line_size": 16})
    n = np.array([[0.0, 0.0, 1.0]])
    for x in (np.arange(16) + 0.5) / 16:
        v = np.array([[np.sqrt(1 - x * x), 0.0, x]])
        got = np.asarray(fac.evaluate(n, v))[0]
        want = _hemisphere_integral(brdf, x)
        np.testing.assert_allclose(got, want, rtol=1e-3, atol=1e-4)


@pytest.mark.slow
def test_split_sum_at_n_equals_v_tends_to_the_mirror_limit():
    """At n = v Karis' assumption holds; as the roughness goes to 0 the split sum tends to F0 L(r), r = n."""
    rng = np.random.default_rng(3)
    h = 64
    th = np.pi * (np.arange(h) + 0.5) / h
    ph = 2 * np.pi * (np.arange(2 * h) + 0.5) / (2 * h)
    img = (1.5 + np.cos(th)[:, None, None] + 0.4 * np.sin(2 * ph)[None, :, None] * np.sin(th)[:, None, None]
           * np.array([1.0, 0.7, 0.4]))
    env = hf.light.from_latlong(img.astype(np.float32), 32)
    f0 = np.array([0.95, 0.8, 0.5])
    n = rng.normal(size=(400, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    # the environment's radiance in direction n (bilinear on its cube texels, the mirror image)
    idx, w = mappers.bilinear("cube", n, 32)
    rad = np.asarray(env.radiance)[: 6 * 32 * 32]
    mirror = f0 * np.sum(w[..., None] * rad[idx], axis=1)
    errs = []
    for alpha in (0.3, 0.1, 0.03):
        brdf = hf.brdf.ggx(kd=0.0, ks=1.0, roughness=alpha, f0=f0)
        fac = baselines.build("split_sum", hf.light.lighting_target(brdf, env), "dual_paraboloid", 32)
        got = np.asarray(fac.evaluate(n, n))
        errs.append(np.linalg.norm(got - mirror) / np.linalg.norm(mirror))
    assert errs[0] > errs[1] > errs[2] and errs[2] < 0.02, errs


class ViewPhong(eqx.Module):
    """Kautz-McCool's assumed integral for a Phong lobe: (n.v) k(x) sum_k max(r.l_k, 0)^e L_k dw_k, computed
    straight from the environment (no horizon, n.l replaced by n.r)."""

    env: hf.light.Environment
    exponent: float = eqx.field(static=True)

    def __call__(self, n, v):
        r = 2 * jnp.sum(n * v, -1, keepdims=True) * n - v
        c = jnp.maximum(r @ self.env.directions.T, 0.0) ** self.exponent
        return (c * self.env.solid_angle) @ self.env.radiance


def test_kautz_mccool_is_exact_for_a_phong_lobe_under_its_own_assumptions():
    env = hf.light.sun_sky(resolution=16, sun_angle_deg=8.0)
    e = 200.0
    brdf = hf.brdf.phong(kd=0.0, ks=1.0, exponent=e)
    K = 4
    fac = baselines.build("kautz_mccool", hf.light.lighting_target(brdf, env), "cube", 16, {"slices": K})
    assert len(fac.terms) == K and fac.lookups == 2 * K
    raw = ViewPhong(env, e)
    # at the slice elevations (n.v = x_s) and texel-centre reflected directions the 3D map is exact, where
    # the lobe is radially symmetric: not cut by the horizon (the grazing slice x = 1/8 is)
    d = np.asarray(mappers.texel_directions("cube", 16)).reshape(-1, 3)[::7]
    for s in range(1, K):
        x = (s + 0.5) / K
        # n with n.v = x and r = d: n = normalize(d + v) where v = 2 x n - d; pick v in the plane of d and z
        t = np.cross(d, np.array([0.3, 0.5, 0.81]))
        t /= np.linalg.norm(t, axis=1, keepdims=True)
        half = np.arccos(x)  # angle between n and r (= between n and v)
        n = np.cos(half) * d + np.sin(half) * t
        v = 2 * x * n - d
        spec = kautz_mccool.profiles(hf.brdf.phong(kd=0.0, ks=1.0, exponent=e), np.array([x]))
        theta, p = spec
        scale = kautz_mccool.directional_albedo(brdf, np.array([x]))[0] / (x * kautz_mccool.sphere_integral(theta, p)[0])
        want = x * scale * np.asarray(raw(jnp.asarray(n, jnp.float32), jnp.asarray(v, jnp.float32)))
        got = np.asarray(fac.evaluate(n, v))
        np.testing.assert_allclose(got, want, rtol=2e-3, atol=1e-6 * want.max())


class Separable(eqx.Module):
    """a(n) b(r) per channel: a separable lighting target."""

    def __call__(self, n, v):
        r = 2 * jnp.sum(n * v, -1, keepdims=True) * n - v
        return (1.5 + n[..., :1] * jnp.array([1.0, 0.5, 0.2])) * (2.0 + jnp.sin(3 * r[..., 1:2]) + r)


def test_rank_one_analysis_of_a_separable_target_is_exact():
    an = baselines.analyse(Target("lighting", Separable()), "nr", "dual_paraboloid", 8, max_rank=3)
    assert an.error[0] == 1.0 and an.error[1] < 1e-5 and an.rank_for(1e-4) == 1
    real = baselines.analyse(hf.light.lighting_target(hf.brdf.cook_torrance(), hf.light.load_environment("forest", 4)),
                             "nr", "dual_paraboloid", 6, max_rank=6)
    assert np.all(np.diff(real.error) <= 1e-9) and real.error[1] > 0.05  # decreasing, and gold is not separable
    assert "Mahajan" in real.summary() and real.record()["pair"] == "nr"


@pytest.mark.slow
def test_baselines_are_ordinary_results(tmp_path):
    """Evaluate, metrics, save / load, the 8-bit textures, shaders: a baseline is the same model as a fit."""
    env = hf.light.load_environment("studio", 4)
    target = hf.light.lighting_target(hf.brdf.cook_torrance(), env)
    fac = hf.fit.factorize(target, "split_sum", texture_size=8, sampling={"size": 6, "validation": 500},
                           advanced={"baseline": {"irradiance": "sh9"}})
    assert fac.solver["method"] == "split_sum" and fac.metrics["validation"]["float"]["nrmse"] < 1
    out = fac.save(tmp_path / "o", png=True, shaders=list(LANGUAGES))
    back = hf.load(out)
    a, b = _pairs(300, 1)
    np.testing.assert_allclose(np.asarray(back.evaluate(a, b)), np.asarray(fac.evaluate(a, b)), rtol=1e-5, atol=1e-7)
    assert back.parametrization == "split_sum" and len(back.model.terms) == 2
    km = hf.fit.factorize(target, "kautz_mccool", texture_size=8, sampling={"size": 6, "validation": 500},
                          advanced={"baseline": {"slices": 3}})
    assert len(km.model.terms) == 4 and "homofac_radiance" in km.shader("wgsl")


def test_baselines_refuse_what_they_cannot_do():
    env = hf.light.load_environment("studio", 4)
    with pytest.raises(HomofacError, match="microfacet"):
        baselines.build("split_sum", hf.light.lighting_target(hf.brdf.phong(), env), "dual_paraboloid", 8)
    with pytest.raises(HomofacError, match="lighting"):
        baselines.build("split_sum", hf.fit.brdf_target(hf.brdf.ggx()), "dual_paraboloid", 8)
    with pytest.raises(HomofacError, match="baseline: unknown key"):
        baselines.build("split_sum", hf.light.lighting_target(hf.brdf.ggx(), env), "dual_paraboloid", 8, {"x": 1})
    with pytest.raises(HomofacError, match="baseline"):
        hf.fit.factorize(hf.light.lighting_target(hf.brdf.ggx(), env), "NR", advanced={"baseline": {"slices": 2}})


def test_split_sum_options_change_what_they_say():
    env = hf.light.load_environment("forest", 8)
    t = hf.light.lighting_target(hf.brdf.ggx(roughness=0.5), env)
    exact = baselines.build("split_sum", t, "dual_paraboloid", 16)
    sh9 = baselines.build("split_sum", t, "dual_paraboloid", 16, {"irradiance": "sh9"})
    plain = baselines.build("split_sum", t, "dual_paraboloid", 16, {"weighting": "plain"})
    e1, e2 = (np.asarray(m.textures[0].data) for m in (exact, sh9))
    assert 0 < np.abs(e1 - e2).max() < 0.2 * e1.max()  # SH9 irradiance: close to the exact one, not equal
    p1, p3 = (np.asarray(m.textures[1].data) for m in (exact, plain))
    assert np.abs(p1 - p3).max() > 0
    np.testing.assert_allclose(split_sum.sh9_irradiance(hf.light.uniform(1.0, 4), np.array([[0, 0, 1.0]])), np.pi,
                               rtol=1e-5)
