"""Cube maps of lights: texel directions and exact solid angles, aggregation, strips, the Environment.

The lights of every environment are the texels of a cube map of face size ``r`` in the pinned layout
of :mod:`homofac.param.mappers` (faces +X, -X, +Y, -Y, +Z, -Z left to right; texel ``k`` is the
row-major index into the ``(r, 6r)`` texture). :func:`finish` turns per-texel radiance into an
:class:`~homofac.light.environment.Environment` with exact texel corners and moments.
"""

from __future__ import annotations

import functools
from typing import Callable, Sequence

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..errors import HomofacError
from ..param import mappers
from .clean import check_power
from .environment import Environment
from .geometry import cube_corners
from .lights import moments_of, with_lights

#: Face file names of a cube map given as six images, in the pinned face order.
FACE_NAMES = ("px", "nx", "py", "ny", "pz", "nz")


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _spherical_triangle(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Solid angle of spherical triangles with unit corners (Van Oosterom-Strackee)."""
    bxc = np.stack(
        [b[..., 1] * c[..., 2] - b[..., 2] * c[..., 1], b[..., 2] * c[..., 0] - b[..., 0] * c[..., 2],
         b[..., 0] * c[..., 1] - b[..., 1] * c[..., 0]], axis=-1)
    num = np.abs(_dot(a, bxc))
    den = 1.0 + _dot(a, b) + _dot(b, c) + _dot(c, a)
    return 2.0 * np.arctan2(num, den)


@functools.lru_cache(maxsize=6)
def cube_texels(r: int) -> tuple[np.ndarray, np.ndarray]:
    """Texel centre directions ``(6 r^2, 3)`` and exact solid angles ``(6 r^2,)`` of the cube map of face
    size ``r`` (float64, read-only), row-major over the pinned ``(r, 6r)`` texture.

    Built from the cube mapper's reverse projection ``from_face_uv`` at the texel centres
    ``(i + 0.5)/r`` and corners ``i/r``; a cube texel's edges are great-circle arcs, so its solid angle
    is exactly that of the two spherical triangles spanned by its corners. The six faces are congruent
    (rotations of each other), so the solid angles of face 0 serve for all. Equal to
    ``mappers.texel_directions`` / ``texel_solid_angles`` (tested), which are too costly for the fine
    supersampling grids used here.
    """
    m = mappers.get("cube")
    t = np.arange(r + 1, dtype=np.float64) / r
    uc, vc = np.meshgrid(t, t)  # rows follow v, columns u
    corners = np.asarray(m.from_face_uv(np.int32(0), uc, vc), np.float64)
    a, b, c, e = corners[:-1, :-1], corners[:-1, 1:], corners[1:, 1:], corners[1:, :-1]
    omega = _spherical_triangle(a, b, c) + _spherical_triangle(a, c, e)  # (r, r)
    t = (np.arange(r, dtype=np.float64) + 0.5) / r
    uu, vv = np.meshgrid(t, t)
    d = np.empty((r, 6, r, 3))
    for f in range(6):
        d[:, f] = np.asarray(m.from_face_uv(np.int32(f), uu, vv), np.float64)
    d = d.reshape(-1, 3)
    w = np.ascontiguousarray(np.broadcast_to(omega[:, None, :], (r, 6, r))).reshape(-1)
    d.flags.writeable = False
    w.flags.writeable = False
    return d, w


def aggregate(values: np.ndarray, r: int, k: int) -> np.ndarray:
    """Sum the ``k x k`` sub-texels of a face-size ``r k`` cube texture onto the face-size ``r`` texels.

    ``values`` has shape ``(6 (r k)^2, C)`` in row-major order of the ``(r k, 6 r k)`` texture; face
    blocks are ``r k`` columns wide, so consecutive groups of ``k`` rows/columns are exactly the
    sub-texels of one coarse texel. Returns ``(6 r^2, C)``.
    """
    c = values.shape[-1]
    return values.reshape(r, k, 6 * r, k, c).sum(axis=(1, 3)).reshape(-1, c)


def supersampled_means(fn: Callable[[np.ndarray], np.ndarray], r: int, k: int) -> np.ndarray:
    """Solid-angle weighted mean of ``fn`` over ``k x k`` sub-points of each cube texel: ``(6 r^2, C)``."""
    d, w = cube_texels(r * k)
    vals = np.asarray(fn(d), np.float64)
    num = aggregate(vals * w[:, None], r, k)
    den = aggregate(w[:, None], r, k)
    return num / den


def cube_nearest(s: int, d: np.ndarray) -> np.ndarray:
    """Flat index of the cube texel (face size ``s``) containing each direction (pinned layout)."""
    m = mappers.get("cube")
    face, u, v = (np.asarray(x) for x in m.to_face_uv(np.asarray(d, np.float64)))
    row = np.clip(np.floor(v * s), 0, s - 1).astype(np.int64)
    col = np.clip(np.floor(u * s), 0, s - 1).astype(np.int64)
    return row * (6 * s) + face.astype(np.int64) * s + col


def cube_strip(a: np.ndarray, source: str) -> np.ndarray:
    """A horizontal ``(S, 6S, 3)`` cube strip from a horizontal or vertical strip or six faces."""
    if isinstance(a, (list, tuple)):
        if len(a) != 6:
            raise HomofacError(f"{source}: a cube map needs six faces ({' '.join(FACE_NAMES)}), got {len(a)}")
        faces = [np.asarray(f) for f in a]
        shapes = [f.shape[:2] for f in faces]
        if any(f.ndim != 3 or f.shape[2] < 3 for f in faces):
            raise HomofacError(f"{source}: cube faces must be (S, S, 3) images")
        if len(set(shapes)) != 1 or shapes[0][0] != shapes[0][1] or shapes[0][0] < 2:
            sizes = ", ".join(f"{n} {s[1]}x{s[0]}" for n, s in zip(FACE_NAMES, shapes))
            raise HomofacError(f"{source}: cube faces must be square, of equal size and at least 2x2, got {sizes}")
        return np.concatenate([f[..., :3] for f in faces], axis=1)
    a = np.asarray(a)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=-1)
    if a.ndim != 3 or a.shape[2] not in (3, 4):
        raise HomofacError(f"{source}: cube map must be an (S, 6S, 3) or (6S, S, 3) image, got shape {a.shape}")
    a = a[..., :3]
    h, w = a.shape[:2]
    if min(h, w) < 2 and (w == 6 * h or h == 6 * w):
        raise HomofacError(f"{source}: cube face size must be at least 2, got {w}x{h}")
    if w == 6 * h and h > 0:
        return a
    if h == 6 * w and w > 0:
        s = w
        return a.reshape(6, s, s, 3).transpose(1, 0, 2, 3).reshape(s, 6 * s, 3)
    raise HomofacError(f"{source}: cube map must be a 6:1 (S x 6S) or 1:6 (6S x S) strip, got {w}x{h}")


@functools.lru_cache(maxsize=4)
def _texel_geometry(r: int) -> tuple:
    """``(corners (6 r^2, 4, 3), moments)`` of the cube texels of face ``r`` as jax float32 arrays (immutable):
    they depend on ``r`` only, and a bake loads the same resolution several times (the 256 face's corners and
    moments took about 1 s of CPU each time)."""
    d, w = cube_texels(r)
    corners = cube_corners(r)
    return jnp.asarray(corners.astype(np.float32)), moments_of(d, w, corners)


def finish(
    radiance: np.ndarray, r: int, info: dict, lights: Sequence[dict], energy_before: np.ndarray | None
) -> Environment:
    """Build the Environment of a resampled cube map (+ extra lights), with energies in ``info``."""
    d, w = cube_texels(r)
    rad32 = radiance.astype(np.float32)
    w32 = w.astype(np.float32)
    after = (rad32.astype(np.float64) * w32.astype(np.float64)[:, None]).sum(axis=0)
    info = dict(info)
    info.update(
        resolution=r,
        n_texels=int(d.shape[0]),
        energy_before=[float(x) for x in (after if energy_before is None else energy_before)],
        energy_after=[float(x) for x in after],
    )
    corners, moments = _texel_geometry(r)
    env = Environment(
        directions=jnp.asarray(d.astype(np.float32)),
        radiance=jnp.asarray(rad32),
        solid_angle=jnp.asarray(w32),
        info=info,
        corners=corners,
        moments=moments,
    )
    env = with_lights(env, lights)
    check_power(np.asarray(env.radiance, np.float64), np.asarray(env.solid_angle, np.float64), info["source"])
    return env


def to_cube_image(env: Environment) -> Float[Array, "r 6r 3"]:
    """The cube-texel radiance of ``env`` as an ``(r, 6r, 3)`` image (pinned layout; extra lights omitted).

    Write it with ``homofac.io.exr.write_exr(path, np.asarray(img), header={"envmap": OpenEXR.ENVMAP_CUBE})``
    to get a file :func:`load_environment` reads back.
    """
    r = env.info.get("resolution")
    n = env.info.get("n_texels")
    if r is None or n is None or n != 6 * r * r:
        raise HomofacError(f"{env.info.get('source', 'environment')}: not a cube-map environment (no resolution in info)")
    return env.radiance[:n].reshape(r, 6 * r, 3)


__all__ = ["FACE_NAMES", "aggregate", "cube_nearest", "cube_strip", "cube_texels", "finish", "supersampled_means",
           "to_cube_image"]
