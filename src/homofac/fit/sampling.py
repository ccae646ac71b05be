"""Sample iterators: which direction pairs (a, b) the target is sampled at (thesis §4.2, §5.6).

* ``texels``: reverse projection of the texel centres of a mapper grid (thesis eq. 46), once for a
  and once for b, all pairs kept that are valid. For GSHD the grid directions are read as (h, d) and
  turned into (wi, wo) (thesis §4.2, last paragraph).
* ``latlong``: a latitude/longitude grid for both directions (thesis §4.2).
* ``random``: uniformly distributed directions, seeded.

Valid pairs (docs/conventions.md): BRDF targets need wi.z > 0 and wo.z > 0; lighting targets need n.v > 0
(the valid-view filter of thesis §5.6). Invalid pairs are never produced, so they are never evaluated.
The validation set is always ``random`` with its own seed.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..errors import HomofacError
from ..param import mappers, projections

#: Smallest cosine accepted as "above the surface" for a valid pair.
MIN_COS = 1e-4


class Pairs(NamedTuple):
    """Direction pairs (float32 numpy arrays (M, 3))."""

    a: np.ndarray
    b: np.ndarray

    def __len__(self) -> int:
        return int(self.a.shape[0])


def _normalize(d: np.ndarray) -> np.ndarray:
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def valid_pairs(kind: str, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Boolean mask of valid pairs for a target kind."""
    if kind == "brdf":
        return (a[:, 2] > MIN_COS) & (b[:, 2] > MIN_COS)
    return np.sum(a * b, axis=-1) > MIN_COS


def grid_directions(mapper: str, size: int, hemisphere: bool) -> np.ndarray:
    """Centre directions of the texels inside the domain of a ``size`` grid of ``mapper`` (eq. 46)."""
    m = mappers.get(mapper)
    d = np.asarray(mappers.texel_directions(m, size), dtype=np.float64)[mappers.inside_mask(m, size)]
    if hemisphere:
        d = d[d[:, 2] > MIN_COS]
    return _normalize(d)


