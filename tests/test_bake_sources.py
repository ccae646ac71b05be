"""The bake's analytic source: found by the rule of bake/sources.py, taken out of the map, added back as a light
with the glTF lobes (GGX widened by its radius); bake.json schema 2 ``sources`` (schema 1 read as none; bad
entries refused)."""

from __future__ import annotations

import dataclasses
import json

import jax.numpy as jnp
import numpy as np
import pytest

import homofac as hf
from homofac.bake import shader
from homofac.bake.sources import (BLUR, CORE, CORE_PIXEL, MAX_SOURCES, SPLIT, SPREAD, Source, box_blob, box_widths,
                                  brightest_source, core_and_halo, core_factor, core_widths, principal_axes, source_terms,
                                  widened_ratio, with_boxes, with_cores)
from homofac.errors import HomofacError
from homofac.io.exr import read_exr
from homofac.light import Environment
from homofac.light.integrals import integrals
from homofac.light.reference import reference_integrals, source_map
from helpers import BAKE_SIZES, optimized_xla, visible_pairs as pairs
from test_bake import as_schema_4, check_glsl_terms, check_glslang, check_msl, check_wgsl

TINY = dict(layers=3, **BAKE_SIZES)


def sun_environment(r=16, seed=3):
    """A uniform 0.1 sky with one texel 1000x brighter: (environment, sun texel index)."""
    env = hf.light.uniform(0.1, r)
    i = 6 * r * r // 2 + r // 2 + seed
    rad = np.asarray(env.radiance).copy()
    rad[i] = (100.0, 80.0, 60.0)
    return Environment(env.directions, jnp.asarray(rad), env.solid_angle, env.info, env.corners, env.moments), i


@pytest.fixture(scope="module")
def sun_bake():
    with optimized_xla():
        return hf.bake(sun_environment()[0], preset="fast", **TINY)


def test_the_rule_finds_a_compact_source_and_leaves_a_uniform_map():
    env, i = sun_environment()
    rest, src, share = brightest_source(env)
    dw = float(env.solid_angle[i])
    np.testing.assert_allclose(src.direction, np.asarray(env.directions[i]), atol=1e-6)
    np.testing.assert_allclose(src.power, (np.array([100.0, 80.0, 60.0]) - 0.1) * dw, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(rest.radiance), 0.1, rtol=1e-5)  # the texel is filled with the ring's sky
    lum = np.array([0.2126, 0.7152, 0.0722])
    power = np.asarray(src.power) @ lum
    np.testing.assert_allclose(share, power / (0.1 * 4 * np.pi + power), rtol=1e-4)
    assert src.radius < 1e-6
    for flat in (hf.light.uniform(1.0, 8), hf.light.uniform((0.2, 0.5, 1.0), 16)):
        same, none, s = brightest_source(flat)
        assert none is None and s < 1e-6 and same is flat


def test_source_terms_are_the_integrals_of_a_directional_light(x64):
    """The point light's (I_d, I_A, I_B) equal the pinned integrals of the same directional light."""
    ell = np.array([0.3, -0.4, 0.866])
    ell /= np.linalg.norm(ell)
    power = (1.5, 1.0, 0.5)
    env = hf.light.uniform(0.0, 4, lights=[{"type": "directional", "direction": ell.tolist(), "irradiance": list(power)}])
    n, v = pairs(300, seed=2)
    for rho in (0.05, 0.3, 0.9):
        ref = np.asarray(integrals(env, jnp.asarray(n), jnp.asarray(v), rho))
        got = np.asarray(source_terms((Source(tuple(ell), power, 0.0),), n, v, rho))
        np.testing.assert_allclose(got, ref, rtol=2e-3, atol=1e-5 * np.abs(ref).max())


