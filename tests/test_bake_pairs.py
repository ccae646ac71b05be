"""The bake accuracy benchmark's weighted pairs (benchmarks/bake_pairs.py) estimate the population's integrals."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import qmc

import homofac as hf
from homofac.io.exr import read_exr
from homofac.light.environment import LUMINANCE
from homofac.light.latlong import latlong_solid_angles

ROOT = Path(__file__).resolve().parents[1]


def _pairs_module():
    spec = importlib.util.spec_from_file_location("homofac_bench_bake_pairs", ROOT / "benchmarks" / "bake_pairs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


bp = _pairs_module()


@pytest.fixture(scope="module")
def city():
    return read_exr(hf.light.bundled("city"))


def _pixel_luminance(image, r):
    """The luminance of the lat-long pixel holding each direction r (N, 3) (pinned layout)."""
    h, w = image.shape[:2]
    th = np.arccos(np.clip(r[:, 2], -1, 1))
    ph = np.mod(np.arctan2(r[:, 1], r[:, 0]), 2 * np.pi)
    row = np.clip((th * h / np.pi).astype(int), 0, h - 1)
    col = np.clip((ph * w / (2 * np.pi)).astype(int), 0, w - 1)
    return np.maximum(image[row, col, :3] @ np.asarray(LUMINANCE), 0)


@pytest.mark.parametrize("nv, mean_nv, share", [("cosine", 2 / 3, bp.NV_SHARE), ("uniform", 1 / 2, bp.NV_SHARE),
                                                 ("cosine", 2 / 3, 1.0), ("uniform", 1 / 2, 0.25)])
def test_weighted_pairs_estimate_the_population(city, nv, mean_nv, share):
    """Weighted means over the importance-sampled pairs equal the population's expectations: E[n.v] (2/3 for
    the cosine law, 1/2 for the uniform hemisphere) and the population's share of n.v < 0.3 (0.09, 0.3), E[r] = 0,
    E[r r^T] = I/3 (r uniform), and the mean luminance (and its square) of the environment seen along r, which
    the proposal concentrates on; with n | r drawn from (2') at any share of p0's own conditional."""
    n, v, c, m, rho, w = bp.weighted_pairs(city, (0.045, 0.15), 4096, 5, nv, share)
    assert np.allclose(np.linalg.norm(n, axis=1), 1) and np.allclose(np.linalg.norm(v, axis=1), 1)
    x = np.sum(n * v, 1)
    assert x.min() > 0
    r = 2 * x[:, None] * n - v
    mean = lambda f: np.sum(w * f) / np.sum(w)  # noqa: E731
    assert abs(mean(x) - mean_nv) < 0.01
    below = 0.09 if nv == "cosine" else 0.3
    assert abs(mean(x < 0.3) - below) < 0.01
    assert np.all(np.abs(np.einsum("i,ij->j", w, r) / w.sum()) < 0.02)
    assert np.allclose(np.einsum("i,ij,ik->jk", w, r, r) / w.sum(), np.eye(3) / 3, atol=0.02)
    h, wd = city.shape[:2]
    y = np.maximum(city[..., :3] @ np.asarray(LUMINANCE), 0)
    dw = latlong_solid_angles(h, wd)[:, None]
    exact = [np.sum(y * dw) / (4 * np.pi), np.sum(y * y * dw) / (4 * np.pi)]
    yr = _pixel_luminance(city, r)
    assert abs(mean(yr) / exact[0] - 1) < 0.03
    assert abs(mean(yr * yr) / exact[1] - 1) < 0.05
    # the proposal puts pairs where the squared luminance is: a uniform draw holds few of those pairs
    bright = y >= np.quantile(y, 0.99)
    assert np.mean(yr >= y[bright].min()) > 0.3
    assert w.max() <= 1 / bp.MIXTURE[0] / share + 1e-9
    assert 0.04 <= rho.min() and rho.max() <= 0.15 and c.min() >= 0 and c.max() <= 1
    assert abs(np.mean(m == 0) - 1 / 3) < 0.01 and abs(np.mean(m == 1) - 1 / 3) < 0.01


def test_doubling_keeps_the_first_pairs(city):
    """The first N pairs of a cell are the first N of 2N (a doubling adds pairs), and a cell's pairs are its
    own: another seed draws others."""
    a = bp.weighted_pairs(city, (0.15, 0.3), 256, 9)
    b = bp.weighted_pairs(city, (0.15, 0.3), 512, 9)
    for x, y in zip(a, b):
        assert np.array_equal(x, y[:256])
    assert not np.allclose(bp.weighted_pairs(city, (0.15, 0.3), 256, 10)[0], a[0])


def test_weighted_nrmse_is_the_nrmse_of_the_weighted_population():
    """Integer weights count a pair that many times: the weighted nrmse equals the plain one of the repeated pairs."""
    rng = np.random.default_rng(0)
    e, a = rng.uniform(0, 1, (20, 3)), rng.uniform(0, 1, (20, 3))
    k = rng.integers(1, 4, 20)
    rep = np.repeat(np.arange(20), k)
    plain = np.linalg.norm(a[rep] - e[rep]) / np.linalg.norm(e[rep])
    assert bp.weighted_nrmse(a, e, k.astype(float)) == pytest.approx(plain, rel=1e-12)


def test_grazing_proposal_draws_grazing_pairs(city):
    """(2'): at the default share the pairs below n.v 0.3 are the drawn share of q (0.3 for the cosine
    population, 0.09 of p0), the weights bring them back to p0's share, and share 1 draws n | r as p0 (the
    seventeenth session's pairs, bit for bit)."""
    n, v, *_, w = bp.weighted_pairs(city, (0.15, 0.3), 4096, 7)
    x = np.sum(n * v, 1)
    c0, c1 = bp.nv_mixture("cosine", bp.NV_SHARE)
    assert np.mean(x < 0.3) == pytest.approx(c0 * 0.3 + c1 * 0.045, abs=0.005)
    assert np.sum(w * (x < 0.3)) / np.sum(w) == pytest.approx(0.09, abs=0.01)
    a = bp.weighted_pairs(city, (0.15, 0.3), 512, 7, "cosine", 1.0)
    u = qmc.Sobol(10, scramble=True, seed=7).random(512)
    assert np.allclose(np.sum(a[0] * a[1], 1), np.sqrt(1 - u[:, 3]))
    with pytest.raises(ValueError, match="share"):
        bp.weighted_pairs(city, (0.15, 0.3), 16, 7, "cosine", 0.0)


@pytest.mark.parametrize("c0, c1", [(0.0, 2.0), (1.0, 0.0), (2.0, -2.0), (0.5, 1.0), (1.5, -1.0)])
def test_grazing_draw_has_the_linear_density(c0, c1):
    """grazing_draw inverts the CDF c0 x + c1 x^2 / 2: the drawn x's histogram is the density c0 + c1 x."""
    u = (np.arange(200000) + 0.5) / 200000
    x = bp.grazing_draw(u, c0, c1)
    assert x.min() >= 0 and x.max() <= 1
    counts, edges = np.histogram(x, bins=10, range=(0, 1))
    mid = (edges[:-1] + edges[1:]) / 2
    assert np.allclose(counts / len(x) / 0.1, c0 + c1 * mid, atol=2e-3)
