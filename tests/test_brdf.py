"""homofac.brdf: analytic models against independent numpy formulas, the horizon rule, reciprocity,
directional albedo (energy conservation), the MERL format, validation and gradients."""

from __future__ import annotations

import os

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import homofac.brdf as B
from homofac.errors import HomofacError

PI = np.pi


def sph(theta_deg, phi_deg):
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def random_dirs(rng, n, max_theta_deg=89.0):
    """Uniform-in-solid-angle directions with theta <= max_theta (above the horizon)."""
    mu = rng.uniform(np.cos(np.radians(max_theta_deg)), 1.0, n)
    phi = rng.uniform(0.0, 2 * PI, n)
    s = np.sqrt(1 - mu**2)
    return np.stack([s * np.cos(phi), s * np.sin(phi), mu], axis=-1)


def sphere_pairs(seed, n):
    """(wi, wo) float32 (n, 3): normal-distributed directions normalized, over the whole sphere (about
    a quarter of the pairs are above the horizon on both sides)."""
    rng = np.random.default_rng(seed)
    wi = rng.normal(size=(n, 3))
    wo = rng.normal(size=(n, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    return jnp.asarray(wi, jnp.float32), jnp.asarray(wo, jnp.float32)


# ------------------------------------------------------------------------------------------------
# Independent numpy references written from the formulas with spherical angles.


def angles(ti, pi_, to, po):
    """cos(alpha) (r_i . wo), cos(theta_h), cos(theta_d) = v.h from spherical angles (degrees)."""
    ti, pi_, to, po = np.radians([ti, pi_, to, po])
    dp = pi_ - po
    cos_a = np.cos(ti) * np.cos(to) - np.sin(ti) * np.sin(to) * np.cos(dp)
    io = np.sin(ti) * np.sin(to) * np.cos(dp) + np.cos(ti) * np.cos(to)  # wi . wo
    norm = np.sqrt(2 + 2 * io)
    cos_h = (np.cos(ti) + np.cos(to)) / norm
    vh = np.sqrt((1 + io) / 2)
    return np.cos(ti), np.cos(to), cos_a, cos_h, vh


def ref(model, p, ti, pi_, to, po):
    ci, co, ca, ch, vh = angles(ti, pi_, to, po)
    kd = np.broadcast_to(np.asarray(p.get("kd", 0.0), float), 3)
    ks = np.broadcast_to(np.asarray(p.get("ks", 0.0), float), 3)
    diffuse = kd / PI
    tan2h = 1 / ch**2 - 1
    if model == "lambert":
        return diffuse
    if model == "phong":
        return diffuse + ks * max(ca, 0) ** p["exponent"]
    if model == "modified_phong":
        n = p["exponent"]
        return diffuse + ks * (n + 2) / (2 * PI) * max(ca, 0) ** n
    if model == "blinn_phong":
        n = p["exponent"]
        return diffuse + ks * (n + 8) / (8 * PI) * ch**n
    f0 = np.asarray(p.get("f0", 1.0), float)
    fres = f0 + (1 - f0) * (1 - vh) ** 5
    if model == "cook_torrance":
        m = p["roughness"]
        d = np.exp(-tan2h / m**2) / (PI * m**2 * ch**4)
        g = min(1.0, 2 * ch * co / vh, 2 * ch * ci / vh)
        return diffuse + ks * d * g * fres / (4 * ci * co)
    if model == "ggx":
        a = p["roughness"]
        d = a**2 / (PI * ch**4 * (a**2 + tan2h) ** 2)

        def lam(c):
            return (-1 + np.sqrt(1 + a**2 * (1 / c**2 - 1))) / 2

        g2 = 1 / (1 + lam(ci) + lam(co))
        return diffuse + ks * d * g2 * fres / (4 * ci * co)
    if model == "ward":
        a = p["roughness"]
        return diffuse + ks * np.exp(-tan2h / a**2) / (4 * PI * a**2 * np.sqrt(ci * co))
    if model == "gltf":  # glTF 2.0 Appendix B: mix(fresnel_mix(0.04, diffuse, specular), conductor_fresnel, metallic)
        c, m, a = np.asarray(p["base_color"], float), p["metallic"], p["roughness"] ** 2
        d = a**2 / (PI * ch**4 * (a**2 + tan2h) ** 2)

        def lam(cos):
            return (-1 + np.sqrt(1 + a**2 * (1 / cos**2 - 1))) / 2

        spec = d / (1 + lam(ci) + lam(co)) / (4 * ci * co)
        fd = 0.04 + 0.96 * (1 - vh) ** 5
        dielectric = (1 - fd) * c / PI + fd * spec
        metal = (c + (1 - c) * (1 - vh) ** 5) * spec
        return (1 - m) * dielectric + m * metal
    raise AssertionError(model)


PARAMS = {
    "lambert": {"kd": (0.2, 0.5, 0.9)},
    "phong": {"kd": 0.3, "ks": (0.4, 0.5, 0.6), "exponent": 12.0},
    "modified_phong": {"kd": (0.1, 0.2, 0.3), "ks": 0.6, "exponent": 7.5},
    "blinn_phong": {"kd": 0.25, "ks": (0.5, 0.3, 0.2), "exponent": 40.0},
    "cook_torrance": {"kd": (0.05, 0.04, 0.02), "ks": 1.0, "roughness": 0.3, "f0": (1.0, 0.78, 0.34)},
    "ggx": {"kd": 0.1, "ks": 0.8, "roughness": 0.25, "f0": (0.9, 0.6, 0.3)},
    "ward": {"kd": (0.3, 0.2, 0.1), "ks": 0.4, "roughness": 0.2},
    "gltf": {"base_color": (0.8, 0.5, 0.2), "metallic": 0.4, "roughness": 0.5},
}
# (theta_i, phi_i, theta_o, phi_o) in degrees: mirror pair, a general pair, a near-mirror off-plane pair
PAIRS = [(30.0, 0.0, 30.0, 180.0), (20.0, 10.0, 50.0, 130.0), (45.0, 60.0, 35.0, 250.0)]


@pytest.mark.parametrize("model", list(PARAMS))
@pytest.mark.parametrize("pair", PAIRS)
def test_analytic_matches_independent_formula(model, pair):
    p = PARAMS[model]
    brdf = B.make(model, **p)
    wi, wo = sph(pair[0], pair[1]), sph(pair[2], pair[3])
    got = np.asarray(brdf(jnp.asarray(wi, jnp.float32), jnp.asarray(wo, jnp.float32)))
    assert got.shape == (3,)
    np.testing.assert_allclose(got, ref(model, p, *pair), rtol=2e-5, atol=1e-7)


def test_hand_values_at_normal_incidence():
    z = jnp.array([0.0, 0.0, 1.0])
    m = 0.3
    f0 = np.array([1.0, 0.78, 0.34])
    kd = np.array([0.05, 0.04, 0.02])
    # Cook-Torrance at wi = wo = n: D = 1/(pi m^2), G = 1, F = F0
    ct = B.cook_torrance(kd=kd, ks=1.0, roughness=m, f0=f0)
    np.testing.assert_allclose(ct(z, z), kd / PI + f0 / (4 * PI * m**2), rtol=1e-6)
    # GGX: D = 1/(pi alpha^2), G2 = 1, F = F0
    np.testing.assert_allclose(B.ggx(kd=0, ks=0.5, roughness=0.2, f0=0.04)(z, z), 0.5 * 0.04 / (4 * PI * 0.04), rtol=1e-6)
    # Ward: ks / (4 pi alpha^2)
    np.testing.assert_allclose(B.ward(kd=0.2, ks=0.5, roughness=0.1)(z, z), 0.2 / PI + 0.5 / (4 * PI * 0.01), rtol=1e-6)
    np.testing.assert_allclose(B.blinn_phong(kd=0, ks=1, exponent=10)(z, z), 18 / (8 * PI), rtol=1e-6)
    np.testing.assert_allclose(B.modified_phong(kd=0, ks=1, exponent=10)(z, z), 12 / (2 * PI), rtol=1e-6)
    np.testing.assert_allclose(B.phong(kd=0.5, ks=0.25, exponent=3)(z, z), 0.5 / PI + 0.25, rtol=1e-6)
    np.testing.assert_allclose(B.lambert(1.0)(z, z), np.full(3, 1 / PI), rtol=1e-7)
    # Classic Phong off the mirror direction: cos(alpha) = cos(40 deg) for wi at 30, wo at 10 deg in plane
    val = B.phong(kd=0, ks=1, exponent=5)(jnp.asarray(sph(30, 0)), jnp.asarray(sph(10, 180)))
    np.testing.assert_allclose(val, np.full(3, np.cos(np.radians(20)) ** 5), rtol=1e-5)


def all_brdfs(small_table=True):
    out = [B.make(m, **p) for m, p in PARAMS.items()]
    rng = np.random.default_rng(3)
    out.append(B.merl(table=rng.uniform(0.0, 2.0, (12, 10, 16, 3)).astype(np.float32)))
    return out


def test_exactly_zero_below_horizon():
    rng = np.random.default_rng(0)
    up = random_dirs(rng, 64)
    down = up * np.array([1, 1, -1])
    flat = up.copy()
    flat[:, 2] = 0.0
    flat /= np.linalg.norm(flat, axis=-1, keepdims=True)
    tiny_neg = up.copy()
    tiny_neg[:, 2] = -1e-30
    for brdf in all_brdfs():
        for bad in (down, flat, tiny_neg):
            for wi, wo in ((bad, up), (up, bad), (bad, bad)):
                v = np.asarray(brdf(jnp.asarray(wi, jnp.float32), jnp.asarray(wo, jnp.float32)))
                assert v.shape == (64, 3)
                assert np.all(v == 0.0), brdf.model
        # and strictly positive somewhere above (sanity)
        assert np.any(np.asarray(brdf(up, up[::-1])) > 0)


def test_shapes_broadcast_and_jit():
    brdf = B.cook_torrance()
    wi = jnp.asarray(random_dirs(np.random.default_rng(1), 10).reshape(2, 5, 3), jnp.float32)
    wo = jnp.array([0.0, 0.6, 0.8])
    out = brdf(wi, wo)
    assert out.shape == (2, 5, 3)
    np.testing.assert_allclose(B.evaluate(brdf, wi, wo), out, rtol=1e-6)
    assert B.lambert(0.5)(wo, wo).shape == (3,)


def test_reciprocity_float64(x64):
    rng = np.random.default_rng(2)
    wi = jnp.asarray(random_dirs(rng, 500))
    wo = jnp.asarray(random_dirs(rng, 500))
    assert wi.dtype == jnp.float64
    checked = []
    for brdf in all_brdfs():
        assert brdf.spec.reciprocal
        a, b = np.asarray(brdf(wi, wo)), np.asarray(brdf(wo, wi))
        assert a.dtype == np.float64
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-12 * np.abs(a).max(), err_msg=brdf.model)
        checked.append(brdf.model)
    assert set(checked) == set(B.MODELS)


# ------------------------------------------------------------------------------------------------
# Directional albedo

VIEW_DEG = [0.0, 30.0, 60.0, 80.0, 89.0]
WO = jnp.asarray(np.array([sph(t, 37.0) for t in VIEW_DEG]), jnp.float32)


def test_albedo_lambert_is_kd():
    a = np.asarray(B.albedo(B.lambert(1.0), WO))
    assert a.shape == (len(VIEW_DEG), 3)
    np.testing.assert_allclose(a, 1.0, atol=1e-4)
    np.testing.assert_allclose(B.albedo(B.lambert((0.2, 0.4, 0.8)), WO)[0], [0.2, 0.4, 0.8], rtol=1e-4)
    # below the horizon: 0; batch shapes kept
    assert np.all(np.asarray(B.albedo(B.lambert(1.0), jnp.array([[[0.0, 0.6, -0.8]]]))) == 0.0)


def test_albedo_modified_phong_conserves_energy():
    for n in (1.0, 10.0, 100.0, 1000.0):
        a = np.asarray(B.albedo(B.modified_phong(kd=0.3, ks=0.7, exponent=n), WO))
        # the (n+2)/(2 pi) lobe has albedo exactly 1 at normal incidence and less elsewhere
        np.testing.assert_allclose(a[0], 1.0, atol=1e-3)
        assert np.all(a <= 1.0 + 1e-4), (n, a)
        assert np.all(np.diff(a[:, 0]) < 0)  # decreasing towards grazing


def test_albedo_blinn_phong_overshoot_matches_closed_form():
    """The (n+8)/(8 pi) factor is approximate: lobe albedo at normal incidence is A(n) > 1."""
    for n in (1.0, 10.0, 100.0):
        a_n = (n + 8) * (2 * (1 - 2 ** (-(n + 4) / 2)) / (n + 4) - (1 - 2 ** (-(n + 2) / 2)) / (n + 2))
        a = np.asarray(B.albedo(B.blinn_phong(kd=0, ks=1, exponent=n), WO))
        np.testing.assert_allclose(a[0], a_n, rtol=2e-4)
        assert a_n > 1.0
    # with the registry's condition kd + 1.075 ks <= 1 it conserves energy at every view angle
    for n in (1.0, 10.0, 100.0, 1000.0):
        a = np.asarray(B.albedo(B.blinn_phong(kd=1 - 1.075 * 0.8, ks=0.8, exponent=n), WO))
        assert np.all(a <= 1.0 + 1e-4), (n, a)
    assert B.MODELS["blinn_phong"].energy_conserving == "kd + 1.075 ks <= 1"


def test_albedo_phong_normal_incidence_closed_form():
    for n in (2.0, 30.0):
        a = np.asarray(B.albedo(B.phong(kd=0.1, ks=1.0, exponent=n), WO))[0]
        np.testing.assert_allclose(a, 0.1 + 2 * PI / (n + 2), rtol=1e-4)


@pytest.mark.parametrize("model", ["cook_torrance", "ggx"])
def test_albedo_microfacet_at_most_one(model):
    normal = {}
    for r in (0.05, 0.2, 0.5, 1.0):
        a = np.asarray(B.albedo(B.make(model, kd=0.0, ks=1.0, roughness=r, f0=1.0), WO))
        assert np.all(a <= 1.0 + 1e-4), (r, a)
        assert np.all(a > 0.25)
        normal[r] = a[0, 0]
    # smooth surfaces keep almost all energy at normal incidence; rough ones lose it (single scattering)
    assert normal[0.05] > 0.99 and normal[1.0] < 0.5


def test_albedo_ward_not_energy_conserving():
    assert B.MODELS["ward"].energy_conserving == ""
    near_grazing = WO.at[-1].set(jnp.asarray(sph(89.99, 0.0), jnp.float32))
    assert float(B.albedo(B.ward(kd=0.0, ks=1.0, roughness=0.2), near_grazing)[-1, 0]) > 1.2


# ------------------------------------------------------------------------------------------------
# MERL


@pytest.fixture(scope="module")
def tables():
    smooth = B.modified_phong(kd=0.3, ks=0.7, exponent=10.0)
    gold = B.cook_torrance()
    return {"smooth": (smooth, B.tabulate_merl(smooth)), "gold": (gold, B.tabulate_merl(gold))}


def test_half_diff_roundtrip():
    rng = np.random.default_rng(5)
    th = jnp.asarray(rng.uniform(0.01, 1.5, 200))
    td = jnp.asarray(rng.uniform(0.01, 1.5, 200))
    pd = jnp.asarray(rng.uniform(-3.1, 3.1, 200))
    wi, wo = B.from_half_diff(th, td, pd)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(wi), axis=-1), 1.0, atol=1e-5)
    th2, td2, pd2 = B.half_diff_angles(wi, wo)
    np.testing.assert_allclose(th2, th, atol=2e-5)
    np.testing.assert_allclose(td2, td, atol=2e-5)
    np.testing.assert_allclose(pd2, pd, atol=5e-5)


