"""Resampling lat-long and cube images to the cube-texel lights, preserving each channel's energy.

Each cube texel is supersampled with ``k x k`` sub-points (the texel centres of the cube map of face
size ``k r``, denser than the source pixels), the source is looked up bilinearly (lat-long: clamped in
theta, wrapped in phi; cube: the mapper's bilinear lookup), averaged weighted by the sub-point solid
angles, and finally each channel is rescaled by (source energy / resampled energy).
``info["energy_before"]`` and ``info["energy_after"]`` (the map only, without extra lights) agree to
float32 rounding (~1e-7).
"""

from __future__ import annotations

import functools
import math
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from ..errors import HomofacError
from ..param import mappers
from .clean import apply_boost, check_resolution, clean, label
from .cubemap import FACE_NAMES, aggregate, cube_nearest, cube_strip, cube_texels, finish
from .environment import Environment
from .latlong import box_downsample, latlong_directions, latlong_solid_angles, latlong_taps

#: Largest supersampling factor per texel side; larger sources are box-averaged first.
MAX_SUPERSAMPLE = 16


@functools.lru_cache(maxsize=2)
def _resampler(kind: str, h: int, w: int, r: int, k: int):
    """Sparse ``(6 r^2, H W)`` matrix A and ``(6 r^2,)`` denominators such that the solid-angle weighted
    mean of the bilinearly interpolated source map over the ``k x k`` sub-points of each cube texel is
    ``(A @ L_flat) / den``. ``kind`` is ``"latlong"`` (H x W = H x 2H) or ``"cube"`` (H x 6H).
    Cached: repeated loads of maps of one size cost one sparse product."""
    R = r * k
    d, ws = cube_texels(R)
    idx, wts = latlong_taps(h, w, d) if kind == "latlong" else mappers.bilinear("cube", d, h)
    wts *= ws[:, None]
    # Group the sub-points by coarse texel, in texel order: (R, 6R) = (r, k, 6r, k) -> (r, 6r, k, k).
    # Each texel then owns 4 k^2 consecutive entries: the CSR structure is known, nothing to sort
    # (duplicate column indices are allowed and summed by the product).
    order = lambda a: a.reshape(r, k, 6 * r, k, 4).transpose(0, 2, 1, 3, 4).ravel()  # noqa: E731
    itype = np.int32 if max(h * w, 4 * d.shape[0]) < 2**31 - 1 else np.int64
    indptr = np.arange(6 * r * r + 1, dtype=itype) * itype(4 * k * k)
    A = sp.csr_matrix((order(wts), order(idx).astype(itype), indptr), shape=(6 * r * r, h * w))
    den = aggregate(ws[:, None], r, k)[:, 0]
    return A, den


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