def test_a_wide_source_is_a_lobe_as_wide_as_the_source_and_the_gpu_reads_it(sun_bake):
    """Near a sun at low roughness the source's lobe (a Gaussian core of the sun's size and a widened GGX tail)
    reads the radiance the reference (the source map read bilinearly) reads within 15 % (measured 0.061; GGX
    widened alone read 0.31, a point light 4.0: it overshoots several times); I_d is the point light's; the
    shader's lobe equals ``source_terms``."""
    env = hf.light.load_environment("city", 64)
    _, sun, _ = brightest_source(env)
    assert sun.radius > 0.005
    d = np.asarray(sun.direction)
    rng = np.random.default_rng(0)
    # reflected directions within 0.4 degrees of the sun, normals cosine-distributed about them, roughness 0.06
    t = np.cross(d, (1.0, 0, 0))
    t /= np.linalg.norm(t)
    b = np.cross(d, t)
    ang, phi = np.radians(0.4) * np.sqrt(rng.uniform(0, 1, 48)), rng.uniform(0, 2 * np.pi, 48)
    r = np.cos(ang)[:, None] * d + np.sin(ang)[:, None] * (np.cos(phi)[:, None] * t + np.sin(phi)[:, None] * b)
    cos = np.sqrt(rng.uniform(0.3, 1, 48))
    u = np.cross(r, (0, 0, 1.0))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    n = cos[:, None] * r + np.sqrt(1 - cos * cos)[:, None] * u
    v = 2 * np.sum(n * r, 1)[:, None] * n - r
    ref = reference_integrals(source_map(read_exr(hf.light.bundled("city")), "city"), n, v, 0.06, samples=4096)
    point = np.asarray(source_terms((sun._replace(radius=0.0),), n, v, 0.06))
    wide = np.asarray(source_terms((sun,), n, v, 0.06))
    err = [np.linalg.norm(x[:, 1] - ref[:, 1]) / np.linalg.norm(ref[:, 1]) for x in (point, wide)]
    assert err[0] > 2 and err[1] < 0.15, err
    np.testing.assert_allclose(wide[:, 0], point[:, 0], rtol=1e-6)
    assert SPREAD > 0
    wide_bake = dataclasses.replace(sun_bake, sources=(sun_bake.sources[0]._replace(radius=0.05),))
    n2, v2 = pairs(500, seed=5)
    ell = np.asarray(wide_bake.sources[0].direction)  # 8 pairs mirroring the source, so the core is read
    n2[:8] = ell + 0.8 * n2[:8]
    n2[:8] /= np.linalg.norm(n2[:8], axis=1, keepdims=True)
    v2[:8] = 2 * (n2[:8] @ ell)[:, None] * n2[:8] - ell
    assert not np.allclose(np.asarray(wide_bake.terms(n2, v2, 0.05)), np.asarray(sun_bake.terms(n2, v2, 0.05)))
    pytest.importorskip("moderngl")
    check_glsl_terms(wide_bake, n2, v2, (0.05, 0.3), 1e-4)


def test_an_elongated_source_keeps_its_axes_and_its_core_reads_them(tmp_path, sun_bake):
    """principal_axes recovers an anisotropic Gaussian's semi-axes (sqrt 2 x its standard deviations, long one
    first); the core of a source with those axes reads higher along the long axis than along the short one at the
    same angle, and a round source with axes of its radius reads as one without; bake.json keeps the axes."""
    rng = np.random.default_rng(0)
    ell = np.array([0.3, -0.4, 0.866]) / np.linalg.norm([0.3, -0.4, 0.866])
    e1 = np.cross(ell, (0, 0, 1.0))
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(ell, e1)
    pts = ell + rng.normal(size=(100000, 1)) * 0.01 * e1 + rng.normal(size=(100000, 1)) * 0.03 * e2
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    axes = principal_axes(pts, np.ones(len(pts)), ell)
    np.testing.assert_allclose(np.linalg.norm(axes, axis=1), np.sqrt(2) * np.array([0.03, 0.01]), rtol=0.02)
    assert abs(np.dot(axes[0], e2)) > 0.99 * np.linalg.norm(axes[0])
    src = Source(tuple(ell), (1.0, 1.0, 1.0), 0.03, axes)
    m = np.stack([np.cos(0.02) * ell + np.sin(0.02) * e for e in (e2, e1)])  # 0.02 rad along the long, short axis
    n = np.stack([ell, ell])
    v = 2 * np.sum(n * m, 1)[:, None] * n - m  # the mirror direction of v about n = l is m
    a = np.asarray(source_terms((src,), n, v, 0.05))[:, 1, 0]
    assert a[0] > 2 * a[1], a  # exp(-0.18) against exp(-1.5) here
    n2, v2 = pairs(200, seed=6)
    iso = Source(tuple(ell), (1.0, 1.0, 1.0), 0.02)
    round_axes = iso._replace(axes=(tuple(0.02 * e1), tuple(0.02 * e2)))
    np.testing.assert_allclose(np.asarray(source_terms((round_axes,), n2, v2, 0.05)),
                               np.asarray(source_terms((iso,), n2, v2, 0.05)), rtol=1e-4, atol=1e-6)
    bk = dataclasses.replace(sun_bake, sources=(src,))
    back = hf.load(bk.save(tmp_path / "bk"))
    assert back.sources == (src,) and "axes" in back.describe()


