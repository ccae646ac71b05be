"""Ridge pairs: importance-sampled training pairs where a bright light's reflection grazes the surface.

Under a sun the lighting of a microfacet BRDF has a narrow ridge: views that graze the surface
(``n.v`` small) and reflect the light (``r`` near its direction ``l``) with the light just above the
horizon of ``n``. There the V-cavity shadowing of Cook-Torrance, ``G = min(1, 2 n.h n.v / v.h,
2 n.h n.l / v.h)``, turns ``f cos = D F G / (4 n.v)`` into ``D F n.h / (2 v.h)``, and ``v.h`` is about
``(n.v + n.l) / 2``: the value grows as ``1 / (n.v + n.l)`` toward the horizon (44 for the plastic under
the bundled city sun, where the mean lighting is 0.37). The region holds about 4e-4 of the validation
distribution's pairs and, under the city sun, most of the squared error of 270 000 uniform pairs
(docs/notes/sums-research.md, "The grazing ridge of the sun"); 600 000 grid pairs put none of theirs lit at ``v.h <
0.02``, so the fit never sees the ridge and the highlight's Fresnel line stays flat there.

:func:`ridge_pairs` draws pairs uniformly over the union of the ridges ``R_j`` of the lights ``l_j``::

    R_j = { (n, v) : n.v < band,  angle(r, l_j) < cap,  n.l_j > -below }

with a weight per pair that makes them an unbiased stratum of the validation distribution (uniform
``n``, ``v`` uniform on the hemisphere of ``n``): ``weight(x) = 1 / sum_j (M_j / P_j) 1[x in R_j]``, the
balance heuristic of multiple importance sampling over the lights' strata (Veach 1997, eq. 9.10),
``P_j`` the probability of ``R_j``. Under that distribution ``r`` is uniform on the sphere and ``n.r``
uniform on (0, 1) given ``r``, and the reflection ``v = 2 (n.r) n - r`` keeps solid angle, so drawing
``r`` uniformly on the cap of ``l_j``, ``t = n.r`` uniformly in (MIN_COS, band) and ``n`` at a uniform
azimuth about ``r`` is uniform on the cone part of ``R_j``; the horizon condition is a rejection, so
``P_j = (1 - cos cap) / 2 * (band - MIN_COS) / (1 - MIN_COS) * acceptance``.

A sum over the ridge pairs of ``weight * g`` estimates ``E[g 1_R]`` over validation pairs; times N it
stands for N uniform pairs' share of the region, which is how :mod:`homofac.fit.polish` adds them to
its objective (the polish's own pairs inside the region get weight 0, so nothing counts twice).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from jaxtyping import Float

from .. import sphere
from .sampling import MIN_COS

#: Half angle (degrees) of the cone of reflections around a light that the ridge holds.
RIDGE_CAP_DEGREES = 12.0
#: Largest n.v of a ridge pair.
RIDGE_BAND = 0.06
#: How far below the horizon of n the light may stand (n.l > -below): the straddling disc of a sun.
RIDGE_BELOW = 0.02


class RidgePairs(NamedTuple):
    """Ridge pairs (float32 (M, 3)) and their weights (float64 (M,), in units of validation pairs:
    ``sum(weight)`` estimates the probability of the union of the ridges)."""

    a: np.ndarray
    b: np.ndarray
    weight: np.ndarray
    probability: tuple[float, ...]  # P_j of each light's ridge


def in_ridge(a: Float[np.ndarray, "N 3"], b: Float[np.ndarray, "N 3"], light: Float[np.ndarray, "3"],
             cap_degrees: float = RIDGE_CAP_DEGREES, band: float = RIDGE_BAND,
             below: float = RIDGE_BELOW) -> np.ndarray:
    """Whether the lighting pairs ``(n, v) = (a, b)`` lie on the ridge of ``light`` (see the module doc)."""
    a, b, light = (np.asarray(x, np.float64) for x in (a, b, light))
    r = sphere.reflect(b, a)
    return (sphere.dot(a, b) < band) & (r @ light > np.cos(np.radians(cap_degrees))) & (a @ light > -below)


def _frame(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to the unit rows of ``d`` and to each other."""
    up = np.where(np.abs(d[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(d, up)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(d, e1)


def _one_light(rng: np.random.Generator, light: np.ndarray, count: int, cap: float, band: float, below: float):
    """``count`` pairs uniform on the ridge of one light and its probability ``P_j``: drawn in rounds of
    twice what is missing (the horizon rejection keeps about half, or all for a high light)."""
    got_a, got_b, tried, kept = [], [], 0, 0
    e1, e2 = _frame(light[None])
    while kept < count:
        k = 2 * (count - kept) + 64
        ct = rng.uniform(np.cos(np.radians(cap)), 1.0, k)
        phi = rng.uniform(0.0, 2.0 * np.pi, k)
        r = ct[:, None] * light + np.sqrt(1.0 - ct * ct)[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
        t = rng.uniform(MIN_COS, band, k)
        psi = rng.uniform(0.0, 2.0 * np.pi, k)
        f1, f2 = _frame(r)
        n = t[:, None] * r + np.sqrt(1.0 - t * t)[:, None] * (np.cos(psi)[:, None] * f1 + np.sin(psi)[:, None] * f2)
        ok = n @ light > -below
        tried += k
        kept += int(ok.sum())
        got_a.append(n[ok])
        got_b.append(2.0 * t[ok, None] * n[ok] - r[ok])
    acceptance = kept / tried
    p = (1.0 - np.cos(np.radians(cap))) / 2.0 * (band - MIN_COS) / (1.0 - MIN_COS) * acceptance
    return np.concatenate(got_a)[:count], np.concatenate(got_b)[:count], float(p)


def ridge_pairs(lights: Float[np.ndarray, "L 3"], count: int, seed: int, cap_degrees: float = RIDGE_CAP_DEGREES,
                band: float = RIDGE_BAND, below: float = RIDGE_BELOW) -> RidgePairs:
    """``count`` pairs on the ridges of ``lights`` (``count // L`` per light, the rest to the first), seeded,
    with their balance-heuristic weights (see the module doc)."""
    lights = np.asarray(lights, np.float64).reshape(-1, 3)
    lights = lights / np.linalg.norm(lights, axis=1, keepdims=True)
    rng = np.random.default_rng(seed)
    per = [count // len(lights) + (count % len(lights) if j == 0 else 0) for j in range(len(lights))]
    used = [(l, m) for l, m in zip(lights, per) if m > 0]
    if not used:
        z = np.zeros((0, 3), np.float32)
        return RidgePairs(z, z, np.zeros(0), ())
    drawn = [_one_light(rng, l, m, cap_degrees, band, below) for l, m in used]
    a = np.concatenate([d[0] for d in drawn])
    b = np.concatenate([d[1] for d in drawn])
    probs = tuple(d[2] for d in drawn)
    density = sum(m / p * in_ridge(a, b, l, cap_degrees, band, below) for (l, m), p in zip(used, probs))
    return RidgePairs(a.astype(np.float32), b.astype(np.float32), 1.0 / density, probs)


def in_any_ridge(a, b, lights, cap_degrees: float = RIDGE_CAP_DEGREES, band: float = RIDGE_BAND,
                 below: float = RIDGE_BELOW) -> np.ndarray:
    """Whether the pairs lie on the ridge of any of ``lights``."""
    out = np.zeros(np.shape(a)[0], bool)
    for light in np.asarray(lights, np.float64).reshape(-1, 3):  # a few lights
        out |= in_ridge(a, b, light / np.linalg.norm(light), cap_degrees, band, below)
    return out


def stratified_nrmse(approx: Float[np.ndarray, "N 3"], exact: Float[np.ndarray, "N 3"], inside: np.ndarray,
                     approx_ridge: Float[np.ndarray, "M 3"], exact_ridge: Float[np.ndarray, "M 3"],
                     weight: Float[np.ndarray, "M"]) -> float:
    """The nrmse of N uniform validation pairs (``approx`` against ``exact``) with the ridge as its own
    stratum: the pairs ``inside`` it are left out and the ridge pairs stand in for them, each weighing
    ``N * weight`` validation pairs (:class:`RidgePairs`). Per channel
    ``sqrt((sum_out d^2 + N sum_ridge w d^2) / (sum_out e^2 + N sum_ridge w e^2))``, averaged over RGB as
    the pinned ``nrmse``: the same quantity, without the few dozen ridge pairs of a validation set
    deciding it (plastic under the city sun: 0.071 against 0.072 on 270 000 uniform pairs, where the
    80 000 validation pairs read 0.054)."""
    approx, exact = np.asarray(approx, np.float64), np.asarray(exact, np.float64)
    approx_ridge, exact_ridge = np.asarray(approx_ridge, np.float64), np.asarray(exact_ridge, np.float64)
    out = ~np.asarray(inside, bool)[:, None]
    w = len(exact) * np.asarray(weight, np.float64)[:, None]
    num = np.sum(out * (approx - exact) ** 2, axis=0) + np.sum(w * (approx_ridge - exact_ridge) ** 2, axis=0)
    den = np.sum(out * exact ** 2, axis=0) + np.sum(w * exact_ridge ** 2, axis=0)
    return float(np.mean(np.sqrt(num / np.maximum(den, 1e-30))))


__all__ = ["RIDGE_BAND", "RIDGE_BELOW", "RIDGE_CAP_DEGREES", "RidgePairs", "in_any_ridge", "in_ridge", "ridge_pairs",
           "stratified_nrmse"]