def from_latlong(
    array,
    resolution: int = 32,
    *,
    boost: dict | None = None,
    lights: Sequence[dict] = (),
    source: str = "<latlong array>",
    extra_info: dict | None = None,
) -> Environment:
    """Environment from an in-memory ``(H, W, 3)`` lat-long map (pinned layout; W must be 2 H).

    Cleans (NaN/Inf -> 0 with a warning, negatives -> 0), applies the optional highlight ``boost``,
    resamples to the cube texels of face size ``resolution`` preserving each channel's energy, and
    appends the extra ``lights``. See the module docstring.
    """
    source = label(source)
    r = check_resolution(resolution, source)
    a = np.asarray(array)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=-1)
    if a.ndim != 3 or a.shape[2] not in (3, 4):
        raise HomofacError(f"{source}: lat-long map must be an (H, W, 3) image, got shape {a.shape}")
    a = a[..., :3]
    h, w = a.shape[:2]
    if h < 1 or w != 2 * h:
        raise HomofacError(f"{source}: lat-long map must be 2:1 (W = 2 H), got {w}x{h}")
    img, n_neg, n_bad = clean(a, source)
    img, boost_info = apply_boost(img, boost, source)
    dw_row = latlong_solid_angles(h, w)
    e_src = (img * dw_row[:, None, None]).sum(axis=(0, 1))
    info = {
        "source": source,
        "kind": "latlong",
        "source_shape": [int(h), int(w)],
        "clamped_negative": n_neg,
        "nonfinite": n_bad,
        "boost": boost_info,
        **(extra_info or {}),
    }
    if not np.any(e_src > 0) and not lights:
        raise HomofacError(f"{source}: environment is all zero: nothing to light with")

    # Sub-points at least as dense as the source pixels: cube sub-texel ~ 2/(r k) rad at a face centre,
    # source pixel pi/H rad. Very large sources are first box-averaged (exactly energy preserving).
    k = max(2, math.ceil(2.0 * h / (math.pi * r)))
    src = img
    if k > MAX_SUPERSAMPLE:
        f = next((f for f in range(2, h + 1) if h % f == 0 and math.ceil(2.0 * h / (f * math.pi * r)) <= MAX_SUPERSAMPLE), None)
        if f is not None:
            src = box_downsample(img, f)
            info["prefilter"] = int(f)
        k = min(MAX_SUPERSAMPLE, max(2, math.ceil(2.0 * src.shape[0] / (math.pi * r))))
    info["supersample"] = int(k)
    A, den = _resampler("latlong", src.shape[0], src.shape[1], r, k)
    means = np.asarray(A @ src.reshape(-1, 3)) / den[:, None]
    _, wt = cube_texels(r)

    def push(c: int) -> np.ndarray:  # nearest-texel splat of each source pixel's energy
        idx = cube_nearest(r, latlong_directions(h, w).reshape(-1, 3))
        e = (img[..., c] * dw_row[:, None]).reshape(-1)
        return np.bincount(idx, weights=e, minlength=6 * r * r) / wt

    rad, scales = _rescale(means, wt, e_src, push)
    info["energy_scale"] = scales
    return finish(rad, r, info, lights, e_src)


def from_cube(
    array,
    resolution: int | None = None,
    *,
    boost: dict | None = None,
    lights: Sequence[dict] = (),
    source: str = "<cube array>",
    extra_info: dict | None = None,
) -> Environment:
    """Environment from an in-memory cube map: ``(S, 6S, 3)`` strip (pinned faces +X -X +Y -Y +Z -Z),
    ``(6S, S, 3)`` vertical strip, or a list of six ``(S, S, 3)`` faces.

    ``resolution`` defaults to ``S`` (no resampling). If ``S`` is a multiple of it the texels are
    solid-angle weighted box averages (exact); otherwise the map is supersampled with the cube
    mapper's bilinear lookup and each channel rescaled to the source energy.
    """
    source = label(source)
    strip = cube_strip(array, source)
    s = strip.shape[0]
    r = s if resolution is None else check_resolution(resolution, source)
    img, n_neg, n_bad = clean(strip, source)
    img, boost_info = apply_boost(img, boost, source)
    _, w_src = cube_texels(s)
    flat = img.reshape(-1, 3)
    e_src = (flat * w_src[:, None]).sum(axis=0)
    info = {
        "source": source,
        "kind": "cube",
        "source_shape": [int(s), int(6 * s)],
        "clamped_negative": n_neg,
        "nonfinite": n_bad,
        "boost": boost_info,
        **(extra_info or {}),
    }
    if not np.any(e_src > 0) and not lights:
        raise HomofacError(f"{source}: environment is all zero: nothing to light with")
    _, wt = cube_texels(r)
    if s % r == 0:
        f = s // r
        means = aggregate(flat * w_src[:, None], r, f) / aggregate(w_src[:, None], r, f)
        info["supersample"] = 1
    else:
        k = min(MAX_SUPERSAMPLE, max(2, math.ceil(2 * s / r)))
        info["supersample"] = int(k)
        A, den = _resampler("cube", s, 6 * s, r, k)
        means = np.asarray(A @ flat) / den[:, None]

    def push(c: int) -> np.ndarray:
        idx = cube_nearest(r, cube_texels(s)[0])
        return np.bincount(idx, weights=flat[:, c] * w_src, minlength=6 * r * r) / wt

    rad, scales = _rescale(means, wt, e_src, push)
    info["energy_scale"] = scales
    return finish(rad, r, info, lights, e_src)


__all__ = ["MAX_SUPERSAMPLE", "from_cube", "from_latlong"]
