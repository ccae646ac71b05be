"""The lighting computation L(v, n) and the lighting factorizations N, R, NR, NRV, NRHD."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import homofac as hf
from homofac import sphere
from homofac.fit import pipeline
from homofac.target import Target
from homofac import light as envmod


def random_pairs(n, seed=0):
    p = hf.fit.sampling.random_pairs("lighting", n, seed)
    return jnp.asarray(p.a), jnp.asarray(p.b)


def test_white_lambert_under_uniform_radiance_is_one():
    env = envmod.uniform(1.0, resolution=32)
    n, v = random_pairs(500)
    out = hf.light.lighting(hf.brdf.lambert(kd=1.0), env, n, v)
    np.testing.assert_allclose(np.asarray(out), 1.0, atol=1e-5)


def test_white_lambert_uniform_float64(x64):
    env = envmod.uniform(1.0, resolution=24)
    n, v = random_pairs(200)
    out = hf.light.lighting(hf.brdf.lambert(kd=1.0), env, n.astype(jnp.float64), v.astype(jnp.float64))
    np.testing.assert_allclose(np.asarray(out), 1.0, atol=1e-9)


def test_gradient_sky_closed_form():
    """L(theta) = a + b cos(theta): white Lambert gives a + (2/3) b n_z."""
    a, b = 0.7, 0.5
    env = envmod.gradient_sky(a, b, resolution=48)
    n, v = random_pairs(400, seed=2)
    out = np.asarray(hf.light.lighting(hf.brdf.lambert(kd=1.0), env, n, v))
    want = a + 2.0 / 3.0 * b * np.asarray(n)[:, 2:3]
    np.testing.assert_allclose(out, np.broadcast_to(want, out.shape), atol=1e-3)


@pytest.mark.slow
def test_lighting_is_zero_for_invalid_pairs_and_uses_all_models():
    env = envmod.sun_sky(sun_direction=(0.3, 0.2, 0.9), sun_radiance=50.0, sun_angle_deg=5.0, resolution=8)
    n = jnp.array([[0.0, 0.0, 1.0]])
    v = jnp.array([[0.0, 0.0, -1.0]])
    for name in ("lambert", "phong", "modified_phong", "blinn_phong", "cook_torrance", "ggx", "ward"):
        b = hf.brdf.make(name)
        assert float(jnp.max(hf.light.lighting(b, env, n, v))) == 0.0
        val = hf.light.lighting(b, env, n, jnp.array([[0.0, 0.6, 0.8]]))
        assert np.all(np.isfinite(np.asarray(val))) and float(jnp.min(val)) > 0, name


@pytest.mark.slow
def test_diffuse_split_and_grouped_path_match_direct_sum(x64):
    """L = sum_k (kd/pi + f_spec(l_k, v)) L_k w_k(n): the diffuse part uses the exact texel weights even
    for texels whose centre is just below the horizon (where f, by convention, is 0); the grouped
    per-normal path gives the same numbers as the per-pair path."""
    from homofac.light.lighting import Lighting

    env = envmod.sun_sky(sun_direction=(0.3, -0.4, 0.8), sun_radiance=20.0, sun_angle_deg=8.0, resolution=8)
    b = hf.brdf.cook_torrance(kd=(0.3, 0.2, 0.1), ks=0.7, roughness=0.25, f0=(0.9, 0.6, 0.3))
    n, v = random_pairs(64, seed=5)
    n, v = n.astype(jnp.float64), v.astype(jnp.float64)
    fast = np.asarray(hf.light.lighting(b, env, n, v, horizon="centre"))  # the reference evaluates f at centres
    t, bb, nn = sphere.frame(n)
    wi = sphere.to_local(env.directions[None], t[:, None], bb[:, None], nn[:, None])
    wo = sphere.to_local(v, t, bb, nn)[:, None, :]
    spec = hf.brdf.cook_torrance(kd=0.0, ks=0.7, roughness=0.25, f0=(0.9, 0.6, 0.3))
    f = spec(wi, jnp.broadcast_to(wo, wi.shape)) + jnp.asarray([0.3, 0.2, 0.1]) / np.pi
    w = Lighting(None, env)._weights(n)
    slow = np.asarray(jnp.einsum("bl,blc,lc->bc", w, f, env.radiance))
    np.testing.assert_allclose(fast, slow, rtol=1e-10, atol=1e-12)
    # grouped: 4 normals x 16 views each, including invalid views (which give 0)
    views = jnp.asarray(sphere.normalize(jnp.asarray(np.random.default_rng(1).normal(size=(4, 16, 3)))))
    g = np.asarray(Lighting(b, env).grouped(n[:4], views))
    ref = np.asarray(hf.light.lighting(b, env, jnp.repeat(n[:4], 16, axis=0), views.reshape(-1, 3))).reshape(4, 16, 3)
    np.testing.assert_allclose(g, ref, rtol=1e-10, atol=1e-12)
    assert np.any(g == 0) and np.any(g > 0)


@pytest.mark.slow
def test_light_resolution_convergence():
    """Exact L(v, n) at light resolutions 16, 32, 64 converges: successive differences shrink."""
    path = hf.light.bundled("forest")
    b = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    n, v = random_pairs(64, seed=7)
    out = [np.asarray(hf.light.lighting(b, hf.light.load_environment(path, resolution=r), n, v)) for r in (16, 32, 64)]
    d1 = np.linalg.norm(out[1] - out[0]) / np.linalg.norm(out[2])
    d2 = np.linalg.norm(out[2] - out[1]) / np.linalg.norm(out[2])
    assert d2 < 0.6 * d1, (d1, d2)
    assert d2 < 0.02, (d1, d2)


def test_culling_stays_under_its_bound():
    env = hf.light.load_environment(hf.light.bundled("studio"), resolution=16)
    culled, info = hf.light.cull_lights(env, 1e-3)
    assert info["dropped"] > 0 and info["kept"] + info["dropped"] == env.directions.shape[0]
    assert np.all(np.asarray(info["dropped_power"]) <= 1e-3 * np.asarray(info["total_power"]).sum() + 1e-9)
    kd = 0.8
    b = hf.brdf.lambert(kd=kd)
    n, v = random_pairs(500, seed=3)
    full = np.asarray(hf.light.lighting(b, env, n, v))
    part = np.asarray(hf.light.lighting(b, culled, n, v))
    bound = kd / np.pi * np.asarray(info["dropped_power"])
    assert np.all(full - part <= bound + 1e-6) and np.all(full - part >= -1e-6)


# --- exact factorization cases -------------------------------------------------------------------


@pytest.mark.slow
def test_lambert_with_N_is_exact():
    env = hf.light.load_environment(hf.light.bundled("forest"), resolution=16)
    target = hf.light.lighting_target(hf.brdf.lambert(kd=(0.8, 0.6, 0.4)), env)
    # Matched resolutions: 64^2 textures sampled on their own texel grid (views sparse: N ignores them);
    # what remains is bilinear interpolation of a smooth map (2.6e-3 at 32, 4e-4 at 64).
    fac = pipeline.factorize(target, "N", mapper="dual_paraboloid", texture_size=64,
                             sampling={"kind": "texels", "size": 64, "view_size": 4, "validation": 3000},
                             solver={"laplacian": 0.05, "tolerance": 1e-7})
    assert fac.metrics["validation"]["float"]["nrmse"] < 1e-3, fac.metrics["validation"]["float"]


class PhongLobe(eqx.Module):
    """ks sum_k max(r . l_k, 0)^N L_k dw_k over the whole sphere (thesis eq. 41): depends on r only."""

    env: hf.light.Environment
    exponent: float = eqx.field(static=True)

    def __call__(self, n, v):
        r = sphere.reflect(v, n)
        c = jnp.maximum(r @ self.env.directions.T, 0.0) ** self.exponent
        return c @ (self.env.radiance * self.env.solid_angle[:, None])


@pytest.mark.slow
def test_phong_lobe_with_R_is_exact():
    env = hf.light.load_environment(hf.light.bundled("forest"), resolution=16)
    target = Target("lighting", PhongLobe(env, 4.0), "lighting")
    fac = pipeline.factorize(target, "R", mapper="dual_paraboloid", texture_size=64,
                             sampling={"kind": "texels", "size": 64, "view_size": 4, "validation": 3000},
                             solver={"laplacian": 0.05, "tolerance": 1e-7})
    assert fac.metrics["validation"]["float"]["nrmse"] < 1e-3, fac.metrics["validation"]["float"]


GOLD = dict(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
# Measured on the bundled forest at these sizes (validation nrmse NR 0.4695, NRV 0.4591 with the exact
# clamped-cosine texel weights; LSMR reaches the direct optimum here, so this is the parametrization's own
# error at 16^2 x 2 textures, not the solver's); the bounds keep ~10% margin so a regression fails while
# float noise does not. Reproduce: the test body, printing fac.metrics["validation"]["float"].
GOLD_BOUNDS = {"NR": 0.52, "NRV": 0.51}


@pytest.mark.slow
@pytest.mark.parametrize("param", ["NR", "NRV"])
def test_gold_in_forest_stays_under_measured_bound(param):
    env = hf.light.load_environment("forest", resolution=12)
    target = hf.light.lighting_target(hf.brdf.cook_torrance(**GOLD), env)
    fac = pipeline.factorize(target, param, mapper="dual_paraboloid", texture_size=16,
                             sampling={"kind": "texels", "size": 12, "validation": 4000})
    val = fac.metrics["validation"]["float"]
    assert val["nrmse"] < GOLD_BOUNDS[param], val
    assert fac.solver["converged"]


@pytest.mark.slow
@pytest.mark.parametrize("mapper", ["dual_paraboloid", "cube", "octahedral"])
def test_nrhd_runs_on_every_sphere_mapper(mapper):
    env = envmod.sun_sky(sun_direction=(0.4, 0.3, 0.85), sun_radiance=30.0, sun_angle_deg=6.0, resolution=8)
    target = hf.light.lighting_target(hf.brdf.cook_torrance(**GOLD), env, parametrization="NRHD")
    assert "dominant" in target.context
    fac = pipeline.factorize(target, "NRHD", mapper=mapper, texture_size=8,
                             sampling={"kind": "texels", "size": 8, "validation": 1000})
    assert len(fac.textures) == 4
    assert np.isfinite(fac.metrics["validation"]["float"]["nrmse"])


def test_parabolic_is_refused_for_lighting():
    env = envmod.uniform(1.0, resolution=4)
    target = hf.light.lighting_target(hf.brdf.lambert(), env)
    with pytest.raises(hf.HomofacError, match="hemisphere"):
        pipeline.factorize(target, "N", mapper="parabolic", texture_size=8)


# --- gradients ------------------------------------------------------------------------------------


def _grad_setup():
    from homofac.fit.differentiable import fit_error

    env = envmod.sun_sky(sun_direction=(0.3, 0.2, 0.9), sun_radiance=10.0, sun_angle_deg=15.0, resolution=4)
    tr = hf.fit.sampling.sample_pairs("lighting", "texels", 6, mapper="dual_paraboloid")
    va = hf.fit.sampling.random_pairs("lighting", 300, 9)
    a, b = jnp.asarray(tr.a, jnp.float64), jnp.asarray(tr.b, jnp.float64)
    vaa, vab = jnp.asarray(va.a, jnp.float64), jnp.asarray(va.b, jnp.float64)

    def err(roughness, radiance):
        brdf = hf.brdf.cook_torrance(kd=(0.2, 0.2, 0.2), ks=1.0, roughness=roughness, f0=(0.9, 0.7, 0.3))
        e = eqx.tree_at(lambda x: x.radiance, env, radiance)
        target = hf.light.lighting_target(brdf, e)
        return fit_error(target, "NR", "octahedral", 6, a, b, vaa, vab, metric="rms", laplacian=0.5,
                         tolerance=1e-12, max_steps=5000)

    return err, jnp.asarray(env.radiance, jnp.float64)


@pytest.mark.slow
def test_gradient_wrt_roughness_matches_finite_difference(x64):
    err, rad = _grad_setup()
    g = jax.grad(err, argnums=0)(jnp.float64(0.35), rad)
    h = 1e-5
    fd = (err(0.35 + h, rad) - err(0.35 - h, rad)) / (2 * h)
    assert np.isfinite(float(g)) and abs(float(g)) > 0
    assert float(g) == pytest.approx(float(fd), rel=1e-4, abs=1e-9)


@pytest.mark.slow
def test_gradient_wrt_environment_pixels_matches_finite_difference(x64):
    err, rad = _grad_setup()
    g = jax.grad(err, argnums=1)(jnp.float64(0.35), rad)
    assert g.shape == rad.shape and np.all(np.isfinite(np.asarray(g)))
    k = int(np.argmax(np.abs(np.asarray(g)).sum(axis=1)))
    for c in range(3):
        h = 1e-5 * max(1.0, float(rad[k, c]))
        e = jnp.zeros_like(rad).at[k, c].set(h)
        fd = (err(0.35, rad + e) - err(0.35, rad - e)) / (2 * h)
        assert float(g[k, c]) == pytest.approx(float(fd), rel=1e-4, abs=1e-9)


@pytest.mark.slow
def test_grouped_path_at_full_size_matches_unfused_reference(x64):
    """Large jitted evaluation (6144 lights, hundreds of views) equals an op-by-op (unfused) float64
    evaluation of the same sum: guards against XLA CPU fusion miscompiles like the one that hit the
    texel moments (see light.geometry.texel_moments)."""
    from homofac.light.lighting import Lighting

    env = hf.light.load_environment("forest", resolution=32)
    b = hf.brdf.cook_torrance(**GOLD)
    g = hf.fit.sampling.grouped_random(64 * 96, 4)
    # the fast path as it runs by default: float32, jitted
    f32 = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32) if hasattr(x, "dtype") and x.dtype == jnp.float64 else x, env)
    fast = np.asarray(jax.jit(lambda e, n, v: Lighting(b, e, horizon="centre").grouped(n, v))(f32, jnp.asarray(g.normals, jnp.float32),
                                                                            jnp.asarray(g.views, jnp.float32)))
    w = np.asarray(Lighting(None, env)._weights(jnp.asarray(g.normals[:3])), np.float64)
    spec = hf.brdf.MODELS["cook_torrance"].fn
    params = {k: np.asarray(v, np.float64) for k, v in b.params.items()}
    params_spec = {**params, "kd": np.zeros(3)}
    dirs = np.asarray(env.directions, np.float64)
    rad = np.asarray(env.radiance, np.float64)
    with jax.disable_jit():
        for i in range(3):
            n = g.normals[i].astype(np.float64)
            t, bb, nn = (np.asarray(x, np.float64) for x in sphere.frame(jnp.asarray(n)))
            frame = np.stack([t, bb, nn], axis=1)
            wi = dirs @ frame
            views = g.views[i][g.mask[i]][:8].astype(np.float64)
            got = fast[i][g.mask[i]][:8]
            for j, v in enumerate(views):
                wo = np.broadcast_to(v @ frame, wi.shape)
                # the raw model function knows no horizon: lights below it (wi.z <= 0, some of which
                # straddle it and so have w_k > 0) contribute 0, as BRDF.__call__ makes them
                f = np.asarray(spec({k: jnp.asarray(x) for k, x in params_spec.items()}, jnp.asarray(wi), jnp.asarray(wo)))
                f = np.where((wi[:, 2:3] > 0) & (wo[:, 2:3] > 0), f, 0.0)
                ref = (f * (w[i][:, None] * rad)).sum(axis=0) + params["kd"] / np.pi * (w[i] @ rad)
                # float32 fast path vs float64 reference: the sum of ~3000 terms with grazing-angle
                # peaks of 1/(4 n.l n.v) carries ~1e-4 relative float32 rounding; a miscompile is O(1).
                np.testing.assert_allclose(got[j], ref, rtol=2e-3)
