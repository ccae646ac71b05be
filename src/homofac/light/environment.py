"""Environment maps as lists of lights: load, clean, resample to cube texels, synthesise.

An :class:`Environment` is the light list of the pinned lighting computation (DESIGN.md, thesis
eq. 10): unit directions ``l_k``, RGB radiance ``L_k`` and the exact solid angle ``dw_k`` of each
light, so that ``radiance * solid_angle`` is the power term of ``L(v, n) = sum_k f L_k max(n.l_k, 0) dw_k``.
The lights are the texels of a cube map of face size ``resolution`` (``6 r^2`` lights, pinned cube
layout of :mod:`homofac.param.mappers`: texel ``k`` is the row-major index into the ``(r, 6r)``
texture), optionally followed by extra directional lights (``solid_angle`` 1, ``radiance`` = their
irradiance). It is an equinox module: ``jax.grad`` with respect to ``radiance`` works.

Sources
-------
* lat-long maps (EXR or Radiance ``.hdr``), pinned layout: row ``r`` <-> theta = pi (r+0.5)/H from +z
  (row 0 is up), column ``c`` <-> phi = 2 pi (c+0.5)/W, d = (sin th cos ph, sin th sin ph, cos th),
  pixel solid angle (2 pi/W)(cos th_top - cos th_bottom). The aspect must be exactly 2:1.
* cube maps: an EXR with header ``envmap = cube`` (or any image exactly 6:1 or 1:6 without an
  ``envmap`` attribute) stored as a horizontal ``(S, 6S)`` strip in the pinned face order
  +X, -X, +Y, -Y, +Z, -Z, or as a vertical ``(6S, S)`` strip (same faces top to bottom); or a directory
  (or a list) of six face images named ``px nx py ny pz nz`` (``.exr`` or ``.hdr``). Each face image is
  oriented as its block of the pinned texture: row = v S - 0.5, column = u S - 0.5.
* a bare bundled name (``"forest"`` or ``"forest.exr"`` when no such file exists): one of
  :data:`BUNDLED`, 256x128 lat-long copies of CC0 maps (see ``homofac/data/hdri/LICENSE.txt``).

Cleaning (recorded in ``info``): negative values are clamped to 0 (``clamped_negative`` counts the
pixels with a negative channel). **NaN/Inf pixels are set to 0** (the whole pixel) with a
``warnings.warn`` that counts them (``nonfinite`` in ``info``): a corrupt pixel must not poison every
lighting sample, and refusing the whole map for a few bad pixels is unhelpful. An environment whose
total power is 0 after cleaning (and after adding extra lights) raises :class:`HomofacError`.

Resampling preserves the total energy ``sum(L dw)`` of each channel: each cube texel is supersampled
with ``k x k`` sub-points (the texel centres of the cube map of face size ``k r``, denser than the
source pixels), the source is looked up bilinearly (lat-long: clamped in theta, wrapped in phi; cube:
the mapper's bilinear lookup), averaged weighted by the sub-point solid angles, and finally each channel
is rescaled by (source energy / resampled energy). ``info["energy_before"]`` and
``info["energy_after"]`` (the map only, without extra lights) agree to float32 rounding (~1e-7).

Highlight boost (thesis §5.7), off by default: ``boost={"threshold": 0.9, "factor": 10}`` multiplies the
source pixels whose luminance exceeds ``threshold * max luminance`` by ``factor`` before resampling.

Extra lights: ``lights=[{"type": "directional", "direction": [x, y, z], "irradiance": [r, g, b]}, ...]``.
A ``"point"`` light is treated as directional, because the environment is distant (the lighting does
not depend on the surface position): its ``direction`` (or ``position``, normalised) is the direction
towards it and its ``irradiance`` at the object is given directly, or as ``intensity / |position|^2``.
"""

from __future__ import annotations

import functools
import math
import os
import warnings
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..errors import HomofacError

__all__ = [
    "Environment",
    "BUNDLED",
    "bundled",
    "load_environment",
    "from_latlong",
    "from_cube",
    "to_cube_image",
    "with_lights",
    "total_power",
    "dominant_direction",
    "luminance",
    "uniform",
    "gradient_sky",
    "sun_sky",
    "painted_lights",
    "latlong_directions",
    "latlong_solid_angles",
]

#: Names of the bundled lat-long maps (256x128, CC0): ``load_environment("forest")``.
BUNDLED = ("city", "forest", "interior", "studio")

#: Rec. 709 luminance weights (linear RGB).
LUMINANCE = (0.2126, 0.7152, 0.0722)

#: Face file names of a cube map given as six images, in the pinned face order.
FACE_NAMES = ("px", "nx", "py", "ny", "pz", "nz")

_MAX_SUPERSAMPLE = 16


