"""The bake's second azimuthal harmonic: the tensor maps read the harmonic's light sum, ``Bake.terms`` adds it
coloured as the isotropic part, and a bake carries it (fetches, tables, save / load)."""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest

import homofac as hf
from homofac.bake import kernels as kn
from homofac.bake.build import harmonic_maps
from homofac.bake.gauge import face_gauge, gauge_read
from homofac.bake.model import Bake, tensor_read
from homofac.bake.plan import plan as make_plan
from homofac.light.environment import LUMINANCE
from homofac.param import mappers
from test_bake import as_schema_4, check_glsl_terms


def test_tensor_maps_read_the_second_harmonic_of_the_light_sum():
    """t^T M(a) t equals sum_l Y_l dw_l k_2(gamma_l) cos(2 omega_l) (times the reference kernel's quadrature
    ratio), omega the light's azimuth about a from t, for any unit t perpendicular to a."""
    env = hf.light.load_environment("studio", 8)
    x = np.array([0.15, 0.6])
    k2 = kn.harmonic_kernels(0.5, x).reshape(4, -1)
    ref = kn.specular_kernels(0.5, x).reshape(4, -1).sum(0)
    m = harmonic_maps(k2, ref, 4, env, None)  # (96, 4, 5)
    a = np.asarray(mappers.texel_directions("cube", 4), np.float64).reshape(-1, 3)
    l = np.asarray(env.directions, np.float64)
    y = (np.asarray(env.radiance, np.float64) @ np.asarray(LUMINANCE)) * np.asarray(env.solid_angle, np.float64)
    q = kn.q_grid(k2.shape[-1])
    u = np.sqrt(q)
    rng = np.random.default_rng(0)
    for i in rng.choice(len(a), 6, replace=False):
        t = np.cross(a[i], rng.normal(size=3))
        t /= np.linalg.norm(t)
        b = np.cross(a[i], t)
        c = np.clip(l @ a[i], -1, 1)
        gamma = np.arccos(c)
        omega = np.arctan2(l @ b, l @ t)
        ul = np.sqrt(np.sqrt(np.clip((1 - c) / 2, 0, 1)))
        s2 = np.sin(2 * np.arcsin(q)) ** 2
        ratio = kn.mass(ref[None])[0] / np.sum(np.asarray(env.solid_angle) * np.interp(ul, u, ref))
        for j in range(len(k2)):
            kt = np.where(s2 > 0, k2[j] / np.where(s2 > 0, s2, 1), 0)
            kt[0] = kt[1]
            direct = np.sum(y * np.interp(ul, u, kt) * np.sin(gamma) ** 2 * np.cos(2 * omega)) * ratio
            got = float(tensor_read(m[i:i + 1, j], t[None])[0])
            assert abs(got - direct) <= 2e-3 * np.abs(m[:, j]).max() + 1e-6 * abs(direct), (i, j, got, direct)
        # M is traceless and M a = 0: the axis' component reads nothing
        assert abs(float(tensor_read(m[i:i + 1, 0], a[i:i + 1])[0])) < 1e-4 * np.abs(m[:, 0]).max()


def _synthetic(harmonic: float, rng, h=None, tensor=None):
    """A hand-made bake (no fit): random positive maps and tables, and with ``harmonic`` constant face-gauge
    tensor channels ``tensor`` (M'_uu, M'_vv, M'_uv) and harmonic weights."""
    pl = make_plan("fast", max_size=8, layers=3, nv_size=4, diffuse_size=8, harmonic=harmonic)
    sizes = (8, 8, 8)
    P = tuple(rng.uniform(0.5, 2.0, (s, 6 * s, 1, 3)).astype(np.float32) for s in sizes)
    E = rng.uniform(0.5, 1.0, (8, 48, 1, 3)).astype(np.float32)
    W = rng.uniform(0.2, 1.0, (3, 4, 3)).astype(np.float32)  # a, b, w
    H = ()
    if harmonic:
        W = np.concatenate([W, np.full((3, 4, 2), h, np.float32)], -1)  # h_A, h_B
        H = (None,) + tuple(np.broadcast_to(np.asarray(tensor, np.float32), (s, 6 * s, 3)).copy() for s in sizes[1:])
    return Bake(pl, (0.1, 0.3, 1.0), (0.0, 0.0, 0.2), P, E, W, {}, H=H)


