"""Direction mappers: unit direction <-> texel of a 2D texture (DESIGN.md "Direction mappers", pinned).

A mapper is data (:class:`Mapper`) plus pure functions, registered by name in :data:`MAPPERS`.
A texture of size ``S`` has shape ``(S, faces * S)``: the sub-maps ("faces") lie side by side, left
to right. Texel centres sit at ``(i + 0.5) / S``; the continuous texel coordinate of a direction is
``row = v S - 0.5``, ``col = face S + u S - 0.5`` (pinned).

==================  ========  ==========================================================================
name                faces     direction -> (u, v) on the face
==================  ========  ==========================================================================
``parabolic``       1         z >= 0: ``((x/(1+z)+1)/2, (y/(1+z)+1)/2)``; reverse thesis eq. 46
``dual_paraboloid`` 2         face 0: z >= 0 as parabolic; face 1: z < 0 with 1 - z in place of 1 + z
``cube``            6         +X -X +Y -Y +Z -Z, OpenGL sc/tc/ma: ``u = (sc/|ma|+1)/2, v = (tc/|ma|+1)/2``
``octahedral``      1         ``p = (x, y)/(|x|+|y|+|z|)``, folded for z < 0; ``(u, v) = (p+1)/2``
``hemispherical``   1         z >= 0, orthographic: ``((x+1)/2, (y+1)/2)`` (thesis fig. 6; comparison)
``spherical``       1         OpenGL sphere map, ``m = 2 sqrt(x^2+y^2+(z+1)^2)``: ``(x/m+1/2, y/m+1/2)``
==================  ========  ==========================================================================

The per-mapper functions work on numpy arrays (the static tables, computed in float64 and cached per
``(name, S)``) and on JAX arrays (jittable, vmappable, differentiable); they use the namespace of
their input. Everything else here is generic, built only from the :class:`Mapper` data, except the
across-edge neighbour links of :func:`neighbours` (cube and octahedral only).
"""

from __future__ import annotations

import functools
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..errors import HomofacError

Vec = Float[Array, "*batch 3"]
_TINY = 1e-12


class Mapper(NamedTuple):
    """A direction mapper: data plus pure functions (see the module table); add one with :func:`register`."""

    name: str
    faces: int  # sub-maps laid side by side, left to right
    covers_sphere: bool  # False: only the hemisphere z >= 0
    to_face_uv: Callable  # d (..., 3) -> (face int32 (...), u (...), v (...))
    from_face_uv: Callable  # (face, u, v) -> unit d (..., 3); extrapolates outside the face's domain
    inside: Callable  # (face, u, v) -> bool: the point lies in the mapped domain


MAPPERS: dict[str, Mapper] = {}


def register(m: Mapper) -> Mapper:
    """Add (or replace) a mapper in :data:`MAPPERS` (and drop all cached tables)."""
    MAPPERS[m.name] = m
    for f in _CACHED:
        f.cache_clear()
    return m


def get(name: str) -> Mapper:
    """The mapper registered as ``name``; :class:`HomofacError` naming the known ones otherwise."""
    if name not in MAPPERS:
        raise HomofacError(f"unknown mapper {name!r}; known mappers: {', '.join(sorted(MAPPERS))}")
    return MAPPERS[name]


# ----------------------------------------------------------------------------------------------------
# Per-mapper functions (numpy or jax.numpy, following the input).


def _xp(*arrays):
    return jnp if any(isinstance(a, jax.Array) for a in arrays) else np


def _normalize(a, xp):
    n = xp.sqrt(xp.maximum(xp.sum(a * a, axis=-1, keepdims=True), _TINY * _TINY))
    return a / n


def _split(d):
    return d[..., 0], d[..., 1], d[..., 2]


def _disk_inside(face, u, v):
    """Texture point inside the unit disk of its face: ``(2u-1)^2 + (2v-1)^2 <= 1``."""
    return (2 * u - 1) ** 2 + (2 * v - 1) ** 2 <= 1.0


def _all_inside(face, u, v):
    xp = _xp(face, u, v)
    return xp.ones(xp.broadcast_shapes(xp.shape(face), xp.shape(u), xp.shape(v)), dtype=bool)