class Environment(eqx.Module):
    """Light list of the lighting computation; a pytree whose arrays are leaves.

    ``radiance * solid_angle[:, None]`` is the power term of the pinned sum (for an extra directional
    light ``solid_angle`` is 1 and ``radiance`` its irradiance). ``info`` (static, JSON-friendly) holds the
    provenance: source, kind, resolution, n_texels, clamped_negative, nonfinite, energy_before,
    energy_after, boost, lights, ...
    """

    directions: Float[Array, "L 3"]
    radiance: Float[Array, "L 3"]
    solid_angle: Float[Array, "L"]
    info: dict = eqx.field(static=True)
    #: Corners (L, 4, 3) of each light texel, counter-clockwise from outside (all zero for delta
    #: lights); they let the lighting integrate max(n.l, 0) exactly over each texel (light.geometry).
    corners: Optional[Float[Array, "L 4 3"]] = None
    #: (moment (L, 3), sin_radius (L,)) of the lights, precomputed from the corners (light.geometry).
    moments: Optional[tuple] = None

    @property
    def num_lights(self) -> int:
        return int(self.directions.shape[0])


# ----------------------------------------------------------------------------------------------
# geometry (cube maths comes from homofac.param.mappers; lat-long is pinned here)


def _mappers():
    from ..param import mappers

    return mappers, mappers.get("cube")


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
def _cube_texels(r: int) -> tuple[np.ndarray, np.ndarray]:
    """Texel centre directions ``(6 r^2, 3)`` and exact solid angles ``(6 r^2,)`` of the cube map of face
    size ``r`` (float64, read-only), row-major over the pinned ``(r, 6r)`` texture.

    Built from the cube mapper's reverse projection ``from_face_uv`` at the texel centres
    ``(i + 0.5)/r`` and corners ``i/r``; a cube texel's edges are great-circle arcs, so its solid angle
    is exactly that of the two spherical triangles spanned by its corners. The six faces are congruent
    (rotations of each other), so the solid angles of face 0 serve for all. Equal to
    ``mappers.texel_directions`` / ``texel_solid_angles`` (tested), which are too costly for the fine
    supersampling grids used here.
    """
    _, m = _mappers()
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


def _aggregate(values: np.ndarray, r: int, k: int) -> np.ndarray:
    """Sum the ``k x k`` sub-texels of a face-size ``r k`` cube texture onto the face-size ``r`` texels.

    ``values`` has shape ``(6 (r k)^2, C)`` in row-major order of the ``(r k, 6 r k)`` texture; face
    blocks are ``r k`` columns wide, so consecutive groups of ``k`` rows/columns are exactly the
    sub-texels of one coarse texel. Returns ``(6 r^2, C)``.
    """
    c = values.shape[-1]
    return values.reshape(r, k, 6 * r, k, c).sum(axis=(1, 3)).reshape(-1, c)


def _supersampled_means(fn: Callable[[np.ndarray], np.ndarray], r: int, k: int) -> np.ndarray:
    """Solid-angle weighted mean of ``fn`` over ``k x k`` sub-points of each cube texel: ``(6 r^2, C)``."""
    d, w = _cube_texels(r * k)
    vals = np.asarray(fn(d), np.float64)
    num = _aggregate(vals * w[:, None], r, k)
    den = _aggregate(w[:, None], r, k)
    return num / den


def latlong_solid_angles(h: int, w: int) -> np.ndarray:
    """``(H,)`` solid angle of one pixel in each row of an H x W lat-long map (pinned layout)."""
    edges = np.pi * np.arange(h + 1, dtype=np.float64) / h
    return (2.0 * np.pi / w) * (np.cos(edges[:-1]) - np.cos(edges[1:]))


def latlong_directions(h: int, w: int) -> np.ndarray:
    """``(H, W, 3)`` pixel-centre directions of an H x W lat-long map (pinned layout, row 0 up)."""
    th = np.pi * (np.arange(h) + 0.5) / h
    ph = 2.0 * np.pi * (np.arange(w) + 0.5) / w
    st = np.sin(th)[:, None]
    return np.stack(
        [st * np.cos(ph)[None, :], st * np.sin(ph)[None, :], np.broadcast_to(np.cos(th)[:, None], (h, w))], axis=-1
    )


