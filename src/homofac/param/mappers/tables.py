"""Neighbour and nearest-valid-texel tables of a mapper (static NumPy, cached per (name, S)).

* :func:`neighbours`: the 4-neighbours of each texel for the Laplacian rows (thesis eq. 36), across
  face edges for the mappers that wrap (cube, octahedral; Latta-Kolb fig. 1);
* :func:`nearest_valid`: for every texel the nearest valid texel of the same face (the identity on
  valid texels), used to fill ("dilate") invalid texels so that a GPU's hardware bilinear filter reads
  the same values as :func:`homofac.param.mappers.bilinear`.
"""

from __future__ import annotations

import functools

import numpy as np
from jaxtyping import Int
from scipy.ndimage import distance_transform_edt
from scipy.spatial import cKDTree

from .geometry import check_size, directions64, frozen, valid_table
from .records import Mapper, get, on_register, resolve


def neighbours(m: Mapper | str, S: int) -> Int[np.ndarray, "HW 4"]:
    """Flat indices of the 4-neighbours (left, right, up, down) of each texel for the Laplacian, -1 if none.

    Only valid texels are linked (rows of invalid texels are all -1). Within a face: grid neighbours
    (the line mapper's one row has left and right only). ``cube`` and ``octahedral`` are also linked
    across face edges (Latta-Kolb fig. 1): an edge texel's neighbour is the valid texel (other than
    itself) whose centre direction is nearest to the direction just beyond the middle of its edge (the
    reverse projection extrapolated there). For the cube this is the texel on the other side of the
    shared cube edge; for the octahedral map the mirror image on the same folded edge ((r, 0) <->
    (S-1-r, 0), ...). The texel and its partner are mirror images about the edge, so the relation is
    symmetric and every texel has 4 neighbours. Octahedral: the two texels at the middle of a border
    edge meet both inside the square and across the fold, so they list each other twice (a double
    link of the Laplacian, as the geometry says).
    """
    m = resolve(m)
    return _neighbours(m.name, check_size(S))


#: How far beyond a face edge (in texels) the across-edge neighbour is looked up.
_BEYOND = 1e-3


@functools.lru_cache(maxsize=None)
def _neighbours(name: str, S: int) -> np.ndarray:
    m = get(name)
    valid = valid_table(name, S)
    H, W = valid.shape
    row, col = np.mgrid[0:H, 0:W]
    face = col // S
    flat_valid = np.flatnonzero(valid)
    tree = None
    if m.wraps:
        tree = cKDTree(directions64(name, S).reshape(-1, 3)[flat_valid])
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
    return frozen(nb.reshape(H * W, 4))




def nearest_valid(m: Mapper | str, S: int) -> Int[np.ndarray, "HW"]:
    """Flat index of the nearest valid texel of the same face, for every texel (identity on valid ones)."""
    m = resolve(m)
    return _nearest_valid(m.name, check_size(S))


@functools.lru_cache(maxsize=None)
def _nearest_valid(name: str, S: int) -> np.ndarray:
    valid = valid_table(name, S)
    H, W = valid.shape
    out = np.arange(H * W, dtype=np.int32).reshape(H, W)
    if valid.all():
        return frozen(out.reshape(-1))
    for f in range(W // S):
        sub = valid[:, f * S : (f + 1) * S]
        _, (ri, ci) = distance_transform_edt(~sub, return_indices=True)
        out[:, f * S : (f + 1) * S] = ri * W + f * S + ci
    return frozen(out.reshape(-1))


def dilate(m: Mapper | str, S: int, texture):
    """``texture`` (H, W, ...) with every invalid texel replaced by its nearest valid texel's value.

    The values a bilinear lookup of an in-domain direction reads never change (all four corners of
    such a footprint are valid by construction of :func:`~homofac.param.mappers.valid_mask`), and a
    GPU's hardware filter reads sensible values even at the rim of a paraboloid.
    """
    m = resolve(m)
    idx = _nearest_valid(m.name, check_size(S))
    t = texture
    flat = t.reshape((-1,) + tuple(t.shape[2:]))
    return flat[idx].reshape(t.shape)


for _f in (_neighbours, _nearest_valid):
    on_register(_f.cache_clear)

__all__ = ["dilate", "nearest_valid", "neighbours"]
