"""The bake's second azimuthal harmonic: the tensor maps read the harmonic's light sum, ``Bake.terms`` adds it
coloured as the isotropic part, and a bake carries it (fetches, tables, save / load)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import homofac as hf
from homofac.bake import kernels as kn
from homofac.bake.build import harmonic_maps
from homofac.bake.model import Bake, tensor_read
from homofac.bake.plan import plan as make_plan
from homofac.light.environment import LUMINANCE
from homofac.param import mappers
from test_bake import as_schema_4, check_glsl_terms, check_glslang, check_msl, check_wgsl


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
    """A hand-made bake (no fit): random positive maps and tables, and with ``harmonic`` constant tensors and
    harmonic weights."""
    pl = make_plan("fast", max_size=8, layers=3, nv_size=4, diffuse_size=8, harmonic=harmonic)
    sizes = (8, 8, 8)
    P = tuple(rng.uniform(0.5, 2.0, (s, 6 * s, 1, 3)).astype(np.float32) for s in sizes)
    E = rng.uniform(0.5, 1.0, (8, 48, 1, 3)).astype(np.float32)
    W = rng.uniform(0.2, 1.0, (3, 4, 3)).astype(np.float32)  # a, b, w
    H = ()
    if harmonic:
        W = np.concatenate([W, np.full((3, 4, 2), h, np.float32)], -1)  # h_A, h_B
        H = (None,) + tuple(np.broadcast_to(np.asarray(tensor, np.float32), (s, 6 * s, 5)).copy() for s in sizes[1:])
    return Bake(pl, (0.1, 0.3, 1.0), (0.0, 0.0, 0.2), P, E, W, {}, H=H)


def test_terms_add_the_harmonic_in_luminance_coloured_as_the_isotropic_part():
    """Zero tensors read today's terms; otherwise Y(I_A) - Y(I_A0) = h_A t^T M t (likewise I_B), the colour
    (chromaticity) of each term unchanged, I_d untouched."""
    rng = np.random.default_rng(1)
    tensor = np.array([0.3, -0.2, 0.1, 0.05, -0.15])
    plain = _synthetic(0.0, np.random.default_rng(1))
    zero = _synthetic(0.25, np.random.default_rng(1), h=0.7, tensor=np.zeros(5))
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
        hs.append(np.asarray(tensor_read(np.broadcast_to(tensor, (64, 5)), t)))
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


def test_plan_counts_the_harmonic_fetches():
    """With the harmonic, P's RGB and the tensor's 5 channels share ceil((3 K + 5) / 4) RGBA maps per layer and the
    tables gain h_A, h_B: fast + harmonic reads 2 x 2 + 1 + 2 = 7 fetches."""
    assert make_plan("fast", harmonic=0.3).lookups == 7
    assert make_plan("fast", harmonic=0.0).lookups == 4
    assert make_plan("balanced", harmonic=0.3, mixed=False).lookups == 2 * 3 + 1 + 3
    assert "second harmonic from roughness 0.3" in make_plan("fast", harmonic=0.3).describe()


# --- a bake with the harmonic: its directory and its shaders ------------------------------------------------

TINY = dict(layers=4, max_size=8, nv_size=8, samples=64, data_resolution=4, diffuse_size=8)


@pytest.fixture(scope="module")
def harmonic_bake():
    return hf.bake("forest", preset="fast", harmonic=0.3, **TINY)


def test_a_bake_fits_the_harmonic_in_its_rough_layers_only(harmonic_bake):
    b = harmonic_bake
    assert [h is not None for h in b.H] == [rho >= 0.3 for rho in b.roughness]
    assert all(np.abs(h).max() > 0 for h in b.H if h is not None)
    w = np.asarray(b.W)
    assert w.shape[-1] == b.plan.channels == 5
    rough = np.asarray(b.roughness) >= 0.3
    assert np.all(w[~rough, :, 3:] == 0) and np.abs(w[rough, :, 3:]).max() > 0


def test_save_load_round_trip_and_schema_2(harmonic_bake, tmp_path):
    """bake.json schema 3 with RGBA specular maps reads back to the same terms; a schema-2 directory (no
    ``harmonic``) still loads, as a bake without it."""
    b = harmonic_bake
    out = b.save(tmp_path / "h", exr="float32")
    doc = json.loads((out / "bake.json").read_text())
    assert doc["schema_version"] == 5 and doc["plan"]["harmonic"] == 0.3
    assert [t["channels"] for t in doc["textures"] if t["kind"] == "prefiltered"] == [
        ["P0.r", "P0.g", "P0.b", "M.xx"], ["M.yy", "M.xy", "M.xz", "M.yz"]]
    back = hf.load(out)
    n, v = _pairs(300, 4)
    for rho in (0.2, 0.5, 0.9):
        np.testing.assert_allclose(np.asarray(back.terms(n, v, rho)), np.asarray(b.terms(n, v, rho)), rtol=1e-5, atol=1e-7)
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


@pytest.mark.parametrize("language", ["glsl", "glsl_es", "hlsl"])
def test_harmonic_shader_compiles_with_glslang(harmonic_bake, language, tmp_path):
    check_glslang(harmonic_bake, language, tmp_path, y_ups=(False,))


def test_harmonic_msl_compiles_against_the_metal_shim(harmonic_bake, tmp_path):
    check_msl(harmonic_bake, tmp_path, y_ups=(False,))


def test_harmonic_wgsl_runs_on_wgpu_and_equals_cpu(harmonic_bake):
    """The WGSL of a bake with RGBA specular maps on wgpu (lavapipe) equals bake.terms and bake.evaluate."""
    check_wgsl(harmonic_bake, 400, (1e-3, 3e-3))