def test_merl_lookup_hits_grid_points_exactly():
    """Querying at the tabulation grid returns the stored values: tabulate and lookup agree on indexing."""
    rng = np.random.default_rng(6)
    dims = (10, 8, 12)
    table = rng.uniform(0.1, 1.0, dims + (3,)).astype(np.float32)
    brdf = B.merl(table=table)
    th, td, pd = (np.asarray(a) for a in B.merl_grid(dims))
    # grid points whose directions are both above the horizon
    wi, wo = B.from_half_diff(jnp.asarray(th), jnp.asarray(td), jnp.asarray(pd))
    ok = (np.asarray(wi)[..., 2] > 1e-3) & (np.asarray(wo)[..., 2] > 1e-3) & (td > 0)  # phi_d undefined at theta_d = 0
    got = np.asarray(brdf(wi, wo))
    np.testing.assert_allclose(got[ok], table[ok], rtol=2e-4)
    assert ok.sum() > 200


def test_merl_file_roundtrip_bit_exact(tables, tmp_path):
    _, table = tables["gold"]
    assert table.shape == (90, 90, 180, 3) and table.dtype == np.float32
    path = tmp_path / "gold.binary"
    B.save_merl(path, table)
    raw = path.read_bytes()
    assert len(raw) == 12 + 3 * 90 * 90 * 180 * 8
    assert np.frombuffer(raw[:12], "<i4").tolist() == [90, 90, 180]
    # channel-major float64, scaled: first red value is table[0, 0, 0, 0] * 1500
    vals = np.frombuffer(raw[12:], "<f8")
    n = 90 * 90 * 180
    np.testing.assert_allclose(vals[[0, n, 2 * n]], table[0, 0, 0] / np.array([1, 1.15, 1.66]) * 1500, rtol=1e-12)
    np.testing.assert_allclose(vals[n + 1 * 180 + 2] * 1.15 / 1500, table[0, 1, 2, 1], rtol=1e-7)
    back = B.load_merl(path)
    assert back.dtype == np.float32 and back.shape == table.shape
    assert np.array_equal(back.view(np.uint32), table.view(np.uint32))  # bit-exact
    B.save_merl(tmp_path / "again.binary", back)
    assert (tmp_path / "again.binary").read_bytes() == raw
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []
    # make("merl", file=...) as a config would
    wi = jnp.asarray(random_dirs(np.random.default_rng(7), 50, 80.0), jnp.float32)
    wo = jnp.asarray(random_dirs(np.random.default_rng(8), 50, 80.0), jnp.float32)
    np.testing.assert_array_equal(B.make("merl", file=str(path))(wi, wo), B.merl(table=table)(wi, wo))


