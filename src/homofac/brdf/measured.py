"""Measured BRDFs in the MERL binary format (Matusik, Pfister, Brand & McMillan 2003).

File layout (little-endian): a header of three int32 ``(90, 90, 180)`` = resolutions of
(theta_half, theta_diff, phi_diff), then ``3 * 90 * 90 * 180`` float64 values, channel-major (all
red, then all green, then all blue); within a channel phi_diff varies fastest, theta_half slowest.
Stored values times the scale factors R 1/1500, G 1.15/1500, B 1.66/1500 are the BRDF.
Other positive resolutions in the header are accepted (a coarser table of the same layout).

Indexing (as the reference ``BRDFRead.cpp``), in Rusinkiewicz (1998) half/difference angles:
  theta_half: non-linear, u = sqrt(theta_h / (pi/2)) * N_h   (dense near the specular peak)
  theta_diff: linear over [0, pi/2), u = theta_d / (pi/2) * N_d
  phi_diff:   linear over [0, pi),   u = (phi_d mod pi) / pi * N_p (reciprocity: phi_d ~ phi_d + pi)
Grid point i sits at u = i (the reference code truncates u, i.e. reads the sample at the lower
end of each cell). This module interpolates trilinearly in u instead of truncating: clamped at the
borders in theta_half and theta_diff, periodic in phi_diff. :func:`tabulate_merl` samples at the
same grid points, so a table written from a smooth model reads back within interpolation error.

Negative entries are holes (unmeasured configurations): the interpolation leaves them out and
renormalizes the measured corners' weights; only a lookup with no measured corner reads 0.
:func:`count_holes` reports how many grid cells have one.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..errors import HomofacError
from ..io.files import read_bounded, write_atomically
from .core import BRDF, ModelSpec, _as_float, make, register

#: Standard MERL resolution (theta_half, theta_diff, phi_diff).
MERL_DIMS = (90, 90, 180)
#: MERL files larger than this are not read (the standard 90 x 90 x 180 table is 35 MiB).
MAX_MERL_BYTES = 256 << 20
#: Stored value * scale = BRDF value (R, G, B), as in the reference reader.
MERL_SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
_HALF_PI = np.pi / 2


# ----------------------------------------------------------------------------------------------
# File I/O


def load_merl(path: str | os.PathLike) -> np.ndarray:
    """Read a MERL ``.binary`` file into a ``(N_h, N_d, N_p, 3)`` float32 table (normally (90, 90, 180, 3)).

    Values are BRDF values (scale factors applied); holes stay negative.

    Raises:
        HomofacError: missing or unreadable file, short header, non-positive resolutions, a size
            that does not match the header, or NaN/Inf values (one line, naming the file).
    """
    p = Path(path)
    if not p.exists():
        raise HomofacError(f"{p}: MERL file not found")
    raw = read_bounded(p, "a MERL", MAX_MERL_BYTES)
    if len(raw) < 12:
        raise HomofacError(f"{p}: not a MERL BRDF file (only {len(raw)} bytes, header needs 12)")
    dims = tuple(int(d) for d in np.frombuffer(raw, dtype="<i4", count=3))
    if any(d < 2 or d > 100_000 for d in dims):
        raise HomofacError(f"{p}: not a MERL BRDF file (header resolutions {dims}, expected {MERL_DIMS})")
    n = dims[0] * dims[1] * dims[2]
    expected = 12 + 3 * n * 8
    if len(raw) != expected:
        what = "truncated" if len(raw) < expected else "too long"
        raise HomofacError(
            f"{p}: MERL file {what}: {len(raw)} bytes, header {dims} needs {expected}"
        )
    vals = np.frombuffer(raw, dtype="<f8", offset=12, count=3 * n).reshape(3, *dims)
    bad = int(np.count_nonzero(~np.isfinite(vals)))
    if bad:
        raise HomofacError(f"{p}: MERL file has {bad} non-finite (NaN/Inf) values; holes must be negative")
    table = vals * MERL_SCALE[:, None, None, None]
    return np.ascontiguousarray(np.moveaxis(table, 0, -1)).astype(np.float32)


def save_merl(path: str | os.PathLike, table: Any) -> None:
    """Write a ``(N_h, N_d, N_p, 3)`` table of BRDF values as a MERL ``.binary`` file.

    Values are divided by the scale factors and stored as float64. The file is written to a
    temporary file in the same directory and renamed, so a failure never leaves a partial file.
    ``load_merl(path)`` returns a float32 ``table`` bit-exactly.
    """
    p = Path(path)
    t = np.asarray(table)
    if t.ndim != 4 or t.shape[-1] != 3 or min(t.shape[:3]) < 2:
        raise HomofacError(f"{p}: MERL table must have shape (N_h, N_d, N_p, 3) with N >= 2, got {t.shape}")
    if not np.all(np.isfinite(t)):
        raise HomofacError(f"{p}: MERL table has non-finite values")
    header = np.asarray(t.shape[:3], dtype="<i4").tobytes()
    body = (np.moveaxis(t.astype(np.float64), -1, 0) / MERL_SCALE[:, None, None, None]).astype("<f8")
    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            f.write(header)
            f.write(np.ascontiguousarray(body).tobytes())

    write_atomically(p, "MERL file", write)


def count_holes(x: BRDF | Any) -> int:
    """Number of grid cells (theta_h, theta_d, phi_d) with a negative (unmeasured) entry in any channel.

    ``x`` is a MERL table or a ``merl`` :class:`BRDF`.
    """
    t = x.params["table"] if isinstance(x, BRDF) else x
    return int(np.count_nonzero(np.any(np.asarray(t) < 0, axis=-1)))


# ----------------------------------------------------------------------------------------------
# Rusinkiewicz coordinates


@jax.jit
def half_diff_angles(wi: Array, wo: Array) -> tuple[Array, Array, Array]:
    """Rusinkiewicz (1998) angles ``(theta_h, theta_d, phi_d)`` of a direction pair (local frame).

    h = normalize(wi + wo); d = wi expressed in the frame that rotates h to the normal
    (rotate by -phi_h about z, then by -theta_h about y). phi_d in (-pi, pi].
    """
    wi = _as_float(wi)
    wo = _as_float(wo)
    s = wi + wo
    h = s / jnp.sqrt(jnp.maximum(jnp.sum(s * s, axis=-1, keepdims=True), 1e-30))
    hx, hy, hz = h[..., 0], h[..., 1], h[..., 2]
    rho2 = hx * hx + hy * hy
    ok = rho2 > 1e-30
    rho = jnp.sqrt(jnp.where(ok, rho2, 1.0))
    cp = jnp.where(ok, hx / rho, 1.0)  # cos(phi_h)
    sp = jnp.where(ok, hy / rho, 0.0)  # sin(phi_h)
    st = jnp.where(ok, rho, 0.0)  # sin(theta_h)
    ct = hz  # cos(theta_h)
    # rotate wi by -phi_h about z
    x1 = wi[..., 0] * cp + wi[..., 1] * sp
    y1 = -wi[..., 0] * sp + wi[..., 1] * cp
    z1 = wi[..., 2]
    # rotate by -theta_h about y
    dx = x1 * ct - z1 * st
    dy = y1
    dz = x1 * st + z1 * ct
    theta_h = jnp.arctan2(st, ct)
    theta_d = jnp.arctan2(jnp.sqrt(dx * dx + dy * dy), dz)
    phi_d = jnp.arctan2(dy, dx)
    return theta_h, theta_d, phi_d


@jax.jit
def from_half_diff(theta_h: Array, theta_d: Array, phi_d: Array) -> tuple[Array, Array]:
    """Inverse of :func:`half_diff_angles` with phi_h = 0: ``(wi, wo)``."""
    sd, cd = jnp.sin(theta_d), jnp.cos(theta_d)
    d = jnp.stack([sd * jnp.cos(phi_d), sd * jnp.sin(phi_d), cd], axis=-1)
    sh, ch = jnp.sin(theta_h), jnp.cos(theta_h)
    wi = jnp.stack([d[..., 0] * ch + d[..., 2] * sh, d[..., 1], -d[..., 0] * sh + d[..., 2] * ch], axis=-1)
    h = jnp.stack([sh, jnp.zeros_like(sh), ch], axis=-1)
    wo = 2.0 * jnp.sum(wi * h, axis=-1, keepdims=True) * h - wi
    return wi, wo


# ----------------------------------------------------------------------------------------------
# Lookup


def _merl_fn(p: dict[str, Array], wi: Array, wo: Array) -> Array:
    """Trilinear lookup over the *measured* corners: holes (negative entries) get weight 0 and the other
    corners' weights are renormalized, so a hole costs nothing where a neighbour was measured; a lookup
    whose eight corners are all holes reads 0."""
    table = p["table"]
    nh, nd, npd = table.shape[:3]
    th, td, pd = half_diff_angles(wi, wo)
    uh = jnp.clip(jnp.sqrt(jnp.clip(th / _HALF_PI, 0.0, 1.0)) * nh, 0.0, nh - 1)
    ud = jnp.clip(td / _HALF_PI * nd, 0.0, nd - 1)
    up = jnp.mod(pd, jnp.pi) / jnp.pi * npd
    ih = jnp.minimum(jnp.floor(uh), nh - 2).astype(jnp.int32)
    idd = jnp.minimum(jnp.floor(ud), nd - 2).astype(jnp.int32)
    fp = jnp.floor(up)
    ip0 = jnp.mod(fp.astype(jnp.int32), npd)
    ip1 = jnp.mod(ip0 + 1, npd)
    th_ = (uh - ih)[..., None]
    td_ = (ud - idd)[..., None]
    tp_ = (up - fp)[..., None]
    flat = table.reshape(-1, 3)
    num = 0.0
    den = 0.0
    for a, wa in ((ih, 1 - th_), (ih + 1, th_)):
        for b, wb in ((idd, 1 - td_), (idd + 1, td_)):
            for c, wc in ((ip0, 1 - tp_), (ip1, tp_)):
                v = jnp.take(flat, (a * nd + b) * npd + c, axis=0)
                w = wa * wb * wc * (v >= 0)
                num = num + w * jnp.maximum(v, 0.0)
                den = den + w
    return jnp.where(den > 0, num / jnp.where(den > 0, den, 1.0), 0.0)


def _prepare(params: dict[str, Any]) -> dict[str, Any]:
    for name in params:
        if name not in ("file", "table"):
            raise HomofacError(f"brdf.{name}: unknown parameter for model 'merl'; its parameters: file, table")
    if "file" in params and "table" in params:
        raise HomofacError("brdf.file: model 'merl' takes file= or table=, not both")
    if "file" in params:
        return {"table": load_merl(params["file"])}
    if "table" not in params:
        raise HomofacError("brdf.file: model 'merl' needs file= (a MERL .binary file) or table=")
    t = params["table"]
    shape = tuple(np.shape(t))
    if len(shape) != 4 or shape[-1] != 3 or min(shape[:3]) < 2:
        raise HomofacError(f"brdf.table must have shape (N_h, N_d, N_p, 3) with N >= 2, e.g. (90, 90, 180, 3), got {shape}")
    return params


MERL_DOC = """Measured BRDF in the MERL format (Matusik et al. 2003, "A data-driven reflectance model").