def test_terms_add_the_harmonic_in_luminance_coloured_as_the_isotropic_part():
    """Zero tensors read today's terms; otherwise Y(I_A) - Y(I_A0) = h_A t^T M t (likewise I_B; t^T M t the
    face-gauge read of constant channels), the colour (chromaticity) of each term unchanged, I_d untouched."""
    rng = np.random.default_rng(1)
    tensor = np.array([0.3, -0.2, 0.1])
    plain = _synthetic(0.0, np.random.default_rng(1))
    zero = _synthetic(0.25, np.random.default_rng(1), h=0.7, tensor=np.zeros(3))
    harm = _synthetic(0.25, np.random.default_rng(1), h=0.7, tensor=tensor)
    n = rng.normal(size=(64, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    v = rng.normal(size=(64, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v = np.where((np.sum(n * v, 1) < 0.05)[:, None], -v, v)
    rho = np.full(64, 0.6)  # between layers 1 and 2 (both with the harmonic)
    base = np.asarray(plain.terms(n, v, rho))
    np.testing.assert_allclose(np.asarray(zero.terms(n, v, rho)), base, rtol=1e-6)
    got = np.asarray(harm.terms(n, v, rho))
    x = np.sum(n * v, 1)
    r = 2 * x[:, None] * n - v
    hs = []
    for shift in (0.0, 0.2):
        a = (1 - shift) * r + shift * n
        a /= np.linalg.norm(a, axis=1, keepdims=True)
        t = n - np.sum(n * a, 1, keepdims=True) * a
        t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-6)
        hs.append(np.asarray(gauge_read(np.broadcast_to(tensor, (64, 3)), a, t)))
    u = np.asarray(harm.layer_coordinate(rho))
    hval = 0.7 * ((2 - u) * hs[0] + (u - 1) * hs[1])
    lum = np.asarray(LUMINANCE)
    np.testing.assert_allclose(got[:, 0], base[:, 0], rtol=1e-6)
    for k in (1, 2):
        expect = np.maximum(base[:, k] @ lum + hval, 0.0)
        np.testing.assert_allclose(got[:, k] @ lum, expect, rtol=1e-4, atol=1e-5)
        chroma = lambda c: c / np.maximum(c.sum(1, keepdims=True), 1e-12)  # noqa: E731
        keep = expect > 1e-3
        np.testing.assert_allclose(chroma(got[keep, k]), chroma(base[keep, k]), atol=1e-5)


def test_face_gauge_reads_t_m_t():
    """The 3 face-gauge channels read t^T M t for every t orthogonal to the texel's axis (exact at the texels);
    between texels, for a smooth field M(a) = P C P (P = I - a a^T), the bilinear read converges with the face
    size (first order at the faces' clamped edges, where a leaves the texels' hull) and its RMS error stays within
    2.5x the 5-channel tensor's."""
    rng = np.random.default_rng(0)
    for s in (4, 8):
        a = np.asarray(mappers.texel_directions("cube", s), np.float64).reshape(-1, 3)
        proj = np.eye(3)[None] - a[:, :, None] * a[:, None, :]
        g = rng.normal(size=(len(a), 3, 3))
        M = proj @ (g + np.swapaxes(g, 1, 2)) @ proj
        M -= np.trace(M, axis1=1, axis2=2)[:, None, None] / 2 * proj  # traceless, M a = 0
        t = np.einsum("nij,nj->ni", proj, rng.normal(size=(len(a), 3)))
        t /= np.linalg.norm(t, axis=1, keepdims=True)
        m5 = np.stack([M[:, 0, 0], M[:, 1, 1], M[:, 0, 1], M[:, 0, 2], M[:, 1, 2]], -1)
        got = np.asarray(gauge_read(jnp.asarray(face_gauge(m5, s).reshape(-1, 3)), jnp.asarray(a, jnp.float32), jnp.asarray(t, jnp.float32)))
        exact = np.einsum("ni,nij,nj->n", t, M, t)
        assert np.abs(got - exact).max() <= 1e-5 * np.abs(exact).max()
        np.testing.assert_allclose(got, np.asarray(tensor_read(jnp.asarray(m5, jnp.float32), jnp.asarray(t, jnp.float32))), atol=1e-5)
    c = rng.normal(size=(3, 3))
    c = c + c.T
    d = rng.normal(size=(2000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = np.cross(d, rng.normal(size=(2000, 3)))
    t /= np.linalg.norm(t, axis=1, keepdims=True)

    def field(x):  # P C P minus its trace part: symmetric, traceless, M x = 0
        p = np.eye(3)[None] - x[:, :, None] * x[:, None, :]
        m = p @ c @ p
        return m - np.trace(m, axis1=1, axis2=2)[:, None, None] / 2 * p

    exact = np.einsum("ni,nij,nj->n", t, field(d), t)
    errors, rms = [], []
    for s in (8, 16, 32):
        m = field(np.asarray(mappers.texel_directions("cube", s), np.float64).reshape(-1, 3))
        m5 = np.stack([m[:, 0, 0], m[:, 1, 1], m[:, 0, 1], m[:, 0, 2], m[:, 1, 2]], -1)
        maps = jnp.asarray(face_gauge(m5, s).reshape(s, 6 * s, 3))
        read = mappers.lookup("cube", maps, jnp.asarray(d, jnp.float32))
        got = np.asarray(gauge_read(read.reshape(-1, 3), jnp.asarray(d, jnp.float32), jnp.asarray(t, jnp.float32)))
        five = np.asarray(tensor_read(mappers.lookup("cube", jnp.asarray(m5.reshape(s, 6 * s, 5), jnp.float32),
                                                     jnp.asarray(d, jnp.float32)).reshape(-1, 5), jnp.asarray(t, jnp.float32)))
        errors.append(np.abs(got - exact).max() / np.abs(exact).max())
        rms.append((np.sqrt(np.mean((got - exact) ** 2)), np.sqrt(np.mean((five - exact) ** 2))))
    assert errors[0] < 0.2 and errors[1] < 0.6 * errors[0] and errors[2] < 0.6 * errors[1], errors
    assert all(g < 2.5 * f for g, f in rms) and rms[2][0] < 0.2 * rms[0][0], rms


def test_plan_counts_the_harmonic_fetches():
    """With the harmonic, P's RGB maps and one more RGB map for the tensor's 3 face-gauge channels, and the
    tables gain h_A, h_B: fast + harmonic reads 2 x 2 + 1 + 2 = 7 fetches."""
    assert make_plan("fast", harmonic=0.3).lookups == 7
    assert make_plan("fast", harmonic=0.0).lookups == 4
    assert make_plan("balanced", harmonic=0.3, mixed=False, shared_gain=False, diffuse_basis="texture").lookups == 2 * 3 + 1 + 3
    assert "second harmonic from roughness 0.3" in make_plan("fast", harmonic=0.3).describe()


# --- a bake with the harmonic: its directory and its shaders ------------------------------------------------

@pytest.fixture
def harmonic_bake(forest_bakes):
    """fast with the harmonic from 0.3, four layers (its shaders in every language: test_bake.py)."""
    return forest_bakes("harmonic")


def test_a_bake_fits_the_harmonic_in_its_rough_layers_only(harmonic_bake):
    b = harmonic_bake
    assert [h is not None for h in b.H] == [rho >= 0.3 for rho in b.roughness]
    assert all(np.abs(h).max() > 0 for h in b.H if h is not None)
    w = np.asarray(b.W)
    assert w.shape[-1] == b.plan.channels == 5
    rough = np.asarray(b.roughness) >= 0.3
    assert np.all(w[~rough, :, 3:] == 0) and np.abs(w[rough, :, 3:]).max() > 0


def five_channels(m3, s: int) -> np.ndarray:
    """(S, 6 S, 5): the tensor (M_xx, M_yy, M_xy, M_xz, M_yz) whose face gauge is ``m3`` (S, 6 S, 3): M = P M' P
    with M' the stored 2 x 2 block in the texel face's minor axes (P = I - a a^T; the bake's M is traceless with
    M a = 0, so this is it)."""
    a = np.asarray(mappers.texel_directions("cube", s), np.float64).reshape(-1, 3)
    m3 = np.asarray(m3, np.float64).reshape(-1, 3)
    idx = np.arange(len(a))
    minor = np.array([[1, 2], [0, 2], [0, 1]])[np.argmax(np.abs(a), 1)]
    Mp = np.zeros((len(a), 3, 3))
    Mp[idx, minor[:, 0], minor[:, 0]] = m3[:, 0]
    Mp[idx, minor[:, 1], minor[:, 1]] = m3[:, 1]
    Mp[idx, minor[:, 0], minor[:, 1]] = Mp[idx, minor[:, 1], minor[:, 0]] = m3[:, 2]
    proj = np.eye(3)[None] - a[:, :, None] * a[:, None, :]
    M = proj @ Mp @ proj
    return np.stack([M[:, 0, 0], M[:, 1, 1], M[:, 0, 1], M[:, 0, 2], M[:, 1, 2]], -1).reshape(s, 6 * s, 5)


def write_rgba_schema(b, out, version: int) -> None:
    """Rewrite the saved directory ``out`` of ``b`` (a bake with the harmonic) as schema ``version`` (3 or 4)
    wrote it: RGBA maps sharing the shelf layout, the K products' RGB then the tensor's 5 channels (mixed: after
    K - 1 products, P_K's RGB and 0, 0 or the tensor), the layers' x, y."""
    from homofac.bake.atlas import assemble
    from homofac.io.exr import write_exr
    from homofac.output import _rgba_maps
    pl = b.plan
    doc = as_schema_4(json.loads((out / "bake.json").read_text()), version)
    layers = []
    for j, p in enumerate(b.P):
        p = np.asarray(p, np.float32)
        s = p.shape[0]
        m = np.zeros((s, 6 * s, 5), np.float32) if b.H[j] is None else five_channels(b.H[j], s).astype(np.float32)
        flat = p.reshape(s, 6 * s, -1)
        if pl.mixed:
            k1 = 3 * pl.terms - 3
            tail = m if b.H[j] is not None else np.concatenate([flat[..., k1:], np.zeros((s, 6 * s, 2), np.float32)], -1)
            flat = np.concatenate([flat[..., :k1], tail], -1)
        else:
            flat = np.concatenate([flat, m], -1)
        maps = _rgba_maps(pl)
        layers.append(np.concatenate([flat, np.zeros((s, 6 * s, 4 * maps - flat.shape[2]), np.float32)], -1))
    old = [t for t in doc["textures"] if t["kind"] == "prefiltered"]
    for f in out.glob("P*.exr"):
        f.unlink()
    rest = [t for t in doc["textures"] if t["kind"] != "prefiltered"]
    a = b.atlas
    entries = []
    for i in range(maps):
        write_exr(out / f"P{i}.exr", assemble(a, [x[..., 4 * i:4 * i + 4] for x in layers], 4), half=False, alpha=True)
        entries.append({**old[0], "name": f"P{i}", "file": f"P{i}.exr", "width": a.width, "height": a.height,
                        "channels": [f"c{4 * i + c}" for c in range(4)]})
    doc["textures"] = entries + rest
    doc["lookups"] = pl.lookups + 2 * (maps - pl.maps)
    (out / "bake.json").write_text(json.dumps(doc))


def test_save_load_round_trip_and_schema_2(harmonic_bake, tmp_path):
    """bake.json schema 5 with RGB specular maps (the tensor's face gauge in its own map) reads back to the same
    terms; a schema-3 directory (RGBA maps, the tensor's 5 channels) reads as the same bake; a schema-2 directory
    (no ``harmonic``) still loads, as a bake without it."""
    b = harmonic_bake
    out = b.save(tmp_path / "h", exr="float32")
    doc = json.loads((out / "bake.json").read_text())
    assert doc["schema_version"] == 8 and doc["plan"]["harmonic"] == 0.3
    assert [t["channels"] for t in doc["textures"] if t["kind"] == "prefiltered"] == [["P0.r", "P0.g", "P0.b"], ["M.uu", "M.vv", "M.uv"]]
    back = hf.load(out)
    n, v = _pairs(300, 4)
    for rho in (0.2, 0.5, 0.9):
        np.testing.assert_allclose(np.asarray(back.terms(n, v, rho)), np.asarray(b.terms(n, v, rho)), rtol=1e-5, atol=1e-7)
    write_rgba_schema(b, out, 3)
    old = hf.load(out)
    assert len(old.atlases) == 2 and old.lookups == b.lookups
    for rho in (0.2, 0.5, 0.9):
        np.testing.assert_allclose(np.asarray(old.terms(n, v, rho)), np.asarray(b.terms(n, v, rho)), rtol=1e-4, atol=1e-6)
    plain = _synthetic(0.0, np.random.default_rng(2)).save(tmp_path / "p", exr="float32")
    doc = as_schema_4(json.loads((plain / "bake.json").read_text()), 2)
    del doc["plan"]["harmonic"]
    (plain / "bake.json").write_text(json.dumps(doc))
    old = hf.load(plain)
    assert old.plan.harmonic == 0.0 and old.H == () and old.lookups == 4


def _pairs(count, seed):
    rng = np.random.default_rng(seed)
    n = rng.normal(size=(count, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    v = rng.normal(size=(count, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return n, np.where((np.sum(n * v, 1) < 0.02)[:, None], -v, v)


def test_gpu_equals_cpu_with_the_harmonic(harmonic_bake):
    pytest.importorskip("moderngl")
    n, v = _pairs(1500, 9)
    # 1e-3: h / Y(I_0) amplifies float32 rounding where Y(I_0) is small
    check_glsl_terms(harmonic_bake, n, v, (0.2, 0.45, 0.8), 1e-3)