@pytest.mark.parametrize("which,rtol", [("smooth", 0.01), ("gold", 0.03)])
def test_merl_reads_back_within_interpolation_error(tables, which, rtol):
    """Trilinear interpolation error is <= h^2/8 max|f''| per axis. The grid step is h ~ 1 deg in
    theta_d and phi_d and up to 1.4 deg (0.025 rad) in theta_h at 45 deg: h^2/8 ~ 8e-5 rad^2.
    For cos^10 (alpha), |f''|/f ~ n^2 tan^2 ~ 100 -> <~1 %. The Beckmann tail exp(-tan^2/m^2), m = 0.3,
    has |(log f)'|^2 ~ 700 at theta_h ~ 40 deg -> a few % there. Pairs are kept <= 75 deg from the
    normal so no interpolation cell reaches below the horizon (tabulated as 0)."""
    analytic, table = tables[which]
    rng = np.random.default_rng(9)
    wi = jnp.asarray(random_dirs(rng, 5000, 75.0), jnp.float32)
    wo = jnp.asarray(random_dirs(rng, 5000, 75.0), jnp.float32)
    exact = np.asarray(analytic(wi, wo))
    got = np.asarray(B.evaluate(B.merl(table=table), wi, wo))
    rel = np.abs(got - exact) / exact
    assert rel.max() < rtol, rel.max()
    assert rel.mean() < rtol / 5, rel.mean()