def _faces_like(x, xp, value=0):
    return xp.full(xp.shape(x), value, dtype=xp.int32)


def _paraboloid_from_uv(u, v, xp):
    """Thesis eq. 46: ``d = normalize(x, y, 1/2 - (x^2+y^2)/2)`` with (x, y) = (2u-1, 2v-1).

    Defined on the whole plane: outside the unit disk it continues below the horizon (z < 0).
    """
    x, y = 2 * u - 1, 2 * v - 1
    return _normalize(xp.stack([x, y, 0.5 - 0.5 * (x * x + y * y)], axis=-1), xp)


def _parabolic_to(d):
    """Pinned: ``((x/(1+z)+1)/2, (y/(1+z)+1)/2)``; finite (far outside the disk) for z < 0 too."""
    xp = _xp(d)
    x, y, z = _split(d)
    den = xp.maximum(1 + z, _TINY)
    return _faces_like(x, xp), (x / den + 1) / 2, (y / den + 1) / 2


def _parabolic_from(face, u, v):
    return _paraboloid_from_uv(u, v, _xp(face, u, v))


def _dual_to(d):
    xp = _xp(d)
    lower = d[..., 2] < 0
    # 1 + |z| is 1 + z on face 0 and 1 - z on face 1 (pinned table).
    x, y, z = _split(d)
    den = 1 + xp.abs(z)
    return lower.astype(xp.int32), (x / den + 1) / 2, (y / den + 1) / 2


def _dual_from(face, u, v):
    xp = _xp(face, u, v)
    d = _paraboloid_from_uv(u, v, xp)
    flip = xp.where(xp.asarray(face) == 1, -1.0, 1.0)
    return xp.concatenate([d[..., :2], d[..., 2:] * flip[..., None]], axis=-1)


# Cube faces +X, -X, +Y, -Y, +Z, -Z: major axis N, and the sc / tc axes of the OpenGL table
# (+X (-z, -y), -X (z, -y), +Y (x, z), -Y (x, -z), +Z (x, -y), -Z (-x, -y)). For each face the three
# rows are orthonormal, so d = |ma| N + sc SC + tc TC.
_CUBE_N = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)
_CUBE_SC = np.array([[0, 0, -1], [0, 0, 1], [1, 0, 0], [1, 0, 0], [1, 0, 0], [-1, 0, 0]], np.float64)
_CUBE_TC = np.array([[0, -1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1], [0, -1, 0], [0, -1, 0]], np.float64)


def _table(t, face, dtype, xp):
    return xp.asarray(t, dtype=dtype)[face]


def _cube_to(d):
    """Pinned cube table; ties in the major axis go to x, then y, then z."""
    xp = _xp(d)
    x, y, z = _split(d)
    ax, ay, az = xp.abs(x), xp.abs(y), xp.abs(z)
    is_x = (ax >= ay) & (ax >= az)
    is_y = ~is_x & (ay >= az)
    face = xp.where(is_x, xp.where(x >= 0, 0, 1), xp.where(is_y, xp.where(y >= 0, 2, 3), xp.where(z >= 0, 4, 5)))
    face = face.astype(xp.int32)
    ma = xp.maximum(xp.sum(_table(_CUBE_N, face, d.dtype, xp) * d, axis=-1), _TINY)
    sc = xp.sum(_table(_CUBE_SC, face, d.dtype, xp) * d, axis=-1)
    tc = xp.sum(_table(_CUBE_TC, face, d.dtype, xp) * d, axis=-1)
    return face, (sc / ma + 1) / 2, (tc / ma + 1) / 2


def _cube_from(face, u, v):
    xp = _xp(face, u, v)
    u, v = xp.asarray(u), xp.asarray(v)
    face = xp.asarray(face).astype(xp.int32)
    sc, tc = (2 * u - 1)[..., None], (2 * v - 1)[..., None]
    dt = u.dtype
    d = _table(_CUBE_N, face, dt, xp) + sc * _table(_CUBE_SC, face, dt, xp) + tc * _table(_CUBE_TC, face, dt, xp)
    return _normalize(d, xp)