def _latlong_taps(h: int, w: int, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear taps of an H x W lat-long map at unit directions ``(N, 3)``: flat pixel indices and
    weights, both ``(N, 4)``. Pinned layout: row = theta H / pi - 0.5 (clamped), col = phi W / 2 pi - 0.5
    (wrapped in phi)."""
    th = np.arccos(np.clip(d[:, 2], -1.0, 1.0))
    ph = np.mod(np.arctan2(d[:, 1], d[:, 0]), 2.0 * np.pi)
    row = th * (h / np.pi) - 0.5
    col = ph * (w / (2.0 * np.pi)) - 0.5
    r0 = np.floor(row)
    tr = row - r0
    r0 = r0.astype(np.int64)
    r1 = np.clip(r0 + 1, 0, h - 1) * w
    r0 = np.clip(r0, 0, h - 1) * w
    c0 = np.floor(col)
    tc = col - c0
    c0 = c0.astype(np.int64)
    c1 = np.mod(c0 + 1, w)
    c0 = np.mod(c0, w)
    idx = np.stack([r0 + c0, r0 + c1, r1 + c0, r1 + c1], axis=-1)
    wts = np.stack([(1 - tr) * (1 - tc), (1 - tr) * tc, tr * (1 - tc), tr * tc], axis=-1)
    return idx, wts


def _cube_taps(s: int, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear taps ``(N, 4)`` flat indices and weights of directions in a cube texture of face size ``s``.

    numpy twin of ``mappers.bilinear(cube, d, s)`` (thesis eq. 33-34, clamp-to-edge within the face the
    mapper's ``to_face_uv`` assigns; every cube texel is valid), without JAX dispatch/compile costs.
    """
    _, m = _mappers()
    face, u, v = (np.asarray(x) for x in m.to_face_uv(np.asarray(d, np.float64)))
    w_tex = 6 * s
    cu = np.clip(u * s - 0.5, 0.0, s - 1.0)
    cv = np.clip(v * s - 0.5, 0.0, s - 1.0)
    j0 = np.clip(np.floor(cu), 0, s - 2)
    i0 = np.clip(np.floor(cv), 0, s - 2)
    au, av = cu - j0, cv - i0
    bu, bv = 1.0 - au, 1.0 - av
    base = i0.astype(np.int64) * w_tex + face.astype(np.int64) * s + j0.astype(np.int64)
    idx = base[:, None] + np.array([0, 1, w_tex, w_tex + 1], np.int64)
    wts = np.stack([bu * bv, au * bv, bu * av, au * av], axis=-1)
    return idx, wts


def _cube_nearest(s: int, d: np.ndarray) -> np.ndarray:
    """Flat index of the cube texel (face size ``s``) containing each direction (pinned layout)."""
    _, m = _mappers()
    face, u, v = (np.asarray(x) for x in m.to_face_uv(np.asarray(d, np.float64)))
    row = np.clip(np.floor(v * s), 0, s - 1).astype(np.int64)
    col = np.clip(np.floor(u * s), 0, s - 1).astype(np.int64)
    return row * (6 * s) + face.astype(np.int64) * s + col


@functools.lru_cache(maxsize=2)
def _resampler(kind: str, h: int, w: int, r: int, k: int):
    """Sparse ``(6 r^2, H W)`` matrix A and ``(6 r^2,)`` denominators such that the solid-angle weighted
    mean of the bilinearly interpolated source map over the ``k x k`` sub-points of each cube texel is
    ``(A @ L_flat) / den``. ``kind`` is ``"latlong"`` (H x W = H x 2H) or ``"cube"`` (H x 6H).
    Cached: repeated loads of maps of one size cost one sparse product."""
    import scipy.sparse as sp

    R = r * k
    d, ws = _cube_texels(R)
    idx, wts = _latlong_taps(h, w, d) if kind == "latlong" else _cube_taps(h, d)
    wts *= ws[:, None]
    # Group the sub-points by coarse texel, in texel order: (R, 6R) = (r, k, 6r, k) -> (r, 6r, k, k).
    # Each texel then owns 4 k^2 consecutive entries: the CSR structure is known, nothing to sort
    # (duplicate column indices are allowed and summed by the product).
    order = lambda a: a.reshape(r, k, 6 * r, k, 4).transpose(0, 2, 1, 3, 4).ravel()  # noqa: E731
    itype = np.int32 if max(h * w, 4 * d.shape[0]) < 2**31 - 1 else np.int64
    indptr = np.arange(6 * r * r + 1, dtype=itype) * itype(4 * k * k)
    A = sp.csr_matrix((order(wts), order(idx).astype(itype), indptr), shape=(6 * r * r, h * w))
    den = _aggregate(ws[:, None], r, k)[:, 0]
    return A, den


def _latlong_box_downsample(img: np.ndarray, f: int) -> np.ndarray:
    """Solid-angle weighted ``f x f`` box average of a lat-long map (energy preserving exactly)."""
    h, w, c = img.shape
    dw = latlong_solid_angles(h, w)[:, None, None]
    e = (img * dw).reshape(h // f, f, w // f, f, c).sum(axis=(1, 3))
    return e / latlong_solid_angles(h // f, w // f)[:, None, None]


def luminance(rgb):
    """Rec. 709 luminance of linear RGB ``(..., 3) -> (...)`` (numpy or jax)."""
    return rgb[..., 0] * LUMINANCE[0] + rgb[..., 1] * LUMINANCE[1] + rgb[..., 2] * LUMINANCE[2]


# ----------------------------------------------------------------------------------------------
# validation and cleaning


def _label(source: Any) -> str:
    return str(source)


def _check_resolution(resolution: Any, source: str) -> int:
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or int(resolution) < 2:
        raise HomofacError(f"{source}: resolution must be an integer >= 2 (cube face size), got {resolution!r}")
    return int(resolution)


def _rgb(value: Any, what: str, source: str, *, allow_negative: bool = False) -> np.ndarray:
    """A scalar or 3-vector colour as a float64 (3,) array."""
    try:
        a = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise HomofacError(f"{source}: {what} must be a number or [r, g, b], got {value!r}") from None
    if a.ndim == 0:
        a = np.repeat(a, 3)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or (not allow_negative and np.any(a < 0)):
        raise HomofacError(f"{source}: {what} must be a finite non-negative number or [r, g, b], got {value!r}")
    return a


def _direction(value: Any, what: str, source: str) -> np.ndarray:
    try:
        a = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise HomofacError(f"{source}: {what} must be [x, y, z], got {value!r}") from None
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.linalg.norm(a) < 1e-12:
        raise HomofacError(f"{source}: {what} must be a non-zero finite [x, y, z], got {value!r}")
    return a / np.linalg.norm(a)


def _clean(img: np.ndarray, source: str) -> tuple[np.ndarray, int, int]:
    """Set non-finite pixels to 0 (warning) and clamp negatives; returns (float64 image, n_negative, n_nonfinite)."""
    a = np.array(img, dtype=np.float64, copy=True)
    bad = ~np.isfinite(a).all(axis=-1)
    n_bad = int(bad.sum())
    if n_bad:
        warnings.warn(f"{source}: {n_bad} non-finite (NaN/Inf) pixels set to 0", RuntimeWarning, stacklevel=3)
        a[bad] = 0.0
    neg = (a < 0).any(axis=-1)
    n_neg = int(neg.sum())
    if n_neg:
        np.maximum(a, 0.0, out=a)
    return a, n_neg, n_bad


def _apply_boost(img: np.ndarray, boost: Any, source: str) -> tuple[np.ndarray, dict | None]:
    """Thesis §5.7 highlight boost on a cleaned source map (in place on a copy)."""
    if boost is None or boost is False:
        return img, None
    if not isinstance(boost, dict):
        raise HomofacError(f"{source}: boost must be a dict {{threshold, factor}}, got {boost!r}")
    unknown = set(boost) - {"threshold", "factor"}
    if unknown:
        raise HomofacError(f"{source}: unknown boost key(s) {sorted(unknown)} (expected threshold, factor)")
    try:
        thr = float(boost.get("threshold", 0.9))
        fac = float(boost.get("factor", 10.0))
    except (TypeError, ValueError):
        raise HomofacError(f"{source}: boost threshold and factor must be numbers, got {boost!r}") from None
    if not (0.0 <= thr <= 1.0):
        raise HomofacError(f"{source}: boost threshold must be in [0, 1], got {thr}")
    if not (math.isfinite(fac) and fac > 0):
        raise HomofacError(f"{source}: boost factor must be a positive number, got {fac}")
    lum = luminance(img)
    mask = lum > thr * lum.max()
    out = img.copy()
    out[mask] *= fac
    return out, {"threshold": thr, "factor": fac, "pixels": int(mask.sum())}


def _check_power(radiance: np.ndarray, solid_angle: np.ndarray, source: str) -> None:
    if not np.any(radiance * solid_angle[:, None] > 0):
        raise HomofacError(f"{source}: environment is all zero: nothing to light with")


def _finish(
    radiance: np.ndarray, r: int, info: dict, lights: Sequence[dict], energy_before: np.ndarray | None
) -> Environment:
    """Build the Environment of a resampled cube map (+ extra lights), with energies in ``info``."""
    d, w = _cube_texels(r)
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
    from .geometry import cube_corners

    env = Environment(
        directions=jnp.asarray(d.astype(np.float32)),
        radiance=jnp.asarray(rad32),
        solid_angle=jnp.asarray(w32),
        info=info,
        corners=jnp.asarray(cube_corners(r).astype(np.float32)),
        moments=_moments(d, w, cube_corners(r)),
    )
    env = with_lights(env, lights)
    _check_power(np.asarray(env.radiance, np.float64), np.asarray(env.solid_angle, np.float64), info["source"])
    return env


def _rescale(texel_means: np.ndarray, w: np.ndarray, e_src: np.ndarray, fallback) -> tuple[np.ndarray, list]:
    """Rescale each channel so that sum(L w) equals the source energy ``e_src``."""
    e_res = (texel_means * w[:, None]).sum(axis=0)
    out = texel_means.copy()
    scales = []
    for c in range(out.shape[1]):
        if e_src[c] <= 0:
            out[:, c] = 0.0
            scales.append(1.0)
            continue
        if e_res[c] <= 0:  # the sub-points missed every lit source pixel: push the energy instead
            out[:, c] = fallback(c)
            e_res_c = (out[:, c] * w).sum()
        else:
            e_res_c = e_res[c]
        s = e_src[c] / e_res_c
        out[:, c] *= s
        scales.append(float(s))
    return out, scales


# ----------------------------------------------------------------------------------------------
# lat-long and cube maps in memory


def from_latlong(
    array,
    resolution: int = 32,
    *,
    boost: dict | None = None,
    lights: Sequence[dict] = (),
    source: str = "<latlong array>",
) -> Environment:
    """Environment from an in-memory ``(H, W, 3)`` lat-long map (pinned layout; W must be 2 H).

    Cleans (NaN/Inf -> 0 with a warning, negatives -> 0), applies the optional highlight ``boost``,
    resamples to the cube texels of face size ``resolution`` preserving each channel's energy, and
    appends the extra ``lights``. See the module docstring.
    """
    source = _label(source)
    r = _check_resolution(resolution, source)
    a = np.asarray(array)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=-1)
    if a.ndim != 3 or a.shape[2] not in (3, 4):
        raise HomofacError(f"{source}: lat-long map must be an (H, W, 3) image, got shape {a.shape}")
    a = a[..., :3]
    h, w = a.shape[:2]
    if h < 1 or w != 2 * h:
        raise HomofacError(f"{source}: lat-long map must be 2:1 (W = 2 H), got {w}x{h}")
    img, n_neg, n_bad = _clean(a, source)
    img, boost_info = _apply_boost(img, boost, source)
    dw_row = latlong_solid_angles(h, w)
    e_src = (img * dw_row[:, None, None]).sum(axis=(0, 1))
    info = {
        "source": source,
        "kind": "latlong",
        "source_shape": [int(h), int(w)],
        "clamped_negative": n_neg,
        "nonfinite": n_bad,
        "boost": boost_info,
    }
    if not np.any(e_src > 0) and not lights:
        raise HomofacError(f"{source}: environment is all zero: nothing to light with")

    # Sub-points at least as dense as the source pixels: cube sub-texel ~ 2/(r k) rad at a face centre,
    # source pixel pi/H rad. Very large sources are first box-averaged (exactly energy preserving).
    k = max(2, math.ceil(2.0 * h / (math.pi * r)))
    src = img
    if k > _MAX_SUPERSAMPLE:
        f = next((f for f in range(2, h + 1) if h % f == 0 and math.ceil(2.0 * h / (f * math.pi * r)) <= _MAX_SUPERSAMPLE), None)
        if f is not None:
            src = _latlong_box_downsample(img, f)
            info["prefilter"] = int(f)
        k = min(_MAX_SUPERSAMPLE, max(2, math.ceil(2.0 * src.shape[0] / (math.pi * r))))
    info["supersample"] = int(k)
    A, den = _resampler("latlong", src.shape[0], src.shape[1], r, k)
    means = np.asarray(A @ src.reshape(-1, 3)) / den[:, None]
    _, wt = _cube_texels(r)

    def push(c: int) -> np.ndarray:  # nearest-texel splat of each source pixel's energy
        idx = _cube_nearest(r, latlong_directions(h, w).reshape(-1, 3))
        e = (img[..., c] * dw_row[:, None]).reshape(-1)
        return np.bincount(idx, weights=e, minlength=6 * r * r) / wt

    rad, scales = _rescale(means, wt, e_src, push)
    info["energy_scale"] = scales
    return _finish(rad, r, info, lights, e_src)


def _cube_strip(a: np.ndarray, source: str) -> np.ndarray:
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


def from_cube(
    array,
    resolution: int | None = None,
    *,
    boost: dict | None = None,
    lights: Sequence[dict] = (),
    source: str = "<cube array>",
) -> Environment:
    """Environment from an in-memory cube map: ``(S, 6S, 3)`` strip (pinned faces +X -X +Y -Y +Z -Z),
    ``(6S, S, 3)`` vertical strip, or a list of six ``(S, S, 3)`` faces.

    ``resolution`` defaults to ``S`` (no resampling). If ``S`` is a multiple of it the texels are
    solid-angle weighted box averages (exact); otherwise the map is supersampled with the cube
    mapper's bilinear lookup and each channel rescaled to the source energy.
    """
    source = _label(source)
    strip = _cube_strip(array, source)
    s = strip.shape[0]
    r = s if resolution is None else _check_resolution(resolution, source)
    img, n_neg, n_bad = _clean(strip, source)
    img, boost_info = _apply_boost(img, boost, source)
    _, w_src = _cube_texels(s)
    flat = img.reshape(-1, 3)
    e_src = (flat * w_src[:, None]).sum(axis=0)
    info = {
        "source": source,
        "kind": "cube",
        "source_shape": [int(s), int(6 * s)],
        "clamped_negative": n_neg,
        "nonfinite": n_bad,
        "boost": boost_info,
    }
    if not np.any(e_src > 0) and not lights:
        raise HomofacError(f"{source}: environment is all zero: nothing to light with")
    _, wt = _cube_texels(r)
    if s % r == 0:
        f = s // r
        means = _aggregate(flat * w_src[:, None], r, f) / _aggregate(w_src[:, None], r, f)
        info["supersample"] = 1
    else:
        k = min(_MAX_SUPERSAMPLE, max(2, math.ceil(2 * s / r)))
        info["supersample"] = int(k)
        A, den = _resampler("cube", s, 6 * s, r, k)
        means = np.asarray(A @ flat) / den[:, None]

    def push(c: int) -> np.ndarray:
        idx = _cube_nearest(r, _cube_texels(s)[0])
        return np.bincount(idx, weights=flat[:, c] * w_src, minlength=6 * r * r) / wt

    rad, scales = _rescale(means, wt, e_src, push)
    info["energy_scale"] = scales
    return _finish(rad, r, info, lights, e_src)


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


# ----------------------------------------------------------------------------------------------
# files


def bundled(name: str) -> Path:
    """Path of a bundled lat-long map (one of :data:`BUNDLED`)."""
    stem = name[:-4] if name.lower().endswith(".exr") else name
    if stem not in BUNDLED:
        raise HomofacError(f"{name}: not a bundled environment (bundled: {', '.join(BUNDLED)})")
    return Path(__file__).resolve().parents[1] / "data" / "hdri" / f"{stem}.exr"


def _read_image(path: Path) -> tuple[np.ndarray, str | None]:
    """``(rgb, envmap kind from the header or None)`` of an EXR or Radiance HDR file."""
    from ..io.files import read_head
    from ..io.exr import EXR_MAGIC, envmap_kind, read_exr_with_header
    from ..io.hdr import read_hdr

    magic = read_head(path, "an image", 10)
    if magic.startswith(EXR_MAGIC):
        rgb, header = read_exr_with_header(path)
        return rgb, envmap_kind(header)
    if magic.startswith(b"#?"):
        return read_hdr(path), None
    raise HomofacError(f"{path}: not an OpenEXR or Radiance HDR file")


def _face_files(directory: Path) -> list[Path]:
    found = []
    missing = []
    for n in FACE_NAMES:
        cands = sorted(p for p in directory.glob(f"{n}.*") if p.suffix.lower() in (".exr", ".hdr", ".pic"))
        if not cands:
            missing.append(n)
        else:
            found.append(cands[0])
    if missing:
        raise HomofacError(f"{directory}: cube map directory lacks face image(s) {' '.join(missing)} (.exr or .hdr)")
    return found


def load_environment(
    path: str | os.PathLike | Sequence[str | os.PathLike],
    resolution: int = 32,
    *,
    boost: dict | None = None,
    lights: Sequence[dict] = (),
) -> Environment:
    """Load an environment map and resample it to ``6 resolution^2`` cube-texel lights.

    ``path``: a lat-long EXR or ``.hdr`` (2:1), a cube-map EXR (header ``envmap = cube``, or a 6:1 / 1:6
    strip), a directory of six faces ``px nx py ny pz nz``, a list of six face files (that order), or a
    bare bundled name such as ``"forest"``. Negative pixels are clamped to 0; NaN/Inf pixels are set to
    0 with a warning (both counted in ``info``). ``boost`` is the thesis §5.7 highlight boost
    (``{"threshold": 0.9, "factor": 10}``, default off), ``lights`` extra directional/point lights.
    Raises :class:`HomofacError` (one line naming the file) on any bad input, and if the result has no
    power at all.
    """
    if isinstance(path, (list, tuple)):
        files = [Path(p) for p in path]
        label = f"cube faces [{', '.join(str(p) for p in files)}]"
        if len(files) != 6:
            raise HomofacError(f"{label}: a cube map needs six face files ({' '.join(FACE_NAMES)}), got {len(files)}")
        faces = [_read_image(p)[0] for p in files]
        return from_cube(faces, resolution, boost=boost, lights=lights, source=label)
    p = Path(os.fspath(path)).expanduser()
    label = str(p)
    if not p.exists():
        s = os.fspath(path)
        bare = os.sep not in s and "/" not in s
        stem = s[:-4] if s.lower().endswith(".exr") else s
        if bare and stem in BUNDLED:
            p = bundled(stem)
            label = str(p)
        else:
            raise HomofacError(f"{p}: no such file (bundled environments: {', '.join(BUNDLED)})")
    if p.is_dir():
        faces = [_read_image(f)[0] for f in _face_files(p)]
        return from_cube(faces, resolution, boost=boost, lights=lights, source=label)
    rgb, kind = _read_image(p)
    h, w = rgb.shape[:2]
    if kind == "cube" or (kind is None and (w == 6 * h or h == 6 * w)):
        return from_cube(rgb, resolution, boost=boost, lights=lights, source=label)
    return from_latlong(rgb, resolution, boost=boost, lights=lights, source=label)


# ----------------------------------------------------------------------------------------------
# extra lights


def _normalise_light(spec: Any, i: int, source: str) -> dict:
    where = f"{source}: lights[{i}]"
    if not isinstance(spec, dict):
        raise HomofacError(f"{where} must be a dict with type, direction, irradiance; got {spec!r}")
    typ = spec.get("type", "directional")
    if typ not in ("directional", "point"):
        raise HomofacError(f"{where}: unknown light type {typ!r} (directional or point)")
    allowed = {"type", "direction", "irradiance"} | ({"position", "intensity"} if typ == "point" else set())
    unknown = set(spec) - allowed
    if unknown:
        raise HomofacError(f"{where}: unknown key(s) {sorted(unknown)} for a {typ} light (allowed: {sorted(allowed)})")
    if "direction" in spec and "position" in spec:
        raise HomofacError(f"{where}: give direction or position, not both")
    if "irradiance" in spec and "intensity" in spec:
        raise HomofacError(f"{where}: give irradiance or intensity, not both")
    vec = spec.get("direction", spec.get("position"))
    if vec is None:
        raise HomofacError(f"{where}: missing direction")
    d = _direction(vec, "light direction", where)
    if "intensity" in spec:
        dist2 = float(np.sum(np.asarray(vec, np.float64) ** 2))
        irr = _rgb(spec["intensity"], "light intensity", where) / dist2
    else:
        irr = _rgb(spec.get("irradiance", 1.0), "light irradiance", where)
    return {"type": typ, "direction": [float(x) for x in d], "irradiance": [float(x) for x in irr]}


def with_lights(env: Environment, lights: Sequence[dict]) -> Environment:
    """``env`` with extra directional lights appended (a point light is treated as directional).

    Each light ``{"type": "directional" | "point", "direction": [x, y, z], "irradiance": c}`` becomes one
    entry with ``solid_angle = 1`` and ``radiance = irradiance`` (so its power term is the irradiance
    it delivers to a surface facing it). A point light may give ``position`` instead of ``direction``
    and ``intensity`` instead of ``irradiance`` (irradiance = intensity / |position|^2).
    """
    source = str(env.info.get("source", "environment"))
    if lights is None:
        lights = ()
    if isinstance(lights, dict):
        lights = [lights]
    specs = [_normalise_light(s, i, source) for i, s in enumerate(lights)]
    if not specs:
        return env
    d = jnp.asarray(np.array([s["direction"] for s in specs], np.float32))
    rad = jnp.asarray(np.array([s["irradiance"] for s in specs], np.float32))
    info = dict(env.info)
    info["lights"] = list(info.get("lights", [])) + specs
    return Environment(
        directions=jnp.concatenate([env.directions, d.astype(env.directions.dtype)]),
        radiance=jnp.concatenate([env.radiance, rad.astype(env.radiance.dtype)]),
        solid_angle=jnp.concatenate([env.solid_angle, jnp.ones(len(specs), env.solid_angle.dtype)]),
        info=info,
        corners=None if env.corners is None else jnp.concatenate(
            [env.corners, jnp.zeros((len(specs), 4, 3), env.corners.dtype)]),
        moments=None if env.moments is None else tuple(
            jnp.concatenate([a, jnp.asarray(b, a.dtype)]) for a, b in zip(
                env.moments, _moments(np.asarray(d), np.ones(len(specs)), np.zeros((len(specs), 4, 3))))),
    )


def _moments(directions, solid_angle, corners) -> tuple:
    from .geometry import texel_moments

    m, sinr = texel_moments(directions, solid_angle, corners)
    return jnp.asarray(m, jnp.float32), jnp.asarray(sinr, jnp.float32)


# ----------------------------------------------------------------------------------------------
# derived quantities


def total_power(env: Environment) -> Float[Array, "3"]:
    """``sum_k radiance_k * solid_angle_k`` per channel (for uniform radiance 1: 4 pi)."""
    return jnp.sum(env.radiance * env.solid_angle[:, None], axis=0)


def dominant_direction(env: Environment) -> Float[Array, "3"]:
    """Dominant light direction, thesis eq. 66: ``normalize(sum_k e_k l_k)``.

    ``e_k = luminance(radiance_k) * solid_angle_k`` (weighted by solid angle because cube texels are
    not equal). Raises :class:`HomofacError` when the sum vanishes (isotropic lighting has no dominant
    direction; give one explicitly). Differentiable when traced (the check is then skipped).
    """
    e = luminance(env.radiance) * env.solid_angle
    s = e @ env.directions
    n = jnp.linalg.norm(s)
    total = jnp.sum(jnp.abs(e))
    if not isinstance(n, jax.core.Tracer) and not isinstance(total, jax.core.Tracer):
        if not float(n) > 1e-5 * float(total):
            src = env.info.get("source", "environment")
            raise HomofacError(
                f"{src}: no dominant light direction (sum of e_k l_k vanishes: isotropic lighting); give one explicitly"
            )
    return s / n


# ----------------------------------------------------------------------------------------------
# synthetic environments (evaluated analytically per cube texel, supersampled)

_SYNTH_K = 4


def _synthetic(fn: Callable[[np.ndarray], np.ndarray], r: int, info: dict, lights: Sequence[dict] = ()) -> Environment:
    rad = _supersampled_means(fn, r, _SYNTH_K)
    info = {"kind": "synthetic", "clamped_negative": 0, "nonfinite": 0, "boost": None, "supersample": _SYNTH_K, **info}
    return _finish(rad, r, info, lights, None)


def uniform(value=1.0, resolution: int = 32, *, lights: Sequence[dict] = ()) -> Environment:
    """Constant radiance ``value`` (scalar or RGB) in every direction; total power ``4 pi value``."""
    r = _check_resolution(resolution, "uniform")
    c = _rgb(value, "value", "uniform")
    # exact: every texel mean is the constant
    d, _ = _cube_texels(r)
    rad = np.broadcast_to(c, (d.shape[0], 3)).copy()
    info = {"source": "uniform", "kind": "synthetic", "value": c.tolist(), "clamped_negative": 0, "nonfinite": 0, "boost": None}
    return _finish(rad, r, info, lights, None)


def gradient_sky(a=1.0, b=0.0, resolution: int = 32, *, lights: Sequence[dict] = ()) -> Environment:
    """``L(theta) = a + b cos(theta)`` (scalar or RGB ``a``, ``b``), clamped at 0.

    The irradiance at a normal n is ``pi (a + (2/3) b n_z)`` while ``a >= |b|`` (no clamping).
    """
    r = _check_resolution(resolution, "gradient_sky")
    ca = _rgb(a, "a", "gradient_sky", allow_negative=True)
    cb = _rgb(b, "b", "gradient_sky", allow_negative=True)

    def fn(d):
        return np.maximum(ca[None, :] + cb[None, :] * d[:, 2:3], 0.0)

    return _synthetic(fn, r, {"source": "gradient_sky", "a": ca.tolist(), "b": cb.tolist()}, lights)


def _add_disc(rad: np.ndarray, r: int, centre: np.ndarray, alpha: float, colour: np.ndarray) -> None:
    """Add a disc light (angular radius ``alpha`` rad, radiance ``colour``) with its exact power.

    Power ``colour * 2 pi (1 - cos alpha)`` is spread over the texels in proportion to the covered
    solid angle (sub-point coverage); a disc smaller than the sub-point spacing is splatted onto the
    four nearest texels with the cube mapper's bilinear weights.
    """
    _, w = _cube_texels(r)
    power = colour * (2.0 * np.pi * (1.0 - np.cos(alpha)))
    k_need = math.ceil(4.0 / (r * max(alpha, 1e-12)))
    cov = None
    if k_need <= _MAX_SUPERSAMPLE:
        k = max(_SYNTH_K, k_need)
        ds, ws = _cube_texels(r * k)
        inside = ds @ centre >= np.cos(alpha)
        if inside.any():
            cov = _aggregate((ws * inside)[:, None], r, k)[:, 0]
    if cov is not None and cov.sum() > 0:
        rad += (cov / cov.sum() / w)[:, None] * power[None, :]
    else:
        idx, wt = _cube_taps(r, centre[None, :])
        idx, wt = idx[0], wt[0] / wt[0].sum()
        np.add.at(rad, idx, (wt / w[idx])[:, None] * power[None, :])


def sun_sky(
    sun_direction=(0.3, 0.2, 0.9),
    sun_radiance=1.0e4,
    sun_angle_deg: float = 0.53,
    *,
    sky=(0.05, 0.08, 0.15),
    sky_gradient=0.0,
    resolution: int = 32,
    lights: Sequence[dict] = (),
) -> Environment:
    """A sun disc over a sky: sky ``L = sky + sky_gradient cos(theta)`` (clamped at 0), plus a disc of
    angular DIAMETER ``sun_angle_deg`` (the real sun: 0.53 degrees) centred on ``sun_direction`` with
    radiance ``sun_radiance`` (scalar or RGB) added on top. The disc's power is exact
    (``sun_radiance * 2 pi (1 - cos(angle/2))``); a disc smaller than a texel is splatted onto the
    nearest texels (bilinear weights of the cube mapper), so its direction is kept.
    """
    r = _check_resolution(resolution, "sun_sky")
    c = _direction(sun_direction, "sun_direction", "sun_sky")
    lsun = _rgb(sun_radiance, "sun_radiance", "sun_sky")
    a = _rgb(sky, "sky", "sun_sky")
    b = _rgb(sky_gradient, "sky_gradient", "sun_sky", allow_negative=True)
    try:
        ang = float(sun_angle_deg)
    except (TypeError, ValueError):
        raise HomofacError(f"sun_sky: sun_angle_deg must be a number, got {sun_angle_deg!r}") from None
    if not (0.0 < ang < 180.0):
        raise HomofacError(f"sun_sky: sun_angle_deg must be in (0, 180), got {ang}")
    rad = _supersampled_means(lambda d: np.maximum(a[None, :] + b[None, :] * d[:, 2:3], 0.0), r, _SYNTH_K)
    _add_disc(rad, r, c, math.radians(ang) / 2.0, lsun)
    info = {
        "source": "sun_sky",
        "kind": "synthetic",
        "sun_direction": c.tolist(),
        "sun_radiance": lsun.tolist(),
        "sun_angle_deg": ang,
        "sky": a.tolist(),
        "sky_gradient": b.tolist(),
        "clamped_negative": 0,
        "nonfinite": 0,
        "boost": None,
    }
    return _finish(rad, r, info, lights, None)


def painted_lights(
    lights_list: Sequence[tuple],
    resolution: int = 32,
    *,
    background=0.0,
    lights: Sequence[dict] = (),
) -> Environment:
    """Painted area lights (thesis §5.7): discs ``(direction, angular_radius_deg, rgb radiance)`` over a
    constant ``background`` radiance; each disc's power is exact (see :func:`sun_sky`)."""
    r = _check_resolution(resolution, "painted_lights")
    bg = _rgb(background, "background", "painted_lights")
    d, _ = _cube_texels(r)
    rad = np.broadcast_to(bg, (d.shape[0], 3)).copy()
    desc = []
    for i, item in enumerate(lights_list):
        try:
            direction, radius_deg, colour = item
        except (TypeError, ValueError):
            raise HomofacError(f"painted_lights: light {i} must be (direction, angular_radius_deg, rgb), got {item!r}") from None
        c = _direction(direction, f"light {i} direction", "painted_lights")
        col = _rgb(colour, f"light {i} colour", "painted_lights")
        try:
            rd = float(radius_deg)
        except (TypeError, ValueError):
            raise HomofacError(f"painted_lights: light {i} angular radius must be a number, got {radius_deg!r}") from None
        if not (0.0 < rd <= 180.0):
            raise HomofacError(f"painted_lights: light {i} angular radius must be in (0, 180] degrees, got {rd}")
        _add_disc(rad, r, c, math.radians(rd), col)
        desc.append({"direction": c.tolist(), "angular_radius_deg": rd, "radiance": col.tolist()})
    info = {"source": "painted_lights", "kind": "synthetic", "painted": desc, "background": bg.tolist(),
            "clamped_negative": 0, "nonfinite": 0, "boost": None}
    return _finish(rad, r, info, lights, None)