def test_merl_errors_name_the_file(tmp_path):
    table = np.full((4, 4, 8, 3), 0.5, np.float32)
    good = tmp_path / "small.binary"
    B.save_merl(good, table)
    np.testing.assert_array_equal(B.load_merl(good), table)  # other resolutions are accepted
    raw = good.read_bytes()

    cases = {
        "missing.binary": None,
        "truncated.binary": raw[:-8],
        "tiny.binary": raw[:7],
        "badheader.binary": np.array([90, 90, 90], "<i4").tobytes() + raw[12:],
        "negheader.binary": np.array([-1, 4, 8], "<i4").tobytes() + raw[12:],
        "long.binary": raw + b"\0" * 8,
    }
    for name, content in cases.items():
        path = tmp_path / name
        if content is not None:
            path.write_bytes(content)
        with pytest.raises(HomofacError) as e:
            B.load_merl(path)
        msg = str(e.value)
        assert str(path) in msg and "\n" not in msg, msg
        with pytest.raises(HomofacError):
            B.merl(file=path)
    with pytest.raises(HomofacError, match="truncated"):
        B.load_merl(tmp_path / "truncated.binary")


def test_save_merl_is_atomic(tmp_path, monkeypatch):
    path = tmp_path / "x.binary"
    B.save_merl(path, np.full((4, 4, 8, 3), 0.5, np.float32))
    before = path.read_bytes()

    def boom(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(HomofacError, match="x.binary"):
        B.save_merl(path, np.full((4, 4, 8, 3), 0.25, np.float32))
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.binary"]
    with pytest.raises(HomofacError, match="shape"):
        B.save_merl(tmp_path / "y.binary", np.zeros((4, 4, 3)))
    with pytest.raises(HomofacError):
        B.save_merl(tmp_path / "no_such_dir" / "z.binary", np.zeros((4, 4, 8, 3)))
    assert not (tmp_path / "y.binary").exists()


def test_merl_holes_read_as_zero(tmp_path):
    table = np.full((6, 6, 8, 3), 0.7, np.float32)
    table[0, 0, :, :] = -1.0 / 1500  # theta_h = theta_d = 0: the normal-incidence configuration
    table[3, 2, 5, 1] = -0.5  # a hole in one channel of one cell
    path = tmp_path / "holes.binary"
    B.save_merl(path, table)
    loaded = B.load_merl(path)
    assert np.array_equal(loaded, table)  # holes stay visible in the raw table
    brdf = B.merl(file=path)
    assert B.count_holes(brdf) == 8 + 1 == B.count_holes(loaded)
    z = jnp.array([0.0, 0.0, 1.0])
    assert np.all(np.asarray(brdf(z, z)) == 0.0)  # exactly on the hole: 0, not negative
    all_holes = B.merl(table=-np.ones((6, 6, 8, 3), np.float32))
    wi = jnp.asarray(random_dirs(np.random.default_rng(4), 100), jnp.float32)
    assert np.all(np.asarray(all_holes(wi, wi[::-1])) == 0.0)
    assert np.all(np.asarray(brdf(wi, wi[::-1])) >= 0.0)


def test_merl_table_is_a_traced_argument():
    table = jnp.full((6, 6, 8, 3), 0.5, jnp.float32)
    brdf = B.merl(table=table)
    leaves = jax.tree_util.tree_leaves(eqx.filter(brdf, eqx.is_array))
    assert any(leaf.shape == (6, 6, 8, 3) for leaf in leaves)
    z = jnp.array([0.0, 0.0, 1.0])
    jaxpr = jax.make_jaxpr(lambda b: b(z, z))(brdf)
    assert any(v.aval.shape == (6, 6, 8, 3) for v in jaxpr.jaxpr.invars)
    assert all(np.size(c) < 100 for c in jaxpr.consts)


# ------------------------------------------------------------------------------------------------
# Validation


def test_make_unknown_model_lists_known():
    with pytest.raises(HomofacError) as e:
        B.make("nope")
    msg = str(e.value)
    assert "nope" in msg and "\n" not in msg
    for name in ("lambert", "phong", "modified_phong", "blinn_phong", "cook_torrance", "ggx", "ward", "merl"):
        assert name in msg
    with pytest.raises(HomofacError, match="model"):
        B.from_config({"kd": 1.0})


@pytest.mark.parametrize(
    "model,kwargs,needle",
    [
        ("cook_torrance", {"roughness": float("nan")}, "roughness"),
        ("ggx", {"roughness": 0.0}, "roughness"),
        ("ward", {"roughness": -0.1}, "roughness"),
        ("lambert", {"kd": -0.1}, "kd"),
        ("phong", {"ks": (0.1, float("inf"), 0.2)}, "ks"),
        ("phong", {"exponent": -1.0}, "exponent"),
        ("blinn_phong", {"kd": (0.1, 0.2)}, "kd"),
        ("cook_torrance", {"f0": (1.2, 0.5, 0.5)}, "f0"),
        ("cook_torrance", {"roughness": (0.1, 0.2, 0.3)}, "roughness"),
        ("lambert", {"kd": "red"}, "kd"),
        ("lambert", {"colour": 0.5}, "colour"),
        ("merl", {}, "file"),
        ("merl", {"table": np.zeros((4, 4, 3))}, "table"),
        ("merl", {"table": np.full((4, 4, 4, 3), np.nan)}, "table"),
    ],
)
def test_make_validation_names_parameter(model, kwargs, needle):
    with pytest.raises(HomofacError) as e:
        B.make(model, **kwargs)
    msg = str(e.value)
    assert needle in msg and "\n" not in msg, msg


def test_validation_message_style():
    with pytest.raises(HomofacError) as e:
        B.cook_torrance(roughness=float("nan"))
    assert str(e.value) == "brdf.roughness must be a finite number > 0, got nan"
    with pytest.raises(HomofacError) as e:
        B.make("lambert", colour=1)
    assert "colour" in str(e.value) and "kd" in str(e.value)  # names it and lists the model's parameters


def test_make_defaults_and_conversion():
    b = B.make("cook_torrance")
    assert set(b.params) == {"kd", "ks", "roughness", "f0"}
    assert b.params["ks"].shape == (3,) and b.params["roughness"].shape == ()
    np.testing.assert_allclose(b.params["f0"], [1.0, 0.78, 0.34])
    assert B.lambert(0.5).params["kd"].shape == (3,)
    assert B.from_config({"model": "ggx", "roughness": 0.1}).params["roughness"] == pytest.approx(0.1)
    for name, spec in B.MODELS.items():
        assert spec.name == name and spec.doc and isinstance(spec.energy_conserving, str)


# ------------------------------------------------------------------------------------------------
# Gradients


def test_grad_roughness_matches_finite_difference(x64):
    rng = np.random.default_rng(11)
    wi = random_dirs(rng, 40, 80.0)
    wo = random_dirs(rng, 40, 80.0)
    wi[:5, 2] *= -1  # some pairs below the horizon: must not poison the gradient
    wi, wo = jnp.asarray(wi), jnp.asarray(wo)
    weights = jnp.asarray([0.2, 0.7, 0.1])

    def loss(r):
        brdf = B.cook_torrance(roughness=r)  # constructing with a tracer works (validation skipped)
        return jnp.sum(brdf(wi, wo) * weights)

    r0, h = 0.3, 1e-6
    g = float(jax.jit(jax.grad(loss))(r0))
    loss_j = jax.jit(loss)
    fd = (float(loss_j(r0 + h)) - float(loss_j(r0 - h))) / (2 * h)
    assert np.isfinite(g) and abs(g) > 1e-3
    assert g == pytest.approx(fd, rel=1e-6)

    # the same through the module's params pytree
    brdf = B.cook_torrance(roughness=r0)
    grads = jax.jit(jax.grad(lambda p: jnp.sum(B.BRDF("cook_torrance", p)(wi, wo) * weights)))(brdf.params)
    assert float(grads["roughness"]) == pytest.approx(g, rel=1e-12)
    assert all(np.all(np.isfinite(np.asarray(v))) for v in grads.values())


def test_grads_finite_for_all_models():
    rng = np.random.default_rng(12)
    wi = random_dirs(rng, 30)
    wo = random_dirs(rng, 30)
    wi[:3, 2] = -wi[:3, 2]
    wi, wo = jnp.asarray(wi, jnp.float32), jnp.asarray(wo, jnp.float32)
    for brdf in all_brdfs():
        grads = jax.jit(jax.grad(lambda p, m=brdf.model: jnp.sum(B.BRDF(m, p)(wi, wo))))(brdf.params)
        for k, v in grads.items():
            assert np.all(np.isfinite(np.asarray(v))), (brdf.model, k)


@pytest.mark.parametrize("model", [m for m in PARAMS if m != "lambert"] + ["lambert"])
def test_lobe_form_reproduces_the_model(model):
    """kd/pi + sum_m colour_m * lobe_m equals brdf(wi, wo) everywhere, the horizon included: the
    lighting computation sums the lobe form (one matmul per lobe), so it must be the same function."""
    from homofac.brdf.core import has_lobes, lobe_colors, lobe_terms

    brdf = B.make(model, **PARAMS[model])
    assert has_lobes(brdf)
    wi, wo = sphere_pairs(7, 512)
    want = np.asarray(brdf(wi, wo))
    above = np.asarray((wi[:, 2] > 0) & (wo[:, 2] > 0))
    kd = np.broadcast_to(np.asarray(PARAMS[model].get("kd", 0.0), np.float32), 3)
    got = np.where(above[:, None], kd / PI, 0.0)
    for c, g in zip(lobe_colors(brdf), lobe_terms(brdf, wi, wo)):
        assert np.all(np.asarray(g)[~above] == 0)
        got = got + np.asarray(c)[None, :] * np.asarray(g)[:, None]
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-7)
    # the component-triple form gives the same lobes as the (..., 3) form
    tri = lobe_terms(brdf, (wi[:, 0], wi[:, 1], wi[:, 2]), (wo[:, 0], wo[:, 1], wo[:, 2]))
    for g1, g2 in zip(tri, lobe_terms(brdf, wi, wo)):
        np.testing.assert_array_equal(np.asarray(g1), np.asarray(g2))