def _sign(a, xp):
    return xp.where(a >= 0, 1.0, -1.0).astype(a.dtype)  # sign(0) = +1 (pinned)


def _octahedral_to(d):
    """Pinned: ``p = (x, y)/(|x|+|y|+|z|)``; if z < 0: ``p = (1-|p_y|, 1-|p_x|) sign(p)``."""
    xp = _xp(d)
    x, y, z = _split(d)
    l1 = xp.maximum(xp.abs(x) + xp.abs(y) + xp.abs(z), _TINY)
    px, py = x / l1, y / l1
    lower = z < 0
    qx = xp.where(lower, (1 - xp.abs(py)) * _sign(px, xp), px)
    qy = xp.where(lower, (1 - xp.abs(px)) * _sign(py, xp), py)
    return _faces_like(qx, xp), (qx + 1) / 2, (qy + 1) / 2


def _octahedral_from(face, u, v):
    """Inverse fold: z = 1 - |p_x| - |p_y|; if z < 0, p = (1-|p_y|, 1-|p_x|) sign(p)."""
    xp = _xp(face, u, v)
    px, py = 2 * xp.asarray(u) - 1, 2 * xp.asarray(v) - 1
    z = 1 - xp.abs(px) - xp.abs(py)
    lower = z < 0
    qx = xp.where(lower, (1 - xp.abs(py)) * _sign(px, xp), px)
    qy = xp.where(lower, (1 - xp.abs(px)) * _sign(py, xp), py)
    return _normalize(xp.stack([qx, qy, z], axis=-1), xp)


def _hemispherical_to(d):
    xp = _xp(d)
    x, y, _ = _split(d)
    return _faces_like(x, xp), (x + 1) / 2, (y + 1) / 2


def _hemispherical_from(face, u, v):
    """Orthographic: ``z = sqrt(1 - x^2 - y^2)``; outside the disk clamped to the horizon."""
    xp = _xp(face, u, v)
    x, y = 2 * xp.asarray(u) - 1, 2 * xp.asarray(v) - 1
    z = xp.sqrt(xp.maximum(1 - x * x - y * y, 0.0))
    return _normalize(xp.stack([x, y, z], axis=-1), xp)


def _spherical_to(d):
    """OpenGL sphere map, ``m = 2 sqrt(x^2 + y^2 + (z+1)^2)``; singular at -z, whose whole rim is the
    one direction -z: exactly -z maps to the rim point (1, 0.5) (0/0 otherwise gave the centre, +z)."""
    xp = _xp(d)
    x, y, z = _split(d)
    m = 2 * xp.sqrt(xp.maximum(x * x + y * y + (z + 1) ** 2, _TINY * _TINY))
    pole = (x * x + y * y < _TINY * _TINY) & (z < 0)
    return _faces_like(x, xp), xp.where(pole, 1.0, x / m + 0.5), xp.where(pole, 0.5, y / m + 0.5)


def _spherical_from(face, u, v):
    """Reverse sphere map: s = (2u-1, 2v-1) is the xy part of h = normalize(d + z); d = 2 h_z h - z.

    Outside the disk (|s| = r > 1) the point is continued through the rim (-z) as the point
    2 - r on the opposite side (h_z < 0), so it stays a valid direction near -z.
    """
    xp = _xp(face, u, v)
    sx, sy = 2 * xp.asarray(u) - 1, 2 * xp.asarray(v) - 1
    r = xp.sqrt(sx * sx + sy * sy)
    rr = xp.clip(xp.where(r > 1, 2 - r, r), 0.0, 1.0)
    scale = xp.where(r > _TINY, rr / xp.maximum(r, _TINY), 1.0)
    hx, hy = sx * scale, sy * scale
    hz = xp.sqrt(xp.maximum(1 - rr * rr, 0.0)) * xp.where(r > 1, -1.0, 1.0)
    return _normalize(xp.stack([2 * hz * hx, 2 * hz * hy, 2 * hz * hz - 1], axis=-1), xp)


#: Mappers whose faces are linked across their edges in :func:`neighbours` (Latta-Kolb fig. 1).
_WRAPS = frozenset({"cube", "octahedral"})


