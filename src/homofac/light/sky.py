"""An analytic daylight sky with a sun, for scenes without a captured map (time of day, issue 15).

:func:`preetham_sky` is the clear-sky model of Preetham, Shirley & Smits 1999 ("A practical analytic
model for daylight", SIGGRAPH 99): the Perez et al. 1993 distribution

    F(theta, gamma) = (1 + A e^(B / cos theta)) (1 + C e^(D gamma) + E cos^2 gamma)

(theta the zenith angle of the view, gamma its angle to the sun) for the luminance Y and the CIE
chromaticities x, y, each scaled so that its zenith value is the model's fit ``Y_z``, ``x_z``,
``y_z`` of turbidity T and the sun's zenith angle theta_s::

    Y(theta, gamma) = Y_z F(theta, gamma) / F(0, theta_s)

(coefficients A..E linear in T, tables 1-2 of the paper's appendix; Y in kcd/m^2). xyY is turned into
linear Rec. 709 RGB. Below the horizon the ground is Lambertian with ``ground_albedo`` under the sky's
and the sun's horizontal illuminance. The sun is a disc of 0.53 degrees whose illuminance outside the
atmosphere (``sun_illuminance``, 128 klx) is attenuated by ``exp(-tau m)`` per channel (Kasten-Young
air mass m; tau from Rayleigh plus a turbidity-scaled aerosol term), which reddens it near the
horizon. With the sun below the horizon the sky is the model at the horizon dimmed by a tenth per
2.5 degrees of depression (a twilight, not part of Preetham's model), over a night floor.

Every texel is the supersampled mean of the radiance over it and the sun's power is exact
(:mod:`homofac.light.synthetic`), so a moving sun moves its power continuously between texels.
:func:`sun_direction` gives the sun's direction for a time of day, latitude and day of the year
(+z up, +x east, +y north).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..errors import HomofacError
from .clean import check_direction, check_resolution
from .cubemap import cube_texels, finish, supersampled_means
from .environment import Environment
from .synthetic import _add_disc

#: Perez coefficients (A, B, C, D, E) of Y, x, y as ``slope * T + intercept`` (Preetham 1999, appendix).
PEREZ = {
    "Y": ((0.1787, -1.4630), (-0.3554, 0.4275), (-0.0227, 5.3251), (0.1206, -2.5771), (-0.0670, 0.3703)),
    "x": ((-0.0193, -0.2592), (-0.0665, 0.0008), (-0.0004, 0.2125), (-0.0641, -0.8989), (-0.0033, 0.0452)),
    "y": ((-0.0167, -0.2608), (-0.0950, 0.0092), (-0.0079, 0.2102), (-0.0441, -1.6537), (-0.0109, 0.0529)),
}
#: Zenith chromaticity polynomials (rows T^2, T, 1; columns theta_s^3, ^2, ^1, ^0), Preetham 1999 eq. A.2.
ZENITH_X = np.array([[0.00166, -0.00375, 0.00209, 0.0], [-0.02903, 0.06377, -0.03202, 0.00394],
                     [0.11693, -0.21196, 0.06052, 0.25886]])
ZENITH_Y = np.array([[0.00275, -0.00610, 0.00317, 0.0], [-0.04214, 0.08970, -0.04153, 0.00516],
                     [0.15346, -0.26756, 0.06670, 0.26688]])
#: CIE XYZ -> linear Rec. 709 RGB.
XYZ_TO_RGB = np.array([[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]])
#: Vertical optical depth per channel: Rayleigh (R, G, B) and aerosol (per unit of turbidity above 1).
RAYLEIGH = np.array([0.05, 0.10, 0.24])
AEROSOL = np.array([0.035, 0.040, 0.045])
#: The sun's angular diameter (degrees) and illuminance outside the atmosphere (klx: the sky's unit x sr).
SUN_ANGLE_DEG = 0.53
SUN_ILLUMINANCE = 128.0
#: Largest sun zenith angle the model is evaluated at (degrees); lower suns use the twilight rule.
MAX_SUN_ZENITH = 89.0


def _perez(coef, theta, gamma):
    a, b, c, d, e = coef
    cos_t = np.maximum(np.cos(theta), 1e-3)
    return (1.0 + a * np.exp(b / cos_t)) * (1.0 + c * np.exp(d * gamma) + e * np.cos(gamma) ** 2)


def _coefficients(turbidity: float) -> dict:
    return {k: tuple(s * turbidity + i for s, i in rows) for k, rows in PEREZ.items()}


def zenith(turbidity: float, theta_s: float) -> tuple[float, float, float]:
    """Zenith luminance Y_z (kcd/m^2) and chromaticity (x_z, y_z) (Preetham 1999 eq. A.1-A.2)."""
    t = turbidity
    chi = (4.0 / 9.0 - t / 120.0) * (math.pi - 2.0 * theta_s)
    y_z = (4.0453 * t - 4.9710) * math.tan(chi) - 0.2155 * t + 2.4192
    powers_t = np.array([t * t, t, 1.0])
    powers_s = np.array([theta_s ** 3, theta_s ** 2, theta_s, 1.0])
    return max(y_z, 0.0), float(powers_t @ ZENITH_X @ powers_s), float(powers_t @ ZENITH_Y @ powers_s)


def sky_rgb(d: np.ndarray, sun: np.ndarray, turbidity: float) -> np.ndarray:
    """Linear RGB radiance (kcd/m^2) of the Preetham sky at directions ``d`` (N, 3) above the horizon
    for a sun at ``sun`` (unit, its zenith angle at most :data:`MAX_SUN_ZENITH`)."""
    theta_s = math.acos(float(np.clip(sun[2], -1.0, 1.0)))
    theta = np.arccos(np.clip(d[:, 2], 0.0, 1.0))
    gamma = np.arccos(np.clip(d @ sun, -1.0, 1.0))
    coef = _coefficients(turbidity)
    y_z, x_z, yc_z = zenith(turbidity, theta_s)
    Y = y_z * _perez(coef["Y"], theta, gamma) / _perez(coef["Y"], 0.0, theta_s)
    x = x_z * _perez(coef["x"], theta, gamma) / _perez(coef["x"], 0.0, theta_s)
    y = yc_z * _perez(coef["y"], theta, gamma) / _perez(coef["y"], 0.0, theta_s)
    y = np.maximum(y, 1e-6)
    xyz = np.stack([x * Y / y, Y, (1.0 - x - y) * Y / y], axis=-1)
    return np.maximum(xyz @ XYZ_TO_RGB.T, 0.0)


def air_mass(zenith_deg: float) -> float:
    """Kasten & Young 1989: ``1 / (cos z + 0.50572 (96.07995 - z)^-1.6364)``."""
    z = min(float(zenith_deg), 90.0)
    return 1.0 / (math.cos(math.radians(z)) + 0.50572 * (96.07995 - z) ** -1.6364)


def sun_transmittance(zenith_deg: float, turbidity: float) -> np.ndarray:
    """RGB transmittance of the direct sun through the atmosphere: ``exp(-tau m)``."""
    tau = RAYLEIGH + AEROSOL * max(turbidity - 1.0, 0.0)
    return np.exp(-tau * air_mass(zenith_deg))


def sun_direction(hour: float, *, latitude: float = 45.0, day: int = 172, azimuth: float = 0.0) -> np.ndarray:
    """The direction to the sun (+z up, +x east, +y north) at solar ``hour`` (0-24, noon = 12) on day
    ``day`` of the year at ``latitude`` degrees, rotated by ``azimuth`` degrees about +z.

    Declination ``23.44 sin(2 pi (284 + day) / 365)`` degrees, hour angle ``15 (hour - 12)`` degrees.
    """
    dec = math.radians(23.44 * math.sin(2.0 * math.pi * (284 + day) / 365.0))
    h = math.radians(15.0 * (hour - 12.0))
    lat = math.radians(latitude)
    east = -math.cos(dec) * math.sin(h)
    north = math.sin(dec) * math.cos(lat) - math.cos(dec) * math.cos(h) * math.sin(lat)
    up = math.sin(dec) * math.sin(lat) + math.cos(dec) * math.cos(h) * math.cos(lat)
    a = math.radians(azimuth)
    v = np.array([east * math.cos(a) - north * math.sin(a), east * math.sin(a) + north * math.cos(a), up])
    return v / np.linalg.norm(v)


def preetham_sky(sun_direction=(0.3, 0.2, 0.9), *, turbidity: float = 3.0, resolution: int = 32,
                 ground_albedo: float = 0.2, sun: bool = True, night: float = 1e-3,
                 lights: Sequence[dict] = ()) -> Environment:
    """The Preetham 1999 daylight sky for a sun at ``sun_direction`` (see the module docstring), in
    kcd/m^2 (the sun disc's illuminance in klx), on cube texels of face size ``resolution``.

    ``turbidity`` in [1.7, 10] (2: very clear, 3: clear, 6: hazy); ``ground_albedo`` in [0, 1];
    ``sun`` adds the disc; ``night`` is the radiance floor of the sky (moon and stars).
    """
    r = check_resolution(resolution, "preetham_sky")
    s = check_direction(sun_direction, "sun_direction", "preetham_sky")
    if not (1.7 <= float(turbidity) <= 10.0):
        raise HomofacError(f"preetham_sky: turbidity must be in [1.7, 10], got {turbidity}")
    if not (0.0 <= float(ground_albedo) <= 1.0):
        raise HomofacError(f"preetham_sky: ground_albedo must be in [0, 1], got {ground_albedo}")
    if not (math.isfinite(night) and night >= 0):
        raise HomofacError(f"preetham_sky: night must be a finite number >= 0, got {night}")
    t = float(turbidity)
    zen = math.degrees(math.acos(float(np.clip(s[2], -1.0, 1.0))))
    # the sky of a sun at (or below) the horizon: the model at MAX_SUN_ZENITH, dimmed through twilight
    model_sun = s.copy()
    if zen > MAX_SUN_ZENITH:
        horiz = np.array([s[0], s[1], 0.0])
        horiz = horiz / max(np.linalg.norm(horiz), 1e-12) if np.linalg.norm(horiz) > 1e-9 else np.array([1.0, 0, 0])
        z = math.radians(MAX_SUN_ZENITH)
        model_sun = horiz * math.sin(z) + np.array([0.0, 0.0, math.cos(z)])
    dim = 10.0 ** (-(max(zen - MAX_SUN_ZENITH, 0.0)) / 2.5)

    def sky(d):
        out = np.zeros((d.shape[0], 3))
        up = d[:, 2] > 0
        out[up] = sky_rgb(d[up], model_sun, t) * dim + night
        return out

    rad = supersampled_means(sky, r, 4)
    d, w = cube_texels(r)
    e_sky = np.sum(rad * (np.maximum(d[:, 2], 0.0) * w)[:, None], axis=0)  # horizontal illuminance
    sun_rgb = SUN_ILLUMINANCE * sun_transmittance(zen, t) if sun and zen < 90.0 else np.zeros(3)
    e_ground = e_sky + sun_rgb * max(float(s[2]), 0.0)
    ground = float(ground_albedo) * e_ground / math.pi
    rad = rad + supersampled_means(lambda q: np.where(q[:, 2:3] < 0, ground[None, :], 0.0), r, 4)
    alpha = math.radians(SUN_ANGLE_DEG) / 2.0
    if np.any(sun_rgb > 0):
        _add_disc(rad, r, s, alpha, sun_rgb / (2.0 * math.pi * (1.0 - math.cos(alpha))))
    info = {"source": "preetham_sky", "kind": "synthetic", "sun_direction": s.tolist(), "sun_zenith_deg": zen,
            "turbidity": t, "ground_albedo": float(ground_albedo), "sun": bool(sun), "night": float(night),
            "sun_rgb": sun_rgb.tolist(),
            "clamped_negative": 0, "nonfinite": 0, "boost": None, "supersample": 4}
    return finish(rad, r, info, lights, None)


def time_of_day(hours: Sequence[float], *, resolution: int = 16, latitude: float = 45.0, day: int = 172,
                azimuth: float = 0.0, turbidity: float = 3.0, **kwargs) -> list[Environment]:
    """One :func:`preetham_sky` per solar hour (a moving sun); all on the same light texels."""
    return [preetham_sky(sun_direction(h, latitude=latitude, day=day, azimuth=azimuth), turbidity=turbidity,
                         resolution=resolution, **kwargs) for h in hours]


__all__ = ["PEREZ", "air_mass", "preetham_sky", "sky_rgb", "sun_direction", "sun_transmittance", "time_of_day",
           "zenith"]
