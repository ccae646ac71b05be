"""Lat-long maps (pinned layout): pixel directions, solid angles, bilinear taps, box downsampling.

Row ``r`` <-> theta = pi (r + 0.5)/H from +z (row 0 is up), column ``c`` <-> phi = 2 pi (c + 0.5)/W,
d = (sin th cos ph, sin th sin ph, cos th), pixel solid angle (2 pi/W)(cos th_top - cos th_bottom).
The aspect must be exactly 2:1.
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

from ..errors import HomofacError


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


def latlong_taps(h: int, w: int, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def box_downsample(img: np.ndarray, f: int) -> np.ndarray:
    """Solid-angle weighted ``f x f`` box average of a lat-long map (energy preserving exactly)."""
    h, w, c = img.shape
    dw = latlong_solid_angles(h, w)[:, None, None]
    e = (img * dw).reshape(h // f, f, w // f, f, c).sum(axis=(1, 3))
    return e / latlong_solid_angles(h // f, w // f)[:, None, None]


def downsample_strips(strips: Iterable[tuple[int, np.ndarray]], h: int, w: int, f: int) -> np.ndarray:
    """:func:`box_downsample` of an H x W lat-long map given as ``(y0, rows)`` strips (each a multiple of
    ``f`` rows, aligned to ``f``): solid-angle weighted, exactly energy preserving, holding one strip."""
    if h % f or w % f:
        raise HomofacError(f"a {w} x {h} lat-long map does not divide by the downsampling factor {f}")
    dw = latlong_solid_angles(h, w)
    coarse = latlong_solid_angles(h // f, w // f)
    out = np.zeros((h // f, w // f, 3), np.float64)
    for y0, strip in strips:
        n = strip.shape[0]
        if y0 % f or n % f:
            raise HomofacError(f"lat-long strip at row {y0} of {n} rows is not aligned to the factor {f}")
        e = (np.asarray(strip, np.float64) * dw[y0 : y0 + n, None, None]).reshape(n // f, f, w // f, f, 3).sum(axis=(1, 3))
        out[y0 // f : (y0 + n) // f] = e / coarse[y0 // f : (y0 + n) // f, None, None]
    return out.astype(np.float32)


__all__ = ["box_downsample", "downsample_strips", "latlong_directions", "latlong_solid_angles", "latlong_taps"]