A (90, 90, 180, 3) table over Rusinkiewicz half/difference angles (theta_h non-linear, theta_d,
phi_d mod pi), trilinearly interpolated (clamped in theta, periodic in phi_d) over the measured
corners: negative entries (holes) are left out, a lookup with no measured corner reads 0. Parameter: table (a pytree leaf, traced under jit), or file= at construction."""

register(ModelSpec("merl", _merl_fn, {"table": None}, True, "", MERL_DOC, prepare=_prepare,
                   schema={"file": (str, ...)}))


def merl(file: str | os.PathLike | None = None, table: Any = None) -> BRDF:
    """A measured BRDF from a MERL ``.binary`` ``file`` or a ``(N_h, N_d, N_p, 3)`` ``table``."""
    kw: dict[str, Any] = {}
    if file is not None:
        kw["file"] = file
    if table is not None:
        kw["table"] = table
    return make("merl", **kw)


# ----------------------------------------------------------------------------------------------
# Tabulation


def merl_grid(dims: tuple[int, int, int] = MERL_DIMS) -> tuple[Array, Array, Array]:
    """Grid angles ``(theta_h, theta_d, phi_d)``, each of shape ``dims``, at the table's sample points."""
    nh, nd, npd = dims
    th = (np.arange(nh) / nh) ** 2 * _HALF_PI
    td = np.arange(nd) / nd * _HALF_PI
    pd = np.arange(npd) / npd * np.pi
    return tuple(jnp.asarray(a) for a in np.meshgrid(th, td, pd, indexing="ij"))  # type: ignore[return-value]


@eqx.filter_jit
def _tabulate(brdf: BRDF, th: Array, td: Array, pd: Array) -> Array:
    wi, wo = from_half_diff(th, td, pd)
    return brdf(wi, wo)


def tabulate_merl(brdf: BRDF, dims: tuple[int, int, int] = MERL_DIMS) -> np.ndarray:
    """Sample any BRDF on the MERL grid: a ``dims + (3,)`` float32 table for :func:`save_merl` / :func:`merl`.

    Grid point (i, j, k) is theta_h = (i / N_h)^2 pi/2, theta_d = j / N_d pi/2, phi_d = k / N_p pi,
    phi_h = 0. Configurations with wi or wo below the horizon get 0 (the BRDF's value there).
    """
    dims = tuple(int(d) for d in dims)
    if len(dims) != 3 or min(dims) < 2:
        raise HomofacError(f"brdf.dims must be three resolutions >= 2, got {dims}")
    th, td, pd = merl_grid(dims)  # type: ignore[arg-type]
    out = _tabulate(brdf, th, td, pd)
    return np.asarray(out, dtype=np.float32)