def test_a_box_core_keeps_its_power_and_moments_reduces_to_the_gaussian_and_the_gpu_reads_it(tmp_path, sun_bake):
    """The core's box blurred by a Gaussian (box_blob) under a coupled G (g12 != 0): unit integral and G / 2 as
    its covariance; as its half-widths go to 0 the built Gaussian exp(-t^T G^-1 t) / (pi sqrt det G), and a
    source with a tiny box shades as the Gaussian one; a wide box is flatter at the centre and reaches as far.
    box_widths: a compact source (no wider than the pixels' blur) keeps the Gaussian, a wide one's box holds the
    variance above BLUR pixel^2. bake.json keeps the box; every shader language compiles the box source (glslang, the MSL stand-in, the WGSL on wgpu equal to the CPU)
    and the GLSL reads it as source_terms does."""
    g11, g12, g22 = 4e-4, 1.5e-4, 2e-4
    x = np.linspace(-0.15, 0.15, 601)
    dx = x[1] - x[0]
    t1, t2 = np.meshgrid(x, x, indexing="ij")
    det = g11 * g22 - g12 * g12
    gauss = np.exp(-(g22 * t1 * t1 - 2 * g12 * t1 * t2 + g11 * t2 * t2) / det) / (np.pi * np.sqrt(det))
    for b in ((0.0, 0.0), (1e-6, 2e-6), (0.012, 0.004), (0.006, 0.01)):  # G minus the box: positive definite
        k = np.asarray(box_blob(jnp.asarray(t1), jnp.asarray(t2), g11, g12, g22, *b), np.float64)
        assert abs(k.sum() * dx * dx - 1) < 1e-4, b
        cov = [2 * (k * p).sum() * dx * dx for p in (t1 * t1, t1 * t2, t2 * t2)]
        np.testing.assert_allclose(cov, (g11, g12, g22), rtol=2e-3, err_msg=str(b))
        if max(b) < 1e-5:
            np.testing.assert_allclose(k, gauss, atol=1e-5 * gauss.max())
        else:
            assert k.max() < 0.995 * gauss.max(), b  # flatter at the centre for the same covariance
    ell = np.array([0.3, -0.4, 0.866]) / np.linalg.norm([0.3, -0.4, 0.866])
    e1 = np.cross(ell, (0, 0, 1.0))
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(ell, e1)
    src = Source(tuple(ell), (1.0, 0.8, 0.6), 0.03, (tuple(0.04 * e2), tuple(0.02 * e1)))
    pixel = np.pi / 128
    assert box_widths(src._replace(axes=(tuple(0.001 * e2), tuple(0.001 * e1))), pixel) == ()
    b = np.asarray(box_widths(src, pixel))
    np.testing.assert_allclose(b * b / 3 + BLUR * pixel * pixel, (CORE * np.array([0.04, 0.02])) ** 2 / 2, rtol=1e-6)
    n, v = pairs(400, seed=7)
    n[:40] = ell + 0.05 * n[:40]  # pairs mirroring near the source, so the core is read
    n[:40] /= np.linalg.norm(n[:40], axis=1, keepdims=True)
    m = ell + 0.02 * np.random.default_rng(1).normal(size=(40, 3))
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    v[:40] = 2 * np.sum(n[:40] * m, 1)[:, None] * n[:40] - m
    gauss_terms = np.asarray(source_terms((src,), n, v, 0.05))
    tiny = np.asarray(source_terms((src._replace(box=(1e-7, 1e-7)),), n, v, 0.05))
    np.testing.assert_allclose(tiny, gauss_terms, rtol=1e-3, atol=1e-4 * np.abs(gauss_terms).max())
    boxed = src._replace(box=tuple(b))
    assert not np.allclose(np.asarray(source_terms((boxed,), n, v, 0.05)), gauss_terms, rtol=1e-2)
    bk = dataclasses.replace(sun_bake, sources=(boxed,))
    out = bk.save(tmp_path / "box")
    back = hf.load(out)
    assert back.sources == (boxed,) and "box" in back.describe()
    doc = json.loads((out / "bake.json").read_text())
    assert doc["schema_version"] == 8 and doc["sources"][0]["box"] == list(boxed.box)
    del doc["sources"][0]["box"]
    (out / "bake.json").write_text(json.dumps({**doc, "schema_version": 7}))
    assert hf.load(out).sources == (src,)  # schema 7: Gaussian cores
    skipped = []
    for check in [*(lambda lang=lang: check_glslang(bk, lang, tmp_path, y_ups=(False,)) for lang in ("glsl", "glsl_es", "hlsl")),
                  lambda: check_msl(bk, tmp_path, y_ups=(False,)), lambda: check_wgsl(bk, 400, (1e-4, 2e-3))]:
        try:
            check()
        except pytest.skip.Exception as e:
            skipped.append(str(e))
    pytest.importorskip("moderngl")
    check_glsl_terms(bk, n, v, (0.05, 0.3), 1e-4)
    if skipped:
        pytest.skip("; ".join(skipped))


