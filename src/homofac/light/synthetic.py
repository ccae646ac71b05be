"""Synthetic environments, evaluated analytically per cube texel (supersampled): uniform, sky, sun, lamps.

Useful for tests with known answers (a white Lambertian surface under ``uniform(1)`` gives exactly 1;
the irradiance of ``gradient_sky(a, b)`` is ``pi (a + 2/3 b n_z)``) and for scenes without a captured
map (a sun over a sky, painted area lights of thesis §5.7).
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np

from ..errors import HomofacError
from ..param import mappers
from .clean import check_direction, check_resolution, check_rgb
from .cubemap import aggregate, cube_texels, finish, supersampled_means
from .environment import Environment
from .resample import MAX_SUPERSAMPLE


_SYNTH_K = 4


def _synthetic(fn: Callable[[np.ndarray], np.ndarray], r: int, info: dict, lights: Sequence[dict] = ()) -> Environment:
    rad = supersampled_means(fn, r, _SYNTH_K)
    info = {"kind": "synthetic", "clamped_negative": 0, "nonfinite": 0, "boost": None, "supersample": _SYNTH_K, **info}
    return finish(rad, r, info, lights, None)


def uniform(value=1.0, resolution: int = 32, *, lights: Sequence[dict] = ()) -> Environment:
    """Constant radiance ``value`` (scalar or RGB) in every direction; total power ``4 pi value``."""
    r = check_resolution(resolution, "uniform")
    c = check_rgb(value, "value", "uniform")
    # exact: every texel mean is the constant
    d, _ = cube_texels(r)
    rad = np.broadcast_to(c, (d.shape[0], 3)).copy()
    info = {"source": "uniform", "kind": "synthetic", "value": c.tolist(), "clamped_negative": 0, "nonfinite": 0, "boost": None}
    return finish(rad, r, info, lights, None)


def gradient_sky(a=1.0, b=0.0, resolution: int = 32, *, lights: Sequence[dict] = ()) -> Environment:
    """``L(theta) = a + b cos(theta)`` (scalar or RGB ``a``, ``b``), clamped at 0.

    The irradiance at a normal n is ``pi (a + (2/3) b n_z)`` while ``a >= |b|`` (no clamping).
    """
    r = check_resolution(resolution, "gradient_sky")
    ca = check_rgb(a, "a", "gradient_sky", allow_negative=True)
    cb = check_rgb(b, "b", "gradient_sky", allow_negative=True)

    def fn(d):
        return np.maximum(ca[None, :] + cb[None, :] * d[:, 2:3], 0.0)

    return _synthetic(fn, r, {"source": "gradient_sky", "a": ca.tolist(), "b": cb.tolist()}, lights)


def _add_disc(rad: np.ndarray, r: int, centre: np.ndarray, alpha: float, colour: np.ndarray) -> None:
    """Add a disc light (angular radius ``alpha`` rad, radiance ``colour``) with its exact power.

    Power ``colour * 2 pi (1 - cos alpha)`` is spread over the texels in proportion to the covered
    solid angle (sub-point coverage); a disc smaller than the sub-point spacing is splatted onto the
    four nearest texels with the cube mapper's bilinear weights.
    """
    _, w = cube_texels(r)
    power = colour * (2.0 * np.pi * (1.0 - np.cos(alpha)))
    k_need = math.ceil(4.0 / (r * max(alpha, 1e-12)))
    cov = None
    if k_need <= MAX_SUPERSAMPLE:
        k = max(_SYNTH_K, k_need)
        ds, ws = cube_texels(r * k)
        inside = ds @ centre >= np.cos(alpha)
        if inside.any():
            cov = aggregate((ws * inside)[:, None], r, k)[:, 0]
    if cov is not None and cov.sum() > 0:
        rad += (cov / cov.sum() / w)[:, None] * power[None, :]
    else:
        idx, wt = mappers.bilinear("cube", centre[None, :], r)
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
    r = check_resolution(resolution, "sun_sky")
    c = check_direction(sun_direction, "sun_direction", "sun_sky")
    lsun = check_rgb(sun_radiance, "sun_radiance", "sun_sky")
    a = check_rgb(sky, "sky", "sun_sky")
    b = check_rgb(sky_gradient, "sky_gradient", "sun_sky", allow_negative=True)
    try:
        ang = float(sun_angle_deg)
    except (TypeError, ValueError):
        raise HomofacError(f"sun_sky: sun_angle_deg must be a number, got {sun_angle_deg!r}") from None
    if not (0.0 < ang < 180.0):
        raise HomofacError(f"sun_sky: sun_angle_deg must be in (0, 180), got {ang}")
    rad = supersampled_means(lambda d: np.maximum(a[None, :] + b[None, :] * d[:, 2:3], 0.0), r, _SYNTH_K)
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
    return finish(rad, r, info, lights, None)


def painted_lights(
    lights_list: Sequence[tuple],
    resolution: int = 32,
    *,
    background=0.0,
    lights: Sequence[dict] = (),
) -> Environment:
    """Painted area lights (thesis §5.7): discs ``(direction, angular_radius_deg, rgb radiance)`` over a
    constant ``background`` radiance; each disc's power is exact (see :func:`sun_sky`)."""
    r = check_resolution(resolution, "painted_lights")
    bg = check_rgb(background, "background", "painted_lights")
    d, _ = cube_texels(r)
    rad = np.broadcast_to(bg, (d.shape[0], 3)).copy()
    desc = []
    for i, item in enumerate(lights_list):
        try:
            direction, radius_deg, colour = item
        except (TypeError, ValueError):
            raise HomofacError(f"painted_lights: light {i} must be (direction, angular_radius_deg, rgb), got {item!r}") from None
        c = check_direction(direction, f"light {i} direction", "painted_lights")
        col = check_rgb(colour, f"light {i} colour", "painted_lights")
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
    return finish(rad, r, info, lights, None)


__all__ = ["gradient_sky", "painted_lights", "sun_sky", "uniform"]