@pytest.mark.parametrize("model", list(PARAMS))
def test_stacked_lobes_equal_each_shape(model):
    """stacked_lobe_terms of B roughnesses / exponents (a library's lobe shapes, evaluated at once with
    the geometry shared when the model has a Shaped split) equals lobe_terms of each, horizon included."""
    from homofac.brdf.core import MODELS, lobe_terms, stacked_lobe_terms

    wi, wo = sphere_pairs(11, 256)
    name = "roughness" if "roughness" in PARAMS[model] else "exponent" if "exponent" in PARAMS[model] else None
    scales = (0.5, 1.0, 1.7)
    brdfs = [B.make(model, **{**PARAMS[model], **({name: PARAMS[model][name] * s} if name else {})}) for s in scales]
    stacked = B.BRDF(model, {k: jnp.stack([jnp.broadcast_to(jnp.asarray(b.params[k], jnp.float32),
                                                            jnp.shape(brdfs[0].params[k])) for b in brdfs])
                             for k in brdfs[0].params})
    got = np.asarray(stacked_lobe_terms(stacked, wi, wo))
    m = len(lobe_terms(brdfs[0], wi, wo))
    assert got.shape == (len(scales), m, 256)
    for b, g in zip(brdfs, got):
        for want, one in zip(lobe_terms(b, wi, wo), g):
            np.testing.assert_allclose(one, np.asarray(want), rtol=2e-5, atol=1e-7)
    if model in ("cook_torrance", "ward"):
        assert MODELS[model].shaped is not None  # the split that the library's lighting uses