def test_the_widening_per_axis_keeps_the_lobe_normalized_and_follows_the_plane_of_incidence():
    """The tail's anisotropic GGX (widened_ratio x GGX D) integrates to 1 over projected half vectors at unequal
    widths (the source's power is unchanged); equal widths read Karis's isotropic widening; the core's covariance
    is the lobe's 4 alpha^2 in the plane of incidence and 4 (n.v)^2 alpha^2 across it; and at a grazing view a
    Gaussian source moved across and along the plane of incidence reads the point light's lobe averaged over the
    source within 20 %, and so does the ratio of the two (across, the lobe is n.v narrower in light directions)."""
    a2, sx2, sy2 = 0.01, 0.02, 0.2
    th = np.linspace(0, np.pi / 2, 4001)[:, None]
    ph = np.linspace(0, 2 * np.pi, 721)[None, :]
    nh2, hx2, hy2 = np.cos(th) ** 2, (np.sin(th) * np.cos(ph)) ** 2, (np.sin(th) * np.sin(ph)) ** 2
    d = a2 / (np.pi * (a2 * nh2 + hx2 + hy2) ** 2) * np.asarray(widened_ratio(a2, sx2, sy2, nh2, hx2, hy2))
    total = np.trapezoid(np.trapezoid(d * np.cos(th) * np.sin(th), ph[0], axis=1), th[:, 0])
    np.testing.assert_allclose(total, 1.0, rtol=2e-3)
    aw, sin2 = a2 + sx2, hx2 + hy2
    np.testing.assert_allclose(np.asarray(widened_ratio(a2, sx2, sx2, nh2, hx2, hy2)),
                               aw / a2 * ((a2 * nh2 + sin2) / (aw * nh2 + sin2)) ** 2, rtol=1e-5)
    x = 0.3
    g11, g12, g22 = core_widths((0.0, 0.0), 0.0, np.sqrt(1 - x * x), a2)  # u = n x v along e2
    np.testing.assert_allclose((g11, g12, g22), (4 * a2, 0.0, 4 * x * x * a2), atol=1e-12)
    # a round source of radius 0.02 (its core: a Gaussian of RMS angle CORE x 0.02) seen at n.v 0.3, moved 0.03 rad
    # across and along the plane of incidence: the model against the point light's lobe averaged over that Gaussian
    # (n, v rotated with each of its directions); the isotropic rule read up to 28 % off (roughness 0.2, along)
    n, v = np.array([0.0, 0.0, 1.0]), np.array([np.sqrt(1 - x * x), 0.0, x])
    ell = np.array([-np.sqrt(1 - x * x), 0.0, x])
    e1, e2 = np.array([0.0, 1.0, 0.0]), np.array([x, 0.0, np.sqrt(1 - x * x)])  # across, along; both normal to ell
    for rho in (0.1, 0.2):
        got, ref = [], []
        rng = np.random.default_rng(1)
        for e, other in ((e1, e2), (e2, e1)):
            ls = np.cos(0.03) * ell + np.sin(0.03) * e
            got.append(float(np.asarray(source_terms((Source(tuple(ls), (1.0, 1.0, 1.0), 0.02),), n[None], v[None], rho))[0, 1, 0]))
            f1 = np.cross(ls, other)
            f1 /= np.linalg.norm(f1)
            g = rng.normal(size=(40000, 2)) * CORE * 0.02 / np.sqrt(2)
            lk = ls + g[:, :1] * f1 + g[:, 1:] * np.cross(ls, f1)
            lk /= np.linalg.norm(lk, axis=1, keepdims=True)
            k = np.cross(lk, ls)  # the rotation taking lk onto ls (Rodrigues), applied to n and v
            sn, cs = np.linalg.norm(k, axis=1, keepdims=True), (lk @ ls)[:, None]
            k = k / np.maximum(sn, 1e-12)
            nk, vk = (p * cs + np.cross(k, p) * sn + k * (k @ p)[:, None] * (1 - cs) for p in (n, v))
            point = Source(tuple(ls), (1.0, 1.0, 1.0), 0.0)
            ref.append(float(np.mean(np.asarray(source_terms((point,), nk, vk, rho))[:, 1, 0])))
        np.testing.assert_allclose(got, ref, rtol=0.15)
        np.testing.assert_allclose(got[0] / got[1], ref[0] / ref[1], rtol=0.15)


