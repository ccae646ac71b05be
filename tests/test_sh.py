"""Spherical harmonics of irradiance (homofac.light.sh): values, order and frame, files (sh9.json, Filament)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

import homofac as hf
from homofac.baselines import split_sum
from homofac.light import sh as shm
from homofac.param import mappers

AXES = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
K0, K1 = 0.5 / np.sqrt(np.pi), np.sqrt(3 / (4 * np.pi))
K2, K20, K22 = np.sqrt(15 / (4 * np.pi)), np.sqrt(5 / (16 * np.pi)), np.sqrt(15 / (16 * np.pi))


def band2_env(b: np.ndarray, resolution: int = 16):
    """An environment whose radiance is ``sum_i b_i Y_i`` (b: (9, 3)), texels averaged from a 4x finer cube."""
    d = mappers.texel_directions("cube", 4 * resolution).astype(np.float64)
    img = shm.sh9_basis(d.reshape(-1, 3)) @ b
    assert img.min() > 0
    return hf.light.from_cube(img.reshape(d.shape[:2] + (3,)).astype(np.float32), resolution)


B = np.array([[3.0, 2.5, 2.0], [0.4, -0.2, 0.1], [0.6, 0.5, 0.3], [-0.3, 0.2, 0.5], [0.2, 0.1, -0.1],
              [-0.15, 0.1, 0.2], [0.25, -0.1, 0.05], [0.1, 0.3, -0.2], [-0.2, 0.15, 0.1]])


def test_constant_environment_is_pi_l():
    """A constant radiance L gives E = pi L everywhere, only c_00 non-zero; Filament's s_0 = L (E/pi)."""
    L = np.array([0.5, 1.0, 2.0])
    s = hf.light.sh9(hf.light.uniform(L, 16), error_size=8)
    n = np.random.default_rng(0).normal(size=(50, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    np.testing.assert_allclose(s.irradiance(n), np.pi * np.broadcast_to(L, (50, 3)), rtol=1e-6)
    assert np.abs(s.coefficients[1:]).max() < 1e-6 * s.coefficients[0].min()
    np.testing.assert_allclose(s.filament()[0], L, rtol=1e-6)
    assert s.error["nrmse"] < 1e-5


def test_band2_environment_matches_exact_irradiance():
    """An environment that is itself band-2: c_i = A_l b_i, and SH9 equals the exact irradiance."""
    env = band2_env(B)
    s = hf.light.sh9(env, error_size=8)
    np.testing.assert_allclose(s.coefficients, shm.SH9_COSINE[:, None] * B, atol=2e-3 * np.abs(B).max())
    n = mappers.texel_directions("cube", 8).reshape(-1, 3)
    exact = np.asarray(hf.light.irradiance(env, n.astype(np.float32)), np.float64)
    np.testing.assert_allclose(s.irradiance(n), exact, rtol=2e-3)
    assert s.error["nrmse"] < 1e-3


@pytest.mark.parametrize("i", range(1, 9))
def test_coefficient_order(i):
    """Radiance 1 + 0.3 P_i (P_i = y, z, x, xy, yz, 3z^2-1, xz, x^2-y^2) puts its weight on c_i alone."""
    b = np.zeros((9, 3))
    b[0] = 1 / K0
    b[i] = 0.3 / shm.SH9_NORM[i]
    c = hf.light.sh9(band2_env(b, 8), error_size=None).coefficients
    assert np.argmax(np.abs(c[1:, 0])) + 1 == i
    assert np.abs(c[1:, 0]).max() > 20 * np.sort(np.abs(c[1:, 0]))[-2]


def test_frame_at_the_axes():
    """E at +-x, +-y, +-z as the written-out formula in homofac's +z-up frame (the band-2 test compares it
    with the exact irradiance)."""
    s = hf.light.sh9(band2_env(B), error_size=None)
    c = s.coefficients
    want = np.stack([
        K0 * c[0] + K1 * c[3] - K20 * c[6] + K22 * c[8],   # +x
        K0 * c[0] - K1 * c[3] - K20 * c[6] + K22 * c[8],   # -x
        K0 * c[0] + K1 * c[1] - K20 * c[6] - K22 * c[8],   # +y
        K0 * c[0] - K1 * c[1] - K20 * c[6] - K22 * c[8],   # -y
        K0 * c[0] + K1 * c[2] + 2 * K20 * c[6],            # +z
        K0 * c[0] - K1 * c[2] + 2 * K20 * c[6],            # -z
    ])
    np.testing.assert_allclose(s.irradiance(AXES), want, rtol=1e-12)
    # a light from +z (up) lights +z most: the frame is homofac's, not a y-up one
    sky = hf.light.gradient_sky(1.0, 0.8, 16)
    e = hf.light.sh9(sky, error_size=None).irradiance(AXES)[:, 0]
    assert np.argmax(e) == 4 and np.argmin(e) == 5


def test_filament_form(tmp_path):
    """sh.txt: 9 lines in cmgen's layout whose polynomial, evaluated at the y-up engine direction
    (x, z, -y) of a homofac normal, is E/pi there."""
    s = hf.light.sh9(band2_env(B, 8), error_size=None)
    p = s.save_filament(tmp_path / "sh.txt")
    lines = p.read_text().splitlines()
    assert [ln.split("// ")[1].split(",")[0] for ln in lines] == list(shm.SH9_NAMES)
    assert all(ln.endswith("irradiance, pre-scaled base") for ln in lines)
    vals = np.array([[float(x) for x in re.match(r"\((.*)\);", ln).group(1).split(",")] for ln in lines])
    np.testing.assert_allclose(vals, s.filament(), atol=1e-14)
    n = np.random.default_rng(1).normal(size=(40, 3))
    n = np.concatenate([AXES, n / np.linalg.norm(n, axis=1, keepdims=True)])
    e = np.stack([n[:, 0], n[:, 2], -n[:, 1]], axis=1)  # engine (y-up) direction of each homofac normal
    x, y, z = e[:, 0], e[:, 1], e[:, 2]
    filament = (vals[0] + vals[1] * y[:, None] + vals[2] * z[:, None] + vals[3] * x[:, None]
                + vals[4] * (y * x)[:, None] + vals[5] * (y * z)[:, None] + vals[6] * (3 * z * z - 1)[:, None]
                + vals[7] * (z * x)[:, None] + vals[8] * (x * x - y * y)[:, None])
    np.testing.assert_allclose(filament, s.irradiance(n) / np.pi, rtol=1e-9, atol=1e-12)


def test_sh9_json(tmp_path):
    """sh9.json: the pinned irradiance list (9 x RGB) and the error against the exact irradiance."""
    s = hf.light.sh9(hf.light.gradient_sky(1.0, 0.5, 16), error_size=8)
    doc = json.loads(s.save_json(tmp_path / "sh9.json").read_text())
    assert np.array(doc["irradiance"]).shape == (9, 3)
    np.testing.assert_allclose(doc["irradiance"], s.coefficients)
    assert 0 <= doc["error"]["nrmse"] < 1e-3 and doc["error"]["directions"] == 6 * 8 * 8


def test_split_sum_uses_the_same_math():
    """split_sum's sh9 irradiance is light.sh's (one place)."""
    assert split_sum.sh9_basis is shm.sh9_basis and split_sum.sh9_irradiance is shm.sh9_irradiance
