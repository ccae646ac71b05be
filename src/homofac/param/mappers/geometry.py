"""Texel geometry of a mapper: texture shapes, texel centres and directions, masks, solid angles.

Static tables in float64 NumPy, computed from the records of :mod:`.records` and cached per
``(mapper name, S)`` (read-only arrays). For the ``line`` mapper a "direction" is the scalar
x = (i + 0.5) / S of each texel and the solid angle is the length 1/S of its interval.
"""

from __future__ import annotations

import functools

import numpy as np
from jaxtyping import Bool, Float

from ...errors import HomofacError
from .records import Mapper, get, on_register, resolve


def check_size(S) -> int:
    """A texture size: a Python int >= 2."""
    if isinstance(S, bool) or not isinstance(S, (int, np.integer)) or S < 2:
        raise HomofacError(f"texture size must be a Python int >= 2, got {S!r}")
    return int(S)


def frozen(a: np.ndarray) -> np.ndarray:
    """``a``, made read-only (cached tables are shared)."""
    a.flags.writeable = False
    return a


def texture_shape(m: Mapper | str, S: int) -> tuple[int, int]:
    """``(H, W) = (S, faces S)``, or ``(1, S)`` for the line mapper (pinned)."""
    m = resolve(m)
    S = check_size(S)
    return m.rows(S), m.faces * S