def test_bake_takes_the_source_out_and_adds_it_back(sun_bake, uniform_bake):
    env, i = sun_environment()
    with_src = sun_bake  # hf.bake(env, preset="fast", **TINY) on this environment
    with optimized_xla():  # helpers.optimized_xla: a bake runs long at -O0
        without = hf.bake(env, preset="fast", analytic_source=False, **TINY)
    assert len(with_src.sources) == 1 and without.sources == ()
    assert "analytic source: direction" in with_src.describe() and "analytic source: none" in without.describe()
    n, v = pairs(400, seed=4)
    ref = np.asarray(integrals(env, jnp.asarray(n), jnp.asarray(v), 0.2))
    err = [np.linalg.norm(np.asarray(b.terms(n, v, 0.2))[:, 1] - ref[:, 1]) / np.linalg.norm(ref[:, 1]) for b in (with_src, without)]
    assert err[0] < 0.5 * err[1]  # a sun in an 8-texel map is the map's error; as a point light it is exact
    assert uniform_bake.sources == ()  # hf.bake(hf.light.uniform(1.0, 8), preset="fast", **TINY)


def test_bake_takes_a_second_source_from_the_map_the_first_left():
    """Two suns far apart, each holding more than MIN_SHARE: the bake takes both out (brightest first) and adds
    both back; the second's power is what its texel holds above the sky."""
    env, i = sun_environment()
    rad = np.asarray(env.radiance).copy()
    j = i + 3 * 16 * 16 // 2  # another face's texel
    rad[j] = (40.0, 50.0, 60.0)
    two = Environment(env.directions, jnp.asarray(rad), env.solid_angle, env.info, env.corners, env.moments)
    with optimized_xla():  # helpers.optimized_xla: a bake runs long at -O0
        b = hf.bake(two, preset="fast", **TINY)
    assert len(b.sources) == 2
    np.testing.assert_allclose(b.sources[0].direction, np.asarray(env.directions[i]), atol=1e-6)
    np.testing.assert_allclose(b.sources[1].direction, np.asarray(env.directions[j]), atol=1e-6)
    np.testing.assert_allclose(b.sources[1].power, (np.array([40.0, 50.0, 60.0]) - 0.1) * float(env.solid_angle[j]), rtol=1e-4)
    assert b.info["analytic_source"]["count"] == 2


