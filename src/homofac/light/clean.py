"""Checks and cleaning of environment inputs: resolutions, colours, directions, bad pixels, boost.

Cleaning (recorded in ``info`` by the loaders): negative values are clamped to 0 (``clamped_negative``
counts the pixels with a negative channel). **NaN/Inf pixels are set to 0** (the whole pixel) with a
``warnings.warn`` that counts them (``nonfinite`` in ``info``): a corrupt pixel must not poison every
lighting sample, and refusing the whole map for a few bad pixels is unhelpful. An environment whose
total power is 0 raises :class:`~homofac.errors.HomofacError`.

Highlight boost (thesis §5.7), off by default: ``boost={"threshold": 0.9, "factor": 10}`` multiplies the
source pixels whose luminance exceeds ``threshold * max luminance`` by ``factor`` before resampling.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from pydantic import ConfigDict, TypeAdapter, ValidationError

from ..errors import HomofacError
from ..options import format_error, validate
from .environment import luminance
from .options import BoostOptions, Resolution


def label(source: Any) -> str:
    return str(source)


_RESOLUTION = TypeAdapter(Resolution, config=ConfigDict(strict=True))


def check_resolution(resolution: Any, source: str) -> int:
    """A cube face size within the limits of :data:`homofac.light.options.Resolution`."""
    if isinstance(resolution, np.integer):
        resolution = int(resolution)
    try:
        return int(_RESOLUTION.validate_python(resolution))
    except ValidationError as e:
        raise HomofacError(f"{source}: resolution (cube face size): {format_error(e, '')}") from None


def check_rgb(value: Any, what: str, source: str, *, allow_negative: bool = False) -> np.ndarray:
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


def check_direction(value: Any, what: str, source: str) -> np.ndarray:
    try:
        a = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise HomofacError(f"{source}: {what} must be [x, y, z], got {value!r}") from None
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.linalg.norm(a) < 1e-12:
        raise HomofacError(f"{source}: {what} must be a non-zero finite [x, y, z], got {value!r}")
    return a / np.linalg.norm(a)


def clean(img: np.ndarray, source: str) -> tuple[np.ndarray, int, int]:
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


def apply_boost(img: np.ndarray, boost: Any, source: str) -> tuple[np.ndarray, dict | None]:
    """Thesis §5.7 highlight boost on a cleaned source map (on a copy); ``boost`` as :class:`BoostOptions`."""
    if boost is None or boost is False:
        return img, None
    opts = validate(BoostOptions, boost, f"{source}: boost")
    lum = luminance(img)
    mask = lum > opts.threshold * lum.max()
    out = img.copy()
    out[mask] *= opts.factor
    return out, {"threshold": opts.threshold, "factor": opts.factor, "pixels": int(mask.sum())}


def check_power(radiance: np.ndarray, solid_angle: np.ndarray, source: str) -> None:
    if not np.any(radiance * solid_angle[:, None] > 0):
        raise HomofacError(f"{source}: environment is all zero: nothing to light with")


__all__ = ["apply_boost", "check_power", "check_resolution", "check_direction", "check_rgb", "clean", "label"]