# ----------------------------------------------------------------------------------------------------
# Generic functions.


def _resolve(m: Mapper | str) -> Mapper:
    m = get(m) if isinstance(m, str) else m
    if MAPPERS.get(m.name) != m:
        raise HomofacError(f"mapper {m.name!r} is not registered; call mappers.register() first")
    return m


def _check_size(S) -> int:
    if isinstance(S, bool) or not isinstance(S, (int, np.integer)) or S < 2:
        raise HomofacError(f"texture size must be a Python int >= 2, got {S!r}")
    return int(S)


def _frozen(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def texture_shape(m: Mapper | str, S: int) -> tuple[int, int]:
    """``(H, W) = (S, faces S)`` (pinned table)."""
    m = _resolve(m)
    S = _check_size(S)
    return S, m.faces * S


def texel_centers(m: Mapper | str, S: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(face, u, v)`` of every texel centre, numpy ``(H, W)``: ``u = (col mod S + 0.5)/S``, ``v = (row + 0.5)/S``."""
    m = _resolve(m)
    return _centers(m.name, _check_size(S))


@functools.lru_cache(maxsize=None)
def _centers(name: str, S: int):
    H, W = S, get(name).faces * S
    row, col = np.mgrid[0:H, 0:W]
    face = (col // S).astype(np.int32)
    return _frozen(face), _frozen((col % S + 0.5) / S), _frozen((row + 0.5) / S)


@functools.lru_cache(maxsize=None)
def _directions64(name: str, S: int) -> np.ndarray:
    return _frozen(get(name).from_face_uv(*_centers(name, S)))


def texel_directions(m: Mapper | str, S: int) -> Float[np.ndarray, "H W 3"]:
    """Reverse projection of every texel centre (e.g. thesis eq. 46), float32 ``(H, W, 3)``."""
    m = _resolve(m)
    return _directions32(m.name, _check_size(S))


@functools.lru_cache(maxsize=None)
def _directions32(name: str, S: int) -> np.ndarray:
    return _frozen(_directions64(name, S).astype(np.float32))


def inside_mask(m: Mapper | str, S: int) -> Bool[np.ndarray, "H W"]:
    """Texels whose centre lies inside the mapped domain (a subset of :func:`valid_mask`)."""
    m = _resolve(m)
    return _inside(m.name, _check_size(S))


@functools.lru_cache(maxsize=None)
def _inside(name: str, S: int) -> np.ndarray:
    return _frozen(np.asarray(get(name).inside(*_centers(name, S)), dtype=bool))


#: Samples per texel side: of the 2-D grid, and along the lines through texel centres.
_VALID_GRID = 8
_VALID_LINE = 64


def valid_mask(m: Mapper | str, S: int) -> Bool[np.ndarray, "H W"]:
    """Texels that hold data: those the bilinear footprint (eq. 34) of some in-domain direction touches.

    A texel is touched when a domain point's continuous coordinates, clamped per face to [0, S-1],
    lie within less than one texel of it along both axes. Found by sampling the domain on a grid
    (``_VALID_GRID`` per texel side) and densely along the lines through texel centres
    (``_VALID_LINE`` per texel): a domain chord on such a line also has domain points just beside
    it, so thin slivers of the domain reaching into a texel's neighbourhood are not missed (up to
    slivers whose bilinear weight stays below ~1e-5). United with :func:`inside_mask`.
    Parabolic-type faces: the disk plus a ring; cube and octahedral: everything.
    """
    m = _resolve(m)
    return _valid(m.name, _check_size(S))


@functools.lru_cache(maxsize=None)
def _valid(name: str, S: int) -> np.ndarray:
    m = get(name)
    mask = _inside(name, S).copy()

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
    return _frozen(mask)


@functools.lru_cache(maxsize=None)
def _nearest_valid(name: str, S: int) -> np.ndarray:
    """Flat index of the nearest valid texel of the same face, for every texel (identity on valid ones)."""
    from scipy.ndimage import distance_transform_edt

    valid = _valid(name, S)
    H, W = valid.shape
    out = np.arange(H * W, dtype=np.int32).reshape(H, W)
    for f in range(W // S):
        sub = valid[:, f * S : (f + 1) * S]
        _, (ri, ci) = distance_transform_edt(~sub, return_indices=True)
        out[:, f * S : (f + 1) * S] = ri * W + f * S + ci
    return _frozen(out.reshape(-1))


def continuous_coords(m: Mapper | str, d: Vec, S: int) -> tuple[Float[Array, "*batch"], Float[Array, "*batch"]]:
    """Pinned continuous texel coordinates: ``row = v S - 0.5``, ``col = face S + u S - 0.5`` (unclamped)."""
    m = _resolve(m)
    S = _check_size(S)
    face, u, v = m.to_face_uv(jnp.asarray(d))
    return v * S - 0.5, face * S + u * S - 0.5


def bilinear(m: Mapper | str, d: Vec, S: int) -> tuple[Int[Array, "*batch 4"], Float[Array, "*batch 4"]]:
    """Bilinear footprint of directions (thesis eq. 33-34): flat indices ``row W + col`` and weights.

    Eq. 33: ``U = floor(u), alpha_u = u - U, beta_u = 1 - alpha_u`` (same for v) on the continuous
    coordinate clamped to [0, S-1] within the face (clamp-to-edge per face: the four texels never
    leave the face the direction maps to). Eq. 34: weights ``beta_u beta_v, alpha_u beta_v,
    beta_u alpha_v, alpha_u alpha_v`` for ``(U, V), (U+1, V), (U, V+1), (U+1, V+1)``.

    Corners outside :func:`valid_mask` get weight 0 and the rest is renormalised (never needed for
    in-domain directions). Out-of-domain directions whose four texels are all invalid (e.g. z < 0 on
    ``parabolic``) keep their weights on the nearest valid texels instead. Jittable, vectorised,
    differentiable w.r.t. ``d``; ``S`` must be a static Python int.
    """
    m = _resolve(m)
    S = _check_size(S)
    d = jnp.asarray(d)
    W = m.faces * S
    face, u, v = m.to_face_uv(d)
    cu = jnp.clip(u * S - 0.5, 0.0, S - 1.0)
    cv = jnp.clip(v * S - 0.5, 0.0, S - 1.0)
    j0 = jnp.clip(jnp.floor(cu), 0, S - 2)
    i0 = jnp.clip(jnp.floor(cv), 0, S - 2)
    au, av = cu - j0, cv - i0
    bu, bv = 1 - au, 1 - av
    base = i0.astype(jnp.int32) * W + face.astype(jnp.int32) * S + j0.astype(jnp.int32)
    idx = base[..., None] + jnp.array([0, 1, W, W + 1], jnp.int32)
    w = jnp.stack([bu * bv, au * bv, bu * av, au * av], axis=-1)

    ok = jnp.asarray(_valid(m.name, S)).reshape(-1)[idx]
    wv = jnp.where(ok, w, 0.0)
    total = jnp.sum(wv, axis=-1, keepdims=True)
    some = total > 0
    w = jnp.where(some, wv / jnp.where(some, total, 1.0), w)
    idx = jnp.asarray(_nearest_valid(m.name, S))[idx]
    return idx, w


def lookup(m: Mapper | str, texture: Float[Array, "H W *C"], d: Vec) -> Float[Array, "*batch *C"]:
    """Bilinearly interpolated texture values at directions (eq. 34 via :func:`bilinear`); ``S = H``."""
    m = _resolve(m)
    texture = jnp.asarray(texture)
    H, W = texture.shape[:2]
    if W != m.faces * H:
        raise HomofacError(
            f"texture of shape {texture.shape} does not fit mapper {m.name} (expected (S, {m.faces} S, ...))"
        )
    idx, w = bilinear(m, d, H)
    flat = texture.reshape((H * W,) + texture.shape[2:])
    vals = flat[idx]  # (..., 4, *C)
    channels = texture.ndim - 2
    return jnp.sum(w.astype(vals.dtype).reshape(w.shape + (1,) * channels) * vals, axis=w.ndim - 1)


def neighbours(m: Mapper | str, S: int) -> Int[np.ndarray, "HW 4"]:
    """Flat indices of the 4-neighbours (left, right, up, down) of each texel for the Laplacian, -1 if none.

    Only valid texels are linked (rows of invalid texels are all -1). Within a face: grid neighbours.
    ``cube`` and ``octahedral`` are also linked across face edges (Latta-Kolb fig. 1): an edge
    texel's neighbour is the valid texel (other than itself) whose centre direction is nearest to the
    direction just beyond the middle of its edge (the reverse projection extrapolated there). For
    the cube this is the texel on the other side of the shared cube edge; for the octahedral map the
    mirror image on the same folded edge ((r, 0) <-> (S-1-r, 0), ...). The texel and its partner are
    mirror images about the edge, so the relation is symmetric and every texel has 4 neighbours.
    Octahedral: the two texels at the middle of a border edge meet both inside the square and across
    the fold, so they list each other twice (a double link of the Laplacian, as the geometry says).
    """
    m = _resolve(m)
    return _neighbours(m.name, _check_size(S))


#: How far beyond a face edge (in texels) the across-edge neighbour is looked up.
_BEYOND = 1e-3


@functools.lru_cache(maxsize=None)
def _neighbours(name: str, S: int) -> np.ndarray:
    m = get(name)
    valid = _valid(name, S)
    H, W = valid.shape
    row, col = np.mgrid[0:H, 0:W]
    face = col // S
    flat_valid = np.flatnonzero(valid)
    tree = None
    if name in _WRAPS:
        from scipy.spatial import cKDTree

        tree = cKDTree(_directions64(name, S).reshape(-1, 3)[flat_valid])
    nb = np.full((H, W, 4), -1, np.int32)
    for k, (dr, dc) in enumerate(((0, -1), (0, 1), (-1, 0), (1, 0))):
        r2, c2 = row + dr, col + dc
        in_face = (r2 >= 0) & (r2 < H) & (c2 >= face * S) & (c2 < (face + 1) * S)
        r2c, c2c = np.clip(r2, 0, H - 1), np.clip(c2, 0, W - 1)
        link = valid & in_face & valid[r2c, c2c]
        nb[..., k] = np.where(link, r2c * W + c2c, -1)
        if tree is not None:
            edge = valid & ~in_face
            step = 0.5 + _BEYOND  # from the texel centre to just beyond the face edge
            u = (col[edge] - face[edge] * S + 0.5 + step * dc) / S
            v = (row[edge] + 0.5 + step * dr) / S
            beyond = m.from_face_uv(face[edge].astype(np.int32), u, v)
            near = flat_valid[tree.query(beyond, k=2)[1]]  # (n, 2): the nearest two, one may be the texel itself
            own = (row * W + col)[edge]
            nb[..., k][edge] = np.where(near[:, 0] == own, near[:, 1], near[:, 0])
    return _frozen(nb.reshape(H * W, 4))


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
    m = _resolve(m)
    return _solid_angles(m.name, _check_size(S))


@functools.lru_cache(maxsize=None)
def _solid_angles(name: str, S: int) -> np.ndarray:
    m = get(name)
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
    return _frozen(out.reshape(u.shape))


_CACHED = (_centers, _directions64, _directions32, _inside, _valid, _nearest_valid, _neighbours, _solid_angles)

register(Mapper("parabolic", 1, False, _parabolic_to, _parabolic_from, _disk_inside))
register(Mapper("dual_paraboloid", 2, True, _dual_to, _dual_from, _disk_inside))
register(Mapper("cube", 6, True, _cube_to, _cube_from, _all_inside))
register(Mapper("octahedral", 1, True, _octahedral_to, _octahedral_from, _all_inside))
register(Mapper("hemispherical", 1, False, _hemispherical_to, _hemispherical_from, _disk_inside))
register(Mapper("spherical", 1, True, _spherical_to, _spherical_from, _disk_inside))

__all__ = [
    "MAPPERS",
    "Mapper",
    "bilinear",
    "continuous_coords",
    "get",
    "lookup",
    "neighbours",
    "register",
    "texel_centers",
    "texel_directions",
    "texel_solid_angles",
    "texture_shape",
    "valid_mask",
    "inside_mask",
]