def test_core_and_halo_split_a_peaked_source_into_two_gaussians_of_its_power():
    """A sun of semi-axes 0.01 x 0.005 rad in a dim round halo 5x wider (its texels 1/100 as bright at the centre):
    the core is the sun (its axes within 10 % of the sun's cut at 1/SPLIT of its peak), the halo wider, the powers sum to the source's and share it as the
    texels' weights do; a flat source (every texel at least 1/SPLIT of the brightest) stays one Gaussian."""
    g = np.linspace(-0.12, 0.12, 97)
    x, y = np.meshgrid(g, g)
    d = np.stack([x.ravel(), y.ravel(), np.ones(x.size)], 1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    sun = np.exp(-(x / 0.01) ** 2 - (y / 0.005) ** 2).ravel()
    halo = 0.01 * np.exp(-(x * x + y * y) / 0.05 ** 2).ravel()
    w = sun + halo
    keep = w > 1e-6 * w.max()
    d, w, sun = d[keep], w[keep], sun[keep]
    src = Source((0.0, 0.0, 1.0), (2.0, 1.0, 0.5), 0.02, principal_axes(d, w, np.array([0.0, 0.0, 1.0])))
    core, out = core_and_halo(src, d, w)
    np.testing.assert_allclose(np.add(core.power, out.power), src.power, rtol=1e-9)
    np.testing.assert_allclose(np.asarray(core.power) / np.asarray(src.power), w[w >= w.max() / SPLIT].sum() / w.sum(), rtol=1e-9)
    c = np.log(SPLIT)  # the core is the sun cut at 1/SPLIT of its peak: its r^2 / a^2 ~ Exp(1) truncated at c
    np.testing.assert_allclose([np.linalg.norm(a) for a in core.axes], np.array([0.01, 0.005]) * np.sqrt(1 - c / np.expm1(c)), rtol=0.1)
    assert core.radius < 0.5 * out.radius and min(np.linalg.norm(a) for a in out.axes) > 0.02
    assert np.allclose(core.direction, (0.0, 0.0, 1.0), atol=1e-6) and np.allclose(out.direction, (0.0, 0.0, 1.0), atol=1e-6)
    flat = (x * x + y * y).ravel()[keep] < 0.02 ** 2
    assert core_and_halo(src, d[flat], np.ones(int(flat.sum()))) == (src,)


def test_each_core_is_its_texels_width_plus_a_fixed_part_of_the_source_pixel():
    """core_factor: the core's mean width g x factor = g + CORE_PIXEL pixel (g the geometric mean of the semi-axes, a
    round source its radius, at least a quarter pixel), so a sub-pixel sun's core is wider in its own units than a
    softbox's and the factor tends to 1 as the light grows; the box then takes that core's variance."""
    pixel = np.pi / 128
    ell = np.array([0.3, -0.4, 0.866]) / np.linalg.norm([0.3, -0.4, 0.866])
    e1 = np.cross(ell, (0, 0, 1.0))
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(ell, e1)
    factors = []
    for a1, a2 in ((0.002, 0.001), (0.01, 0.005), (0.04, 0.01), (0.1, 0.1)):
        src = Source(tuple(ell), (1.0, 0.8, 0.6), float(np.hypot(a1, a2) / np.sqrt(2)), (tuple(a1 * e2), tuple(a2 * e1)))
        g = np.sqrt(a1 * a2)
        f = core_factor(src, pixel)
        np.testing.assert_allclose(f * max(g, pixel / 4), max(g, pixel / 4) + CORE_PIXEL * pixel, rtol=1e-9)
        factors.append(f)
        (boxed,) = with_boxes(with_cores((src,), pixel), pixel)
        assert boxed.core == f
        if boxed.box:  # the box and its Gaussian hold the core's own variance along each axis
            np.testing.assert_allclose(np.asarray(boxed.box) ** 2 / 3 + BLUR * pixel * pixel,
                                       np.maximum((f * np.array([a1, a2])) ** 2 / 2, BLUR * pixel * pixel), rtol=1e-6)
    assert factors == sorted(factors, reverse=True) and factors[0] == pytest.approx(1 + 4 * CORE_PIXEL) and factors[-1] < 1.03
    round_ = Source(tuple(ell), (1.0, 1.0, 1.0), 0.02)
    assert core_factor(round_, pixel) * 0.02 == pytest.approx(0.02 + CORE_PIXEL * pixel)
    assert core_factor(round_._replace(radius=0.0), pixel) == pytest.approx(1 + 4 * CORE_PIXEL)  # a point: the floor


def test_the_bake_takes_up_to_bake_json_s_eight_sources(tmp_path):
    """Nine suns far apart, each holding more than MIN_SHARE of what the others leave: the bake takes eight (the
    format's limit, MAX_SOURCES; a softbox-lit studio takes eight cores), brightest first, and they round-trip."""
    env = hf.light.uniform(0.1, 16)
    d = np.asarray(env.directions)
    targets = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
                        [1, 1, 1], [-1, -1, 1], [1, -1, -1]], np.float64)
    texels = [int(np.argmax(d @ (t / np.linalg.norm(t)))) for t in targets]
    rad = np.asarray(env.radiance).copy()
    for k, j in enumerate(texels):
        rad[j] = 60.0 - k
    suns = Environment(env.directions, jnp.asarray(rad), env.solid_angle, env.info, env.corners, env.moments)
    with optimized_xla():  # helpers.optimized_xla: a bake runs long at -O0
        b = hf.bake(suns, preset="fast", **TINY)
    assert b.info["analytic_source"]["lights"] == MAX_SOURCES == 8 and len(b.sources) == 8  # one-texel suns: a core each
    np.testing.assert_allclose([s.direction for s in b.sources], d[texels[:8]], atol=1e-6)
    assert hf.load(b.save(tmp_path / "bk")).sources == b.sources


