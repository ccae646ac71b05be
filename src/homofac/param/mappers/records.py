"""Direction mappers as records: the math of each mapper, written once (docs/conventions.md, pinned).

A texture of size ``S`` has shape ``(rows, faces * S)`` with ``rows = S`` (2D maps) or 1 (the ``line``
mapper): the sub-maps ("faces") lie side by side, left to right. Texel centres sit at ``(i + 0.5) / S``;
the continuous texel coordinate of a direction is ``row = v rows - 0.5``, ``col = face S + u S - 0.5``.

==================  ========  ==========================================================================
name                faces     direction -> (u, v) on the face
==================  ========  ==========================================================================
``parabolic``       1         z >= 0: ``((x/(1+z)+1)/2, (y/(1+z)+1)/2)``; reverse thesis eq. 46
``dual_paraboloid`` 2         face 0: z >= 0 as parabolic; face 1: z < 0 with 1 - z in place of 1 + z
``cube``            6         +X -X +Y -Y +Z -Z, OpenGL sc/tc/ma: ``u = (sc/|ma|+1)/2, v = (tc/|ma|+1)/2``
``octahedral``      1         ``p = (x, y)/(|x|+|y|+|z|)``, folded for z < 0; ``(u, v) = (p+1)/2``
``hemispherical``   1         z >= 0, orthographic: ``((x+1)/2, (y+1)/2)`` (thesis fig. 6; comparison)
``spherical``       1         OpenGL sphere map, ``m = 2 sqrt(x^2+y^2+(z+1)^2)``: ``(x/m+1/2, y/m+1/2)``
``line``            1         a scalar x in [0, 1] (not a direction): ``(u, v) = (x, 1/2)``, texture (1, S)
==================  ========  ==========================================================================

Each record's ``to_face_uv`` is written against the namespace of its input
(:func:`homofac.sphere.namespace`): NumPy for the static tables, JAX inside jitted code, and the
symbolic values of :mod:`homofac.shader.symbolic`, which print it as shader code -- so the GPU's
mapper is this very function. ``from_face_uv`` (texel -> direction) and ``inside`` (the mapped
domain) are used for the tables only, in NumPy or JAX.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from ...errors import HomofacError
from ...sphere import namespace

_TINY = 1e-12


class Mapper(NamedTuple):
    """A direction mapper (or the scalar ``line`` mapper): data plus pure functions."""

    name: str
    faces: int  # sub-maps laid side by side, left to right
    covers_sphere: bool  # False: only the hemisphere z >= 0
    to_face_uv: Callable  # d (..., 3) [or x (...) for line] -> (face int32 (...), u (...), v (...))
    from_face_uv: Callable  # (face, u, v) -> unit d (..., 3) [x (...)]; extrapolates outside the domain
    inside: Callable  # (face, u, v) -> bool: the point lies in the mapped domain
    doc: str
    scalar: bool = False  # True: maps a scalar in [0, 1] (``line``), textures of shape (1, S)
    wraps: bool = False  # faces are linked across their edges for the Laplacian (Latta-Kolb fig. 1)

    def rows(self, S: int) -> int:
        """Texture rows: S for 2D maps, 1 for the line mapper."""
        return 1 if self.scalar else S


MAPPERS: dict[str, Mapper] = {}
_CACHE_CLEARERS: list[Callable[[], None]] = []


def register(m: Mapper) -> Mapper:
    """Add (or replace) a mapper in :data:`MAPPERS` and drop every cached table."""
    MAPPERS[m.name] = m
    for clear in _CACHE_CLEARERS:
        clear()
    return m


def on_register(clear: Callable[[], None]) -> None:
    """Call ``clear`` whenever a mapper is (re)registered (the table caches use it)."""
    _CACHE_CLEARERS.append(clear)


def get(name: str) -> Mapper:
    """The mapper registered as ``name``; :class:`HomofacError` naming the known ones otherwise."""
    if not isinstance(name, str) or name not in MAPPERS:
        raise HomofacError(f"unknown mapper {name!r}; known mappers: {', '.join(sorted(MAPPERS))}")
    return MAPPERS[name]


def resolve(m: Mapper | str) -> Mapper:
    """A registered mapper from a record or a name."""
    m = get(m) if isinstance(m, str) else m
    if MAPPERS.get(m.name) != m:
        raise HomofacError(f"mapper {m.name!r} is not registered; call mappers.register() first")
    return m


# ----------------------------------------------------------------------------------------------------
# Per-mapper functions (NumPy, JAX or symbolic, following the input).


def _normalize(a, xp):
    n = xp.sqrt(xp.maximum(xp.sum(a * a, axis=-1, keepdims=True), _TINY * _TINY))
    return a / n


def _split(d):
    return d[..., 0], d[..., 1], d[..., 2]


def _disk_inside(face, u, v):
    """Texture point inside the unit disk of its face: ``(2u-1)^2 + (2v-1)^2 <= 1``."""
    return (2 * u - 1) ** 2 + (2 * v - 1) ** 2 <= 1.0


def _all_inside(face, u, v):
    xp = namespace(face, u, v)
    return xp.ones(xp.broadcast_shapes(xp.shape(face), xp.shape(u), xp.shape(v)), dtype=bool)


def _face0(x, xp):
    return xp.full(xp.shape(x), 0, dtype=xp.int32)


def _paraboloid_from_uv(u, v, xp):
    """Thesis eq. 46: ``d = normalize(x, y, 1/2 - (x^2+y^2)/2)`` with (x, y) = (2u-1, 2v-1).

    Defined on the whole plane: outside the unit disk it continues below the horizon (z < 0).
    """
    x, y = 2 * u - 1, 2 * v - 1
    return _normalize(xp.stack([x, y, 0.5 - 0.5 * (x * x + y * y)], axis=-1), xp)


def _parabolic_to(d):
    """Pinned: ``((x/(1+z)+1)/2, (y/(1+z)+1)/2)``; finite (far outside the disk) for z < 0 too."""
    xp = namespace(d)
    x, y, z = _split(d)
    den = xp.maximum(1 + z, _TINY)
    return _face0(x, xp), (x / den + 1) / 2, (y / den + 1) / 2


def _parabolic_from(face, u, v):
    return _paraboloid_from_uv(u, v, namespace(face, u, v))


def _dual_to(d):
    """Face 0 for z >= 0, face 1 for z < 0; ``1 + |z|`` is 1 + z on face 0 and 1 - z on face 1."""
    xp = namespace(d)
    x, y, z = _split(d)
    den = 1 + xp.abs(z)
    return (z < 0).astype(xp.int32), (x / den + 1) / 2, (y / den + 1) / 2


def _dual_from(face, u, v):
    xp = namespace(face, u, v)
    d = _paraboloid_from_uv(u, v, xp)
    flip = xp.where(xp.asarray(face) == 1, -1.0, 1.0)
    return xp.concatenate([d[..., :2], d[..., 2:] * flip[..., None]], axis=-1)


# Cube faces +X, -X, +Y, -Y, +Z, -Z: major axis N, and the sc / tc axes of the OpenGL table
# (+X (-z, -y), -X (z, -y), +Y (x, z), -Y (x, -z), +Z (x, -y), -Z (-x, -y)). For each face the three
# rows are orthonormal, so d = |ma| N + sc SC + tc TC.
CUBE_N = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)
CUBE_SC = np.array([[0, 0, -1], [0, 0, 1], [1, 0, 0], [1, 0, 0], [1, 0, 0], [-1, 0, 0]], np.float64)
CUBE_TC = np.array([[0, -1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1], [0, -1, 0], [0, -1, 0]], np.float64)


def _cube_to(d):
    """Pinned cube table; ties in the major axis go to x, then y, then z."""
    xp = namespace(d)
    x, y, z = _split(d)
    ax, ay, az = xp.abs(x), xp.abs(y), xp.abs(z)
    is_x = (ax >= ay) & (ax >= az)
    is_y = ~is_x & (ay >= az)
    face = xp.where(is_x, xp.where(x >= 0, 0, 1), xp.where(is_y, xp.where(y >= 0, 2, 3), xp.where(z >= 0, 4, 5)))
    face = face.astype(xp.int32)
    ma = xp.maximum(xp.sum(xp.asarray(CUBE_N, dtype=d.dtype)[face] * d, axis=-1), _TINY)
    sc = xp.sum(xp.asarray(CUBE_SC, dtype=d.dtype)[face] * d, axis=-1)
    tc = xp.sum(xp.asarray(CUBE_TC, dtype=d.dtype)[face] * d, axis=-1)
    return face, (sc / ma + 1) / 2, (tc / ma + 1) / 2


def _cube_from(face, u, v):
    xp = namespace(face, u, v)
    u, v = xp.asarray(u), xp.asarray(v)
    face = xp.asarray(face).astype(xp.int32)
    sc, tc = (2 * u - 1)[..., None], (2 * v - 1)[..., None]
    dt = u.dtype
    d = (xp.asarray(CUBE_N, dtype=dt)[face] + sc * xp.asarray(CUBE_SC, dtype=dt)[face]
         + tc * xp.asarray(CUBE_TC, dtype=dt)[face])
    return _normalize(d, xp)


def _sign(a, xp):
    return xp.where(a >= 0, 1.0, -1.0).astype(a.dtype)  # sign(0) = +1 (pinned)


def _octahedral_to(d):
    """Pinned: ``p = (x, y)/(|x|+|y|+|z|)``; if z < 0: ``p = (1-|p_y|, 1-|p_x|) sign(p)``."""
    xp = namespace(d)
    x, y, z = _split(d)
    l1 = xp.maximum(xp.abs(x) + xp.abs(y) + xp.abs(z), _TINY)
    px, py = x / l1, y / l1
    lower = z < 0
    qx = xp.where(lower, (1 - xp.abs(py)) * _sign(px, xp), px)
    qy = xp.where(lower, (1 - xp.abs(px)) * _sign(py, xp), py)
    return _face0(qx, xp), (qx + 1) / 2, (qy + 1) / 2


def _octahedral_from(face, u, v):
    """Inverse fold: z = 1 - |p_x| - |p_y|; if z < 0, p = (1-|p_y|, 1-|p_x|) sign(p)."""
    xp = namespace(face, u, v)
    px, py = 2 * xp.asarray(u) - 1, 2 * xp.asarray(v) - 1
    z = 1 - xp.abs(px) - xp.abs(py)
    lower = z < 0
    qx = xp.where(lower, (1 - xp.abs(py)) * _sign(px, xp), px)
    qy = xp.where(lower, (1 - xp.abs(px)) * _sign(py, xp), py)
    return _normalize(xp.stack([qx, qy, z], axis=-1), xp)


def _hemispherical_to(d):
    xp = namespace(d)
    x, y, _ = _split(d)
    return _face0(x, xp), (x + 1) / 2, (y + 1) / 2


def _hemispherical_from(face, u, v):
    """Orthographic: ``z = sqrt(1 - x^2 - y^2)``; outside the disk clamped to the horizon."""
    xp = namespace(face, u, v)
    x, y = 2 * xp.asarray(u) - 1, 2 * xp.asarray(v) - 1
    z = xp.sqrt(xp.maximum(1 - x * x - y * y, 0.0))
    return _normalize(xp.stack([x, y, z], axis=-1), xp)


def _spherical_to(d):
    """OpenGL sphere map, ``m = 2 sqrt(x^2 + y^2 + (z+1)^2)``; singular at -z, whose whole rim is the
    one direction -z: exactly -z maps to the rim point (1, 0.5) (0/0 otherwise gave the centre, +z)."""
    xp = namespace(d)
    x, y, z = _split(d)
    m = 2 * xp.sqrt(xp.maximum(x * x + y * y + (z + 1) * (z + 1), _TINY * _TINY))
    pole = (x * x + y * y < _TINY * _TINY) & (z < 0)
    return _face0(x, xp), xp.where(pole, 1.0, x / m + 0.5), xp.where(pole, 0.5, y / m + 0.5)


def _spherical_from(face, u, v):
    """Reverse sphere map: s = (2u-1, 2v-1) is the xy part of h = normalize(d + z); d = 2 h_z h - z.

    Outside the disk (|s| = r > 1) the point is continued through the rim (-z) as the point
    2 - r on the opposite side (h_z < 0), so it stays a valid direction near -z.
    """
    xp = namespace(face, u, v)
    sx, sy = 2 * xp.asarray(u) - 1, 2 * xp.asarray(v) - 1
    r = xp.sqrt(sx * sx + sy * sy)
    rr = xp.clip(xp.where(r > 1, 2 - r, r), 0.0, 1.0)
    scale = xp.where(r > _TINY, rr / xp.maximum(r, _TINY), 1.0)
    hx, hy = sx * scale, sy * scale
    hz = xp.sqrt(xp.maximum(1 - rr * rr, 0.0)) * xp.where(r > 1, -1.0, 1.0)
    return _normalize(xp.stack([2 * hz * hx, 2 * hz * hy, 2 * hz * hz - 1], axis=-1), xp)


def _line_to(x):
    """Pinned ``line`` mapper: a scalar x in [0, 1] at u = x of a one-row texture (v = 1/2)."""
    xp = namespace(x)
    return _face0(x, xp), x * 1.0, 0.5


def _line_from(face, u, v):
    return namespace(face, u, v).asarray(u) + 0.0


def _line_inside(face, u, v):
    return (u >= 0) & (u <= 1)


register(Mapper("parabolic", 1, False, _parabolic_to, _parabolic_from, _disk_inside,
                "hemisphere z >= 0 on one paraboloid (thesis eq. 46); BRDF textures"))
register(Mapper("dual_paraboloid", 2, True, _dual_to, _dual_from, _disk_inside,
                "two paraboloids, z >= 0 left and z < 0 right (Heidrich & Seidel 1998)"))
register(Mapper("cube", 6, True, _cube_to, _cube_from, _all_inside,
                "six faces +X -X +Y -Y +Z -Z of the OpenGL cube map, side by side", wraps=True))
register(Mapper("octahedral", 1, True, _octahedral_to, _octahedral_from, _all_inside,
                "octahedral map of the sphere (Engelhardt & Dachsbacher 2008)", wraps=True))
register(Mapper("hemispherical", 1, False, _hemispherical_to, _hemispherical_from, _disk_inside,
                "orthographic hemisphere (thesis fig. 6); for comparison only"))
register(Mapper("spherical", 1, True, _spherical_to, _spherical_from, _disk_inside,
                "OpenGL sphere map (thesis fig. 6); singular at -z, for comparison only"))
register(Mapper("line", 1, False, _line_to, _line_from, _line_inside,
                "1D table of a scalar in [0, 1] (n.v, cos theta): texture (1, S), linear, clamped", scalar=True))

__all__ = ["CUBE_N", "CUBE_SC", "CUBE_TC", "MAPPERS", "Mapper", "get", "on_register", "register", "resolve"]