def latlong_directions(size: int, hemisphere: bool) -> np.ndarray:
    """A lat-long grid: ``size`` steps in phi, size/4 (hemisphere) or size/2 (sphere) in theta."""
    n_theta = max(1, size // 4 if hemisphere else size // 2)
    theta_max = np.pi / 2 if hemisphere else np.pi
    theta = (np.arange(n_theta) + 0.5) * theta_max / n_theta
    phi = (np.arange(size) + 0.5) * 2 * np.pi / size
    t, p = np.meshgrid(theta, phi, indexing="ij")
    d = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    return d


def random_directions(rng: np.random.Generator, count: int, hemisphere: bool) -> np.ndarray:
    """Uniform directions on the sphere (or the upper hemisphere)."""
    d = _normalize(rng.normal(size=(count, 3)))
    if hemisphere:
        d[:, 2] = np.abs(d[:, 2])
    return d


def all_pairs(kind: str, da: np.ndarray, db: np.ndarray) -> Pairs:
    """Every valid pair of a direction from ``da`` with one from ``db`` (vectorised product)."""
    a = np.repeat(da, len(db), axis=0)
    b = np.tile(db, (len(da), 1))
    keep = valid_pairs(kind, a, b)
    return Pairs(a[keep].astype(np.float32), b[keep].astype(np.float32))


def half_difference_to_pairs(h: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Invert the GSHD projection (eq. 22): wi = d_x t' + d_y b' + d_z h, wo = 2 (wi.h) h - wi."""
    x = np.broadcast_to(np.array([1.0, 0.0, 0.0]), h.shape)
    tp = x - np.sum(x * h, -1, keepdims=True) * h
    tp = _normalize(tp)
    bp = np.cross(h, tp)
    wi = d[:, 0:1] * tp + d[:, 1:2] * bp + d[:, 2:3] * h
    wo = 2 * np.sum(wi * h, -1, keepdims=True) * h - wi
    return wi, wo


def sample_pairs(
    kind: str,
    sampling_kind: str,
    size: int,
    *,
    mapper: str,
    parametrization: str = "",
    count: int = 0,
    seed: int = 0,
    view_size: int | None = None,
) -> Pairs:
    """Training pairs for a target of ``kind`` ("brdf" or "lighting").

    Args:
        kind: target kind; decides the domain (hemisphere pairs or sphere pairs with n.v > 0).
        sampling_kind: ``texels``, ``latlong`` or ``random``.
        size: grid size of the sampling mapper (texels) or phi steps (latlong) for the first direction.
        view_size: the same for the second direction (wo, or d for GSHD); default ``size``
            (the two direction iterators of thesis §6.1.5 have their own sizes).
        mapper: the mapper whose texel grid is reverse-projected (``texels`` only).
        parametrization: with ``GSHD`` the texel grids are read as (h, d) (thesis §4.2).
        count: number of random pairs (``random`` only).
        seed: random seed (``random`` only).
    """
    hemi = kind == "brdf"
    view_size = view_size or size
    if sampling_kind == "grid":
        raise HomofacError("sampling.kind: grid pairs texel centres of n and r, for lighting targets; "
                           "BRDF targets use texels, latlong or random")
    if sampling_kind in ("texels", "auto"):
        m = mappers.get(mapper)
        if not m.covers_sphere and not hemi:
            raise HomofacError(f"sampling.mapper {mapper} covers only a hemisphere; lighting needs a sphere mapper")
        g = grid_directions(mapper, size, hemi)
        g2 = grid_directions(mapper, view_size, hemi)
        if kind == "brdf" and parametrization == "GSHD":
            h = np.repeat(g, len(g2), axis=0)
            d = np.tile(g2, (len(g), 1))
            wi, wo = half_difference_to_pairs(h, d)
            keep = valid_pairs(kind, wi, wo)
            return Pairs(_normalize(wi[keep]).astype(np.float32), _normalize(wo[keep]).astype(np.float32))
        return all_pairs(kind, g, g2)
    if sampling_kind == "latlong":
        return all_pairs(kind, latlong_directions(size, hemi), latlong_directions(view_size, hemi))
    if sampling_kind == "random":
        return random_pairs(kind, count or size * size * view_size * view_size // 4, seed)
    raise HomofacError(f"sampling.kind must be texels, latlong or random, got {sampling_kind!r}")


def random_pairs(kind: str, count: int, seed: int) -> Pairs:
    """``count`` uniformly random valid pairs (rejection of invalid ones), reproducible from ``seed``."""
    rng = np.random.default_rng(seed)
    hemi = kind == "brdf"
    out_a, out_b, have = [np.zeros((0, 3))], [np.zeros((0, 3))], 0
    while have < count:  # rejection rounds (about 2 for lighting), not a loop over samples
        n = 2 * (count - have) + 16
        a = random_directions(rng, n, hemi)
        b = random_directions(rng, n, hemi)
        keep = valid_pairs(kind, a, b)
        out_a.append(a[keep])
        out_b.append(b[keep])
        have += int(keep.sum())
    a = np.concatenate(out_a)[:count]
    b = np.concatenate(out_b)[:count]
    return Pairs(a.astype(np.float32), b.astype(np.float32))


class Grouped(NamedTuple):
    """Lighting pairs grouped by normal: G normals, P views each, mask of the valid (n . v > 0) ones.

    The lighting computation does the per-normal work (texel weights, local light frame, diffuse
    term, horizon culling) once per group (:meth:`homofac.light.Lighting.grouped`).
    """

    normals: np.ndarray  # (G, 3)
    views: np.ndarray  # (G, P, 3)
    mask: np.ndarray  # (G, P) bool

    def flatten(self) -> Pairs:
        """The valid pairs, normal-major (the order of :func:`all_pairs`)."""
        g, p = self.mask.shape
        a = np.broadcast_to(self.normals[:, None, :], (g, p, 3))[self.mask]
        return Pairs(a.astype(np.float32), self.views[self.mask].astype(np.float32))


def group_product(normals: np.ndarray, views: np.ndarray) -> Grouped:
    """All valid (n, v) of two direction sets, grouped by normal; views padded per normal."""
    valid = normals @ views.T > MIN_COS  # (G, V)
    p = max(1, int(valid.sum(axis=1).max()))
    # stable sort puts each normal's valid views first, in their original order
    order = np.argsort(~valid, axis=1, kind="stable")[:, :p]
    mask = np.take_along_axis(valid, order, axis=1)
    v = views[order]
    return Grouped(normals.astype(np.float32), v.astype(np.float32), mask)


def grouped_pairs(sampling_kind: str, size: int, *, mapper: str, count: int = 0, seed: int = 0,
                  view_size: int | None = None, projection: str = "r", context: dict | None = None) -> Grouped:
    """Lighting training pairs grouped by normal (same pairs as :func:`sample_pairs`); ``projection``
    (and its ``context``): the direction the ``grid`` design puts on texel centres beside ``n``."""
    view_size = view_size or size
    if sampling_kind == "grid":
        return grouped_grid(mapper, size, count, seed, projection=projection, context=context)
    if sampling_kind in ("texels", "auto"):
        m = mappers.get(mapper)
        if not m.covers_sphere:
            raise HomofacError(f"sampling.mapper {mapper} covers only a hemisphere; lighting needs a sphere mapper")
        return group_product(grid_directions(mapper, size, False), grid_directions(mapper, view_size, False))
    if sampling_kind == "latlong":
        return group_product(latlong_directions(size, False), latlong_directions(view_size, False))
    if sampling_kind == "random":
        return grouped_random(count or size * size * view_size * view_size // 4, seed)
    raise HomofacError(f"sampling.kind must be texels, latlong, random or grid, got {sampling_kind!r}")


def grouped_random(count: int, seed: int, views: int | None = None) -> Grouped:
    """``count`` random valid lighting pairs: about sqrt(count) uniform normals (``count / views`` with
    ``views``), each with uniform views on its upper hemisphere (the same distribution as uniform pairs
    conditioned on n . v > 0)."""
    rng = np.random.default_rng(seed)
    if count <= 0:
        return Grouped(np.zeros((0, 3), np.float32), np.zeros((0, 1, 3), np.float32), np.zeros((0, 1), bool))
    g = max(1, int(round(np.sqrt(count) if views is None else count / max(int(views), 1))))
    p = -(-count // g)
    n = random_directions(rng, g, False)
    v = _normalize(rng.normal(size=(g, p, 3)))
    flip = np.sum(v * n[:, None, :], axis=-1) < 0
    v = np.where(flip[..., None], -v, v)
    mask = (np.arange(g * p) < count).reshape(g, p) & (np.sum(v * n[:, None, :], axis=-1) > MIN_COS)
    return Grouped(n.astype(np.float32), v.astype(np.float32), mask)


#: Training pairs of the ``grid`` design when ``sampling.count`` is 0: environments with a sun or small
#: lamps need about this many (100k left glints unresolved; benchmarks/accuracy.py).
GRID_COUNT = 300_000


def grid_texel_pairs(mapper: str, size: int, count: int, seed: int, projection: str = "r",
                     context: dict | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``count`` pairs ``(a, b)`` of flat texel indices of a ``size`` grid of ``mapper`` and their views
    ``v``: texel centres ``n = dirs[a]`` and ``p = dirs[b]`` inside the domain, drawn with probability
    proportional to the texel solid angles, ``v`` the view that ``projection`` maps to ``p`` at ``n``
    (for ``r``: ``v = 2 (n.p) n - p``), kept when ``n.v > MIN_COS`` and with the projection's density
    (d omega_v / d omega_p, :attr:`homofac.param.projections.Projection.invert`), so ``(n, v)`` follow
    the validation distribution."""
    m = mappers.get(mapper)
    proj = projections.get(projection, "lighting")
    if proj.invert is None or proj.scalar:
        raise HomofacError(f"sampling.kind: grid puts n and a direction on texel centres; {projection} has no inverse")
    ctx = context or {}
    dirs = np.asarray(mappers.texel_directions(m, size), np.float64).reshape(-1, 3)
    inside = np.asarray(mappers.inside_mask(m, size)).reshape(-1)
    omega = np.asarray(mappers.texel_solid_angles(m, size), np.float64).reshape(-1)
    idx = np.nonzero(inside & (omega > 0))[0]
    pr = omega[idx] / omega[idx].sum()
    rng = np.random.default_rng(seed)
    out_a, out_b, out_v, have, rate = [], [], [], 0, 0.5
    while have < count:  # rejection rounds (about 2 for r), vectorised; the batch follows the acceptance rate
        k = int(min(4_000_000, (count - have) / rate + 64))
        a = idx[rng.choice(len(idx), size=k, p=pr)]
        b = idx[rng.choice(len(idx), size=k, p=pr)]
        v, density = proj.invert(dirs[a], dirs[b], ctx)
        keep = np.sum(dirs[a] * v, axis=-1) > MIN_COS
        if np.any(density < 1):  # r (an isometry) draws nothing more: its pairs are those of earlier versions
            keep &= rng.random(k) < density
            rate = max(float(keep.mean()), 1e-3)
        out_a.append(a[keep])
        out_b.append(b[keep])
        out_v.append(v[keep])
        have += int(keep.sum())
    return np.concatenate(out_a)[:count], np.concatenate(out_b)[:count], np.concatenate(out_v)[:count]


def grouped_grid(mapper: str, size: int, count: int, seed: int, *, projection: str = "r",
                 context: dict | None = None) -> Grouped:
    """Lighting pairs of the ``grid`` design, grouped by normal: ``n`` and the direction
    ``projection(n, v)`` (the mirror direction ``r = 2 (n.v) n - v`` by default, ``r_off`` for the
    off-specular products) are texel centres of the fitted textures' own grid, so every ``n``- and
    ``r``-lookup of a training pair reads exactly one texel and alternating least squares decouples
    per texel (:mod:`homofac.fit.als`)."""
    if not mappers.get(mapper).covers_sphere:
        raise HomofacError(f"grid sampling on {mapper}: lighting needs a sphere mapper")
    a, b, v = grid_texel_pairs(mapper, size, count or GRID_COUNT, seed, projection, context)
    dirs = np.asarray(mappers.texel_directions(mapper, size), np.float64).reshape(-1, 3)
    order = np.argsort(a, kind="stable")
    a, v = a[order], _normalize(v[order])
    groups, start, counts = np.unique(a, return_index=True, return_counts=True)
    n = dirs[groups]
    p = int(counts.max())
    slot = np.arange(len(a)) - np.repeat(start, counts)
    g_of = np.repeat(np.arange(len(groups)), counts)
    views = np.broadcast_to(n[:, None, :], (len(groups), p, 3)).copy()
    mask = np.zeros((len(groups), p), bool)
    views[g_of, slot] = v
    mask[g_of, slot] = True
    return Grouped(n.astype(np.float32), views.astype(np.float32), mask)


def regroup(a: np.ndarray, b: np.ndarray) -> Grouped:
    """Flat lighting pairs (normal-major, as :meth:`Grouped.flatten` writes them) grouped again by normal:
    each run of consecutive equal normals is one group, so ``regroup(*g.flatten())`` holds the pairs of
    ``g`` in the same order (what a refit reuses of a run's samples, whatever produced them)."""
    a = np.asarray(a, np.float32)
    b = np.asarray(b, np.float32)
    m = int(a.shape[0])
    if m == 0:
        return Grouped(np.zeros((0, 3), np.float32), np.zeros((0, 1, 3), np.float32), np.zeros((0, 1), bool))
    start = np.concatenate([[True], np.any(a[1:] != a[:-1], axis=1)])
    group = np.cumsum(start) - 1  # group index of every pair
    first = np.nonzero(start)[0]
    counts = np.diff(np.append(first, m))
    slot = np.arange(m) - first[group]
    g, p = len(first), int(counts.max())
    normals = a[first]
    views = np.broadcast_to(normals[:, None, :], (g, p, 3)).copy()  # padding: v = n (valid, never read)
    mask = np.zeros((g, p), bool)
    views[group, slot] = b
    mask[group, slot] = True
    return Grouped(normals, views, mask)