def test_round_trip_and_schema_1_reads_as_no_sources(sun_bake, tmp_path):
    out = sun_bake.save(tmp_path / "bk")
    doc = json.loads((out / "bake.json").read_text())
    assert doc["schema_version"] == 8 and len(doc["sources"]) == 1
    # the sun's own core factor (one 16-face texel: the floor's, 1 + 4 CORE_PIXEL), written as baked
    assert doc["sources"][0]["core"] == sun_bake.sources[0].core == pytest.approx(core_factor(sun_bake.sources[0], np.pi / 32))
    back = hf.load(out)
    assert back.sources == sun_bake.sources
    n, v = pairs(100, seed=8)
    np.testing.assert_allclose(np.asarray(back.terms(n, v, 0.3)), np.asarray(sun_bake.terms(n, v, 0.3)), rtol=3e-3, atol=1e-4)
    # a bake written in the previous format (schema 1, no field): the maps alone
    old = {k: val for k, val in as_schema_4(doc, 1).items() if k != "sources"}
    (out / "bake.json").write_text(json.dumps(old))
    v1 = hf.load(out)
    assert v1.sources == ()
    maps = np.asarray(sun_bake.terms(n, v, 0.3)) - np.asarray(source_terms(sun_bake.sources, n, v, 0.3))
    np.testing.assert_allclose(np.asarray(v1.terms(n, v, 0.3)), maps, rtol=3e-3, atol=1e-4)
    assert "hf_source" not in shader.source(v1) and "hf_source" in shader.source(sun_bake)