def texel_centers(m: Mapper | str, S: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(face, u, v)`` of every texel centre, numpy ``(H, W)``: ``u = (col mod S + 0.5)/S``, ``v = (row + 0.5)/H``."""
    m = resolve(m)
    return _centers(m.name, check_size(S))


@functools.lru_cache(maxsize=None)
def _centers(name: str, S: int):
    m = get(name)
    H, W = m.rows(S), m.faces * S
    row, col = np.mgrid[0:H, 0:W]
    face = (col // S).astype(np.int32)
    return frozen(face), frozen((col % S + 0.5) / S), frozen((row + 0.5) / H)


@functools.lru_cache(maxsize=None)
def directions64(name: str, S: int) -> np.ndarray:
    """Reverse projection of every texel centre, float64 ``(H, W, 3)`` (``(1, S)`` scalars for line)."""
    return frozen(np.asarray(get(name).from_face_uv(*_centers(name, S)), np.float64))


def texel_directions(m: Mapper | str, S: int) -> Float[np.ndarray, "H W 3"]:
    """Reverse projection of every texel centre (e.g. thesis eq. 46), float32 ``(H, W, 3)``."""
    m = resolve(m)
    return _directions32(m.name, check_size(S))


@functools.lru_cache(maxsize=None)
def _directions32(name: str, S: int) -> np.ndarray:
    return frozen(directions64(name, S).astype(np.float32))


def inside_mask(m: Mapper | str, S: int) -> Bool[np.ndarray, "H W"]:
    """Texels whose centre lies inside the mapped domain (a subset of :func:`valid_mask`)."""
    m = resolve(m)
    return _inside(m.name, check_size(S))


@functools.lru_cache(maxsize=None)
def _inside(name: str, S: int) -> np.ndarray:
    return frozen(np.asarray(get(name).inside(*_centers(name, S)), dtype=bool))


def valid_mask(m: Mapper | str, S: int) -> Bool[np.ndarray, "H W"]:
    """Texels that hold data: those the bilinear footprint (eq. 34) of some in-domain direction touches.

    A texel is touched when a domain point's continuous coordinates, clamped per face to [0, S-1],
    lie within less than one texel of it along both axes. Found by sampling the domain on a grid
    (``_VALID_GRID`` per texel side) and densely along the lines through texel centres
    (``_VALID_LINE`` per texel): a domain chord on such a line also has domain points just beside
    it, so thin slivers of the domain reaching into a texel's neighbourhood are not missed (up to
    slivers whose bilinear weight stays below ~1e-5). United with :func:`inside_mask`.
    Parabolic-type faces: the disk plus a ring; cube, octahedral and line: everything.
    """
    m = resolve(m)
    return valid_table(m.name, check_size(S))


#: Samples per texel side: of the 2-D grid, and along the lines through texel centres.
_VALID_GRID = 8
_VALID_LINE = 64


@functools.lru_cache(maxsize=None)
def valid_table(name: str, S: int) -> np.ndarray:
    """:func:`valid_mask` by name (cached)."""
    m = get(name)
    mask = _inside(name, S).copy()
    if m.scalar:
        return frozen(np.ones_like(mask))

    def mark(f, u, v, rows=None, cols=None):
        """Mark the footprints of the in-domain points among (u, v); rows/cols: their centre line."""
        ins = np.asarray(m.inside(np.full(u.shape, f, np.int32), u, v), dtype=bool)
        if ins.all():  # the whole face is in the domain (cube, octahedral)
            mask[:, f * S : (f + 1) * S] = True
            return
        cu, cv = np.clip(u[ins] * S - 0.5, 0, S - 1), np.clip(v[ins] * S - 0.5, 0, S - 1)
        rr = [np.floor(cv), np.ceil(cv)] if rows is None else [rows[ins] + k for k in (-1, 0, 1)]
        cc = [np.floor(cu), np.ceil(cu)] if cols is None else [cols[ins] + k for k in (-1, 0, 1)]
        for r in rr:
            for c in cc:
                mask[np.clip(r, 0, S - 1).astype(int), f * S + np.clip(c, 0, S - 1).astype(int)] = True

    grid = np.arange(S * _VALID_GRID + 1) / (S * _VALID_GRID)
    line = np.arange(S * _VALID_LINE + 1) / (S * _VALID_LINE)
    k, centre = np.meshgrid(np.arange(S), line, indexing="ij")  # (S, n): centre line k, position along it
    for f in range(m.faces):
        mark(f, *np.meshgrid(grid, grid))
        mark(f, centre, (k + 0.5) / S, rows=k)  # on row k's centre line: rows k-1..k+1 are reached
        mark(f, (k + 0.5) / S, centre, cols=k)  # on column k's centre line
    return frozen(mask)


# Solid angles ---------------------------------------------------------------------------------------

#: Points per texel edge of the boundary polygons in :func:`texel_solid_angles` (32 intervals),
#: Richardson-extrapolated against half as many intervals.
_SA_EDGE = 33
#: Texels per chunk (bounds the memory of the quadrature).
_SA_CHUNK = 2048


def _triangles(a, b, c):
    """Signed Van Oosterom-Strackee: ``tan(Omega/2) = a.(b x c) / (1 + a.b + b.c + c.a)`` for unit a, b, c."""
    dot = lambda p, q: np.einsum("...i,...i->...", p, q)  # noqa: E731
    return 2 * np.arctan2(dot(a, np.cross(b, c)), 1 + dot(a, b) + dot(b, c) + dot(c, a))


def _clipped_boundary_solid_angles(m: Mapper, face, u0, v0, h: float, n: int):
    """Solid angles of the in-domain parts of the squares ``[u0, u0+h] x [v0, v0+h]`` (one per entry).

    Walk the square's four edges; on each, keep the interval inside the domain (its end found by
    bisection of ``inside`` where the edge crosses the domain border; assumes one interval per edge,
    true for the disks here) and sample it at ``n`` points clustered towards both ends
    (``(1 - cos)/2``, so square-root singularities of the map at the border stay resolved). The
    reverse projections form a spherical polygon (consecutive intervals joined by great-circle arcs
    along the border) whose solid angle is the sum of a fan of signed triangles.
    """
    K = len(u0)
    cu = u0[:, None] + h * np.array([0.0, 1.0, 1.0, 0.0])  # corners counter-clockwise in (u, v)
    cv = v0[:, None] + h * np.array([0.0, 0.0, 1.0, 1.0])
    f4 = np.repeat(face[:, None], 4, axis=1)
    ins = np.asarray(m.inside(f4, cu, cv), dtype=bool)
    nu, nv, nins = np.roll(cu, -1, 1), np.roll(cv, -1, 1), np.roll(ins, -1, 1)
    # Interval [a, b] of the edge parameter t in [0, 1] that lies inside the domain.
    t_in, t_out = np.where(ins, 0.0, 1.0), np.where(ins, 1.0, 0.0)  # bisection bracket on each edge
    cross = ins != nins
    if cross.any():
        for _ in range(52):
            t = (t_in + t_out) / 2
            mi = np.asarray(m.inside(f4, cu + t * (nu - cu), cv + t * (nv - cv)), dtype=bool)
            t_in, t_out = np.where(mi, t, t_in), np.where(mi, t_out, t)
    a = np.where(ins, 0.0, np.where(cross, t_in, 0.0))
    b = np.where(nins, 1.0, np.where(cross, t_in, 0.0))
    emit = ins | nins  # the edge has an inside interval
    s = (1 - np.cos(np.pi * np.arange(n) / (n - 1))) / 2
    t = a[..., None] + (b - a)[..., None] * s  # (K, 4, n)
    pu = (cu[..., None] + t * (nu - cu)[..., None]).reshape(K, 4 * n)
    pv = (cv[..., None] + t * (nv - cv)[..., None]).reshape(K, 4 * n)
    emit = np.repeat(emit, n, axis=1)
    # Edges without an inside interval repeat the previous emitted vertex: zero-area triangles.
    slot = np.maximum.accumulate(np.where(emit, np.arange(4 * n), -1), axis=1)
    slot = np.where(slot < 0, np.argmax(emit, axis=1)[:, None], slot)
    pu, pv = np.take_along_axis(pu, slot, 1), np.take_along_axis(pv, slot, 1)
    d = m.from_face_uv(np.repeat(face[:, None], 4 * n, axis=1), pu, pv)
    total = np.abs(np.sum(_triangles(d[:, :1], d[:, 1:-1], d[:, 2:]), axis=1))
    return np.where(emit.any(axis=1), total, 0.0)


def texel_solid_angles(m: Mapper | str, S: int) -> Float[np.ndarray, "H W"]:
    """Solid angle (float64) of the part of each texel's square inside the domain (0 where none).

    Each texel's square, clipped to the domain (assumed to meet each texel edge in one interval,
    as the disks and full faces here do), is reverse-projected as a spherical polygon of
    boundary points (see :func:`_clipped_boundary_solid_angles`; the same value as summing
    projected sub-quads, whose inner edges cancel), with 32 and 16 intervals per edge,
    Richardson-extrapolated (the chord error is O(h^2)): about 1e-6 relative per texel. Cube texel
    edges are great-circle arcs, so for ``cube`` this is the closed form (sum of
    ``atan(xy / sqrt(1 + x^2 + y^2))`` over a texel's corners) to rounding. The total is 4 pi
    (sphere mappers) or 2 pi (hemisphere mappers).
    """
    m = resolve(m)
    return _solid_angles(m.name, check_size(S))


@functools.lru_cache(maxsize=None)
def _solid_angles(name: str, S: int) -> np.ndarray:
    m = get(name)
    if m.scalar:
        return frozen(np.full((1, S), 1.0 / S))
    face, u, v = _centers(name, S)
    face, u0, v0 = face.ravel(), u.ravel() - 0.5 / S, v.ravel() - 0.5 / S
    out = np.empty(face.size)
    for k in range(0, face.size, _SA_CHUNK):
        f, a, b = face[k : k + _SA_CHUNK], u0[k : k + _SA_CHUNK], v0[k : k + _SA_CHUNK]
        # Texels whose value does not change when the edge midpoints are added have great-circle
        # edges (cube, octahedral): the corner polygon is exact there.
        exact = _clipped_boundary_solid_angles(m, f, a, b, 1 / S, 3)
        rest = ~(np.abs(exact - _clipped_boundary_solid_angles(m, f, a, b, 1 / S, 2)) <= 1e-12 * exact + 1e-15)
        if rest.any():
            fine = _clipped_boundary_solid_angles(m, f[rest], a[rest], b[rest], 1 / S, _SA_EDGE)
            coarse = _clipped_boundary_solid_angles(m, f[rest], a[rest], b[rest], 1 / S, (_SA_EDGE + 1) // 2)
            exact[rest] = (4 * fine - coarse) / 3
        out[k : k + _SA_CHUNK] = exact
    return frozen(out.reshape(u.shape))




for _f in (_centers, directions64, _directions32, _inside, valid_table, _solid_angles):
    on_register(_f.cache_clear)

__all__ = ["check_size", "directions64", "frozen", "inside_mask", "texel_centers", "texel_directions",
           "texel_solid_angles", "texture_shape", "valid_mask", "valid_table"]
