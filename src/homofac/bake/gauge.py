"""The second harmonic's tensor map in 3 channels: the face gauge (issue 42; docs/notes/bake.md, "Memory,
sixteenth session").

A layer's tensor M(a) (symmetric, traceless, M a = 0; :func:`homofac.bake.build.harmonic_maps`) is read only as
t^T M t with t orthogonal to the axis a. Adding a w^T + w a^T to M changes no such read, so at each texel
(direction a, cube face of major axis m, minor axes (u, v) in x, y, z order) w is chosen so that M' = M + a w^T
+ w a^T has row and column m zero:

    w_m = -M_mm / (2 a_m),   w_j = -(M_mj + w_m a_j) / a_m   (j != m)

and the other 2 x 2 block (M'_uu, M'_vv, M'_uv) is stored. The read at a direction a of that face is

    t^T M t = t_u^2 M'_uu + t_v^2 M'_vv + 2 t_u t_v M'_uv

exact at the texels; |a_m| >= 1/sqrt(3) keeps w bounded and smooth within a face, and the cube mapper's bilinear
read stays in one face. Between texels the read adds 2 (t.a_i)(t.w_i) per texel i, t.a_i = t.(a_i - a): second
order inside the texels' hull, first order on the faces' clamped edge strips (tests/test_bake_harmonic.py: RMS
error of a smooth field 1.4-2x the 5-channel read's at faces 8-32; on the benchmark's cells no change above
0.0005, docs/notes/bake.md).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..param import mappers


def face_gauge(m5, size: int) -> np.ndarray:
    """(S, 6 S, 3) float32: the tensor maps m5 (S, 6 S, 5) = (M_xx, M_yy, M_xy, M_xz, M_yz) (M_zz = -M_xx - M_yy)
    of a cube of face ``size`` as (M'_uu, M'_vv, M'_uv) in the face gauge of the module docstring."""
    a = np.asarray(mappers.texel_directions("cube", size), np.float64).reshape(-1, 3)
    xx, yy, xy, xz, yz = np.asarray(m5, np.float64).reshape(-1, 5).T
    M = np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1), np.stack([xz, yz, -xx - yy], -1)], 1)
    idx = np.arange(len(a))
    major = np.argmax(np.abs(a), 1)
    am = a[idx, major]
    wm = -M[idx, major, major] / (2 * am)
    w = -(M[idx, major, :] + wm[:, None] * a) / am[:, None]  # w_j for j != m
    w[idx, major] = wm
    Mp = M + a[:, :, None] * w[:, None, :] + w[:, :, None] * a[:, None, :]
    minor = np.array([[1, 2], [0, 2], [0, 1]])[major]
    u, v = minor[:, 0], minor[:, 1]
    return np.stack([Mp[idx, u, u], Mp[idx, v, v], Mp[idx, u, v]], -1).reshape(size, 6 * size, 3).astype(np.float32)


def gauge_read(m3: Float[Array, "N 3"], a: Float[Array, "N 3"], t: Float[Array, "N 3"]) -> Float[Array, "N"]:
    """t_u^2 M'_uu + t_v^2 M'_vv + 2 t_u t_v M'_uv with (u, v) the minor axes of a's cube face (the major axis
    the largest |a_i|, ties to x, then y): the face-gauge read of the module docstring."""
    ab = jnp.abs(a)
    fx = (ab[:, 0] >= ab[:, 1]) & (ab[:, 0] >= ab[:, 2])
    fy = ~fx & (ab[:, 1] >= ab[:, 2])
    tu = jnp.where(fx, t[:, 1], t[:, 0])
    tv = jnp.where(fx | fy, t[:, 2], t[:, 1])
    return tu * tu * m3[:, 0] + tv * tv * m3[:, 1] + 2.0 * tu * tv * m3[:, 2]


__all__ = ["face_gauge", "gauge_read"]