def test_a_bake_reads_with_the_core_it_was_baked_with(sun_bake, tmp_path):
    """bake.json schema 8 records each source's core width factor; a schema-7 bake.json (no ``core``) reads with
    the factor of the code that wrote it: 1.2 with the twentieth session's ``info.analytic_source.lights``, else
    1.15. The factor changes what the source reads at its mirror direction (a wider core, a lower peak)."""
    out = sun_bake.save(tmp_path / "bk")
    doc = json.loads((out / "bake.json").read_text())
    doc["sources"][0]["core"] = 1.5
    (out / "bake.json").write_text(json.dumps(doc))
    assert hf.load(out).sources[0].core == 1.5
    old = json.loads(json.dumps(doc))
    old["schema_version"] = 7
    del old["sources"][0]["core"], old["plan"]["block_size"]
    (out / "bake.json").write_text(json.dumps(old))
    assert "lights" in old["info"]["analytic_source"] and hf.load(out).sources[0].core == 1.2
    del old["info"]["analytic_source"]["lights"]
    (out / "bake.json").write_text(json.dumps(old))
    back = hf.load(out)
    assert back.sources[0].core == 1.15 and back.plan.block == back.plan.max_size
    ell = np.asarray(sun_bake.sources[0].direction)
    n = np.broadcast_to(ell, (1, 3))  # looking straight down the source: the core's peak
    peak = [float(np.asarray(source_terms((s._replace(radius=0.02, axes=(), core=c),), n, n, 0.05))[0, 1].sum())
            for s in sun_bake.sources[:1] for c in (1.15, 1.5)]
    assert peak[0] > 1.2 * peak[1]


@pytest.mark.parametrize("field, value", [
    ("power", [float("nan"), 1.0, 1.0]), ("core", -1.0), ("core", 100.0), ("power", [1.0, -1.0, 1.0]), ("direction", [1.0, 0.0]),
    ("direction", [2.0, 0.0, 0.0]), ("radius", -1.0), ("axes", [[0.01, 0.0, 0.0]]),
    ("axes", [[0.01, 0.0, 0.0], [float("nan"), 0.0, 0.0]]), ("box", [0.01, -1.0]), ("box", [0.01]),
])
def test_bad_sources_are_refused_in_one_line(sun_bake, tmp_path, field, value):
    out = sun_bake.save(tmp_path / "bk")
    doc = json.loads((out / "bake.json").read_text())
    doc["sources"][0][field] = value
    (out / "bake.json").write_text(json.dumps(doc).replace("NaN", "1e400"))
    with pytest.raises(HomofacError) as e:
        hf.load(out)
    assert "\n" not in str(e.value) and "sources" in str(e.value)


def test_cli_prints_the_source_and_turns_it_off(tmp_path, capsys):
    from homofac.app import bake_cli
    flags = ["--preset", "fast", "--layers", "3", "--max-size", "8", "--nv-size", "8", "--samples", "64",
             "--data-resolution", "4", "--diffuse-size", "8"]
    assert bake_cli.main(["interior", "--out", str(tmp_path / "a"), *flags]) == 0
    assert "analytic source: direction" in capsys.readouterr().out
    assert len(json.loads((tmp_path / "a" / "bake.json").read_text())["sources"]) >= 1  # interior: its lamps
    assert bake_cli.main(["interior", "--out", str(tmp_path / "b"), "--no-analytic-source", *flags]) == 0
    assert "analytic source: none" in capsys.readouterr().out
    assert json.loads((tmp_path / "b" / "bake.json").read_text())["sources"] == []
