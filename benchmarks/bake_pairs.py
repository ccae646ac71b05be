"""The accuracy benchmark's pairs: (n, v, material) importance-sampled over the reflected direction, with weights.

A cell of benchmarks/bake_accuracy.py (environment x roughness band) is the nrmse of a method's radiance a
against the reference e over a population of pairs p0(n, v, material):

    nrmse^2 = E_p0 |a - e|^2 / E_p0 |e|^2                                                          (1)

**The population** (``nv="cosine"``, the default): n uniform on the sphere and v cosine-distributed about n,
i.e. p0(n, v) = max(n.v, 0) / (4 pi^2). This is the distribution of (n, v) over the pixels of a rendered
convex object seen from a uniformly random direction: a surface element covers screen area in proportion to
its projected area n.v, so n.v has the density 2x on [0, 1] (a sphere: the image disc's radius is sin theta),
and a grazing view is as rare on screen as in this population (n.v < 0.1 on 1 % of the pixels; the former
uniform-hemisphere draw put 10 % of its pairs there). ``nv="uniform"``: v uniform on the hemisphere of n
(p0 = 1[n.v > 0] / (8 pi^2)), the draw of the earlier runs. Materials: roughness uniform in the band, base
colour uniform, metallic 0, 1 or uniform by thirds.

**The reflected direction carries the variance.** With r = 2 (n.v) n - v, the map (n, v) -> (n, r) is an
isometry of the sphere for each n, so p0(n, r) = p0(n, v): for both populations r is uniform on the sphere
and n | r has the same law as v | n (cosine, or uniform, about r). Below roughness 0.6 a pair's radiance and
error are dominated by the environment seen around r (a sun or a lamp carries a band's squared error), so r
is drawn from a defensive mixture (Hesterberg 1995) over the pixels of the source lat-long map:

    q(pixel) = 1/4 dw / 4 pi + 1/4 Y_b dw / sum(Y_b dw) + 1/4 Y_b^2 dw / sum(Y_b^2 dw)
               + 1/4 Y_1^2 dw / sum(Y_1^2 dw)                                                       (2)

with Y_b the luminance max-pooled over a window as wide as the band's reflection lobe (radius about
6 alpha_max, alpha = roughness^2) and Y_1 over 3 x 3 pixels (a sun's core: below roughness 0.15 the bake's
error sits within half a degree of it), r uniform in solid angle inside the pixel, and n | r drawn from p0's
own conditional. Pairs near a source at grazing views carry most of what is left (at n.v < 0.3, 9 % of the
cosine population, 40-90 % of the bake's squared error in the cells that did not converge in the seventeenth
session), so n | r is drawn from a second defensive mixture over x = n.v = n.r (azimuth about r uniform):

    q(x) = s p(x) + (1 - s) g(x),   g(x) = 2 (1 - x)                                                 (2')

with p(x) p0's own conditional density of x (2x for the cosine population, 1 for the uniform one), g a density
favouring grazing views, s = :data:`NV_SHARE` (1/2: for the cosine population q is uniform in x, and 30 % of
the pairs fall below n.v 0.3). Both are linear in x, so x is drawn by inverting the quadratic CDF
(:func:`grazing_draw`). Each pair is weighted by

    w = p0(n, r) / q(n, r) = [(dw / 4 pi) / q(pixel)] [p(x) / q(x)] <= 4 / s,

so that

    nrmse^2 ~= sum_i w_i |a_i - e_i|^2 / sum_i w_i |e_i|^2                                          (3)

estimates (1) (a ratio of two unbiased estimates). The points are a scrambled Sobol' sequence (pixel choice,
position in the pixel, n about r, roughness, base colour, metallic: 10 dimensions), so the first N pairs of a
cell are the first N of 2N: doubling adds pairs and keeps the earlier ones, and the pixel choice is stratified
by the proposal's cumulative probability.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import qmc

from homofac.light.environment import LUMINANCE
from homofac.light.latlong import latlong_solid_angles

#: Mixture shares of (2): uniform, pooled luminance, pooled luminance squared, luminance squared (3 x 3 pixels).
MIXTURE = (0.25, 0.25, 0.25, 0.25)
#: Radius of the luminance window in units of the band's largest alpha (the reflection lobe's width is
#: about 2 alpha; 3 widths keep a source's tails inside the window).
LOBE_RADII = 6.0
#: Share of p0's own conditional of n.v in (2'); the rest is g(x) = 2 (1 - x). 1: n | r as in p0 (the
#: seventeenth session's pairs).
NV_SHARE = 0.5
#: p(x) = c0 + c1 x, p0's conditional density of x = n.v for each population, and g(x) of (2').
NV_DENSITY = {"cosine": (0.0, 2.0), "uniform": (1.0, 0.0)}
GRAZING = (2.0, -2.0)


def pooled_luminance(image: np.ndarray, radius: float) -> np.ndarray:
    """Luminance (H, W) of a lat-long image, max-pooled over about ``radius`` radians: blocks of f x f pixels
    (f the power of two with f pi / H closest below radius / 1.5, at least 1), then the 3 x 3 maximum of the
    blocks (longitude wrapped), spread back over the block's pixels."""
    h, w = image.shape[:2]
    y = np.maximum(np.asarray(image[..., :3], np.float64) @ np.asarray(LUMINANCE), 0.0)
    f = 1
    while 2 * f * np.pi / h <= radius / 1.5 and 2 * f <= h:
        f *= 2
    if f >= h:
        return np.full((h, w), y.max())
    blocks = y.reshape(h // f, f, w // f, f).max(axis=(1, 3))
    pad = np.pad(blocks, ((1, 1), (0, 0)), mode="edge")
    pad = np.concatenate([pad[:, -1:], pad, pad[:, :1]], axis=1)
    hb, wb = blocks.shape
    pooled = np.max(np.stack([pad[1 + i:1 + i + hb, 1 + j:1 + j + wb] for i in (-1, 0, 1) for j in (-1, 0, 1)]), axis=0)
    return np.repeat(np.repeat(pooled, f, axis=0), f, axis=1)


def proposal(image: np.ndarray, band: tuple[float, float]) -> np.ndarray:
    """q(pixel) of (2), (H W,) summing to 1, for a lat-long image (H, 2H, 3) and a roughness band."""
    h, w = image.shape[:2]
    dw = np.broadcast_to(latlong_solid_angles(h, w)[:, None], (h, w))
    y = pooled_luminance(image, LOBE_RADII * band[1] ** 2)
    y1 = pooled_luminance(image, 0.0)
    parts = [dw, y * dw, y * y * dw, y1 * y1 * dw]
    q = sum(s * p / p.sum() for s, p in zip(MIXTURE, parts))
    return (q / q.sum()).reshape(-1)


def nv_mixture(nv: str, share: float) -> tuple[float, float]:
    """(c0, c1) of q(x) = c0 + c1 x of (2'): ``share`` of the population's conditional density of x = n.v plus
    1 - ``share`` of the grazing density g."""
    if not 0 < share <= 1:
        raise ValueError(f"the share of p0's n.v in the proposal must be in (0, 1], got {share}")
    p = NV_DENSITY[nv]
    return share * p[0] + (1 - share) * GRAZING[0], share * p[1] + (1 - share) * GRAZING[1]


def grazing_draw(u: np.ndarray, c0: float, c1: float) -> np.ndarray:
    """x in [0, 1] with density c0 + c1 x (a density: c0 + c1 / 2 = 1, c0 >= 0, c0 + c1 >= 0), from uniform
    ``u``: the root of the CDF c0 x + c1 x^2 / 2 = u, written 2u / (c0 + sqrt(c0^2 + 2 c1 u)) (no cancellation,
    and c1 = 0 gives x = u)."""
    return 2 * u / (c0 + np.sqrt(np.maximum(c0 * c0 + 2 * c1 * u, 0.0)))


def _basis(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing ``r`` (N, 3) to an orthonormal frame (Duff et al. 2017, branchless)."""
    s = np.where(r[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (s + r[:, 2])
    b = r[:, 0] * r[:, 1] * a
    t = np.stack([1 + s * r[:, 0] ** 2 * a, s * b, -s * r[:, 0]], 1)
    u = np.stack([b, s + r[:, 1] ** 2 * a, -r[:, 1]], 1)
    return t, u


def weighted_pairs(image: np.ndarray, band: tuple[float, float], count: int, seed: int, nv: str = "cosine",
                   nv_share: float = NV_SHARE):
    """The first ``count`` pairs of a cell (module docstring): ``n, v`` (N, 3), ``c`` (N, 3), ``m``, ``rho``,
    ``w`` (N,) float64 with ``w`` the weights of (3). ``image``: the source lat-long map (H, 2H, 3);
    ``nv_share``: s of (2')."""
    if nv not in NV_DENSITY:
        raise ValueError(f"nv must be 'cosine' or 'uniform', got {nv!r}")
    c0, c1 = nv_mixture(nv, nv_share)
    h, w_ = image.shape[:2]
    q = proposal(image, band)
    u = qmc.Sobol(10, scramble=True, seed=seed).random(count)
    cdf = np.cumsum(q)
    idx = np.clip(np.searchsorted(cdf, u[:, 0] * cdf[-1], side="right"), 0, q.size - 1)
    row, col = idx // w_, idx % w_
    edges = np.cos(np.pi * np.arange(h + 1) / h)
    z = edges[row] - u[:, 1] * (edges[row] - edges[row + 1])
    ph = 2 * np.pi * (col + u[:, 2]) / w_
    s = np.sqrt(np.maximum(1 - z * z, 0.0))
    r = np.stack([s * np.cos(ph), s * np.sin(ph), z], 1)
    dw = latlong_solid_angles(h, w_)[row]
    cos = np.clip(grazing_draw(1 - u[:, 3], c0, c1), 1e-6, 1.0)
    p = NV_DENSITY[nv]
    weight = dw / (4 * np.pi) / q[idx] * (p[0] + p[1] * cos) / (c0 + c1 * cos)
    sin = np.sqrt(np.maximum(1 - cos * cos, 0.0))
    t, b = _basis(r)
    n = cos[:, None] * r + sin[:, None] * (np.cos(2 * np.pi * u[:, 4])[:, None] * t + np.sin(2 * np.pi * u[:, 4])[:, None] * b)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    v = 2 * np.sum(n * r, 1)[:, None] * n - r
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    rho = band[0] + u[:, 5] * (band[1] - band[0])
    c = u[:, 6:9].copy()
    m = np.where(u[:, 9] < 1 / 3, 0.0, np.where(u[:, 9] < 2 / 3, 1.0, 3 * u[:, 9] - 2))
    return n, v, c, m, rho, weight


def weighted_nrmse(a, e, w) -> float:
    """(3): sqrt(sum w |a - e|^2 / sum w |e|^2), |.| over RGB."""
    a, e, w = np.asarray(a, np.float64), np.asarray(e, np.float64), np.asarray(w, np.float64)
    return float(np.sqrt(np.sum(w * np.sum((a - e) ** 2, 1)) / np.sum(w * np.sum(e * e, 1))))
