"""Spherical harmonics of irradiance: the 9 RGB coefficients of Ramamoorthi & Hanrahan (2001).

Real SH basis (no Condon-Shortley phase), in homofac's +z-up world frame, in the order
``Y00, Y1-1, Y10, Y11, Y2-2, Y2-1, Y20, Y21, Y22``::

    Y00 = 0.282095                 Y1-1 = 0.488603 y     Y10 = 0.488603 z      Y11 = 0.488603 x
    Y2-2 = 1.092548 x y            Y2-1 = 1.092548 y z   Y20 = 0.315392 (3 z^2 - 1)
    Y21 = 1.092548 x z             Y22 = 0.546274 (x^2 - y^2)

The environment's projection ``L_lm = sum_k L_k Y_lm(l_k) dw_k`` (the pinned light sum; texel centres)
convolved with the clamped cosine (R-H eq. 7-8: ``A_0 = pi, A_1 = 2 pi / 3, A_2 = pi / 4``) gives the
coefficients ``c_lm = A_l L_lm`` of the irradiance

    E(n) = sum_i c_i Y_i(n),        E of a constant radiance L is pi L (not divided by pi).

Files (:meth:`SH9.save_json`, :meth:`SH9.save_filament`):

* ``sh9.json`` (pinned ``{"irradiance": [[r, g, b] x 9]}``: the c_i above), with additive keys ``basis``,
  ``frame`` and ``error`` (SH9 against the exact irradiance of :func:`homofac.light.irradiance` over the
  sphere: ``nrmse`` per channel then averaged, weighted by solid angle, and the largest error relative
  to the mean irradiance, on the texel centres of a cube of face ``error_size``).
* Filament's ``sh.txt`` (cmgen ``--sh-shader``/``--deploy``): 9 lines ``(r, g, b); // L00, irradiance,
  pre-scaled base`` in the same l, m order, pre-scaled for the polynomial form Filament's shader evaluates
  (``Irradiance_SphericalHarmonics``)::

      E(n)/pi = s0 + s1 y + s2 z + s3 x + s4 y x + s5 y z + s6 (3 z^2 - 1) + s7 z x + s8 (x^2 - y^2)

  in Filament's right-handed **y-up** world: the engine direction ``(x, y, z)_e`` is homofac's
  ``(x_e, -z_e, y_e)`` (the ``HOMOFAC_Y_UP`` convention of the shaders), i.e. homofac's ``(x, y, z)`` is
  ``(x, z, -y)`` there. Filament's Lambertian diffuse multiplies this by the diffuse colour (its 1/pi is
  included). cmgen also windows the SH (``--sh-window``, auto by default) and mirrors the cube map it
  builds from a lat-long image; this file does neither: it is the exact projection of the environment
  homofac lit, rotated into the y-up frame.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from jaxtyping import Float

from ..io.files import write_atomically
from ..param import mappers
from .environment import Environment
from .lighting import irradiance as exact_irradiance

#: Constants of the 9 real basis functions (the polynomials below times these give Y_i): 1/(2 sqrt(pi)),
#: sqrt(3/(4 pi)), sqrt(15/(4 pi)), sqrt(5/(16 pi)), sqrt(15/(16 pi)) (0.282095, 0.488603, 1.092548, 0.315392, 0.546274).
SH9_NORM = np.sqrt(np.array([1 / 4, 3 / 4, 3 / 4, 3 / 4, 15 / 4, 15 / 4, 5 / 16, 15 / 4, 15 / 16]) / np.pi)
#: Convolution factors of the clamped cosine per coefficient (R-H 2001: pi, 2 pi / 3, pi / 4).
SH9_COSINE = np.array([np.pi] + [2 * np.pi / 3] * 3 + [np.pi / 4] * 5)
#: Names in the pinned order (Filament's ``L{l}{m}`` labels).
SH9_NAMES = ("L00", "L1-1", "L10", "L11", "L2-2", "L2-1", "L20", "L21", "L22")


def sh9_polynomials(d: Float[np.ndarray, "N 3"]) -> Float[np.ndarray, "N 9"]:
    """The 9 polynomials ``1, y, z, x, x y, y z, 3 z^2 - 1, x z, x^2 - y^2`` at directions ``d`` (N, 3)."""
    d = np.asarray(d, np.float64)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return np.stack([np.ones_like(x), y, z, x, x * y, y * z, 3 * z * z - 1, x * z, x * x - y * y], axis=-1)


def sh9_basis(d: Float[np.ndarray, "N 3"]) -> Float[np.ndarray, "N 9"]:
    """The 9 real SH basis functions Y_i at unit directions ``d`` (N, 3) -> (N, 9), in the pinned order."""
    return sh9_polynomials(d) * SH9_NORM


def sh9_coefficients(env: Environment) -> Float[np.ndarray, "9 3"]:
    """Irradiance coefficients ``c_i = A_l sum_k L_k Y_i(l_k) dw_k`` of ``env`` (float64, (9, 3))."""
    ld = np.asarray(env.directions, np.float64)
    power = np.asarray(env.radiance, np.float64) * np.asarray(env.solid_angle, np.float64)[:, None]
    return SH9_COSINE[:, None] * (sh9_basis(ld).T @ power)


def sh9_irradiance(env: Environment, dirs: Float[np.ndarray, "N 3"]) -> Float[np.ndarray, "N 3"]:
    """E(n) at ``dirs`` from the environment's 9 SH coefficients (R-H 2001 eq. 8), (N, 3) float64."""
    return sh9_basis(np.asarray(dirs, np.float64)) @ sh9_coefficients(env)


# homofac (x, y, z) -> a right-handed y-up engine's (x, z, -y) (docs/conventions.md, HOMOFAC_Y_UP)
_TO_Y_UP = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])


def filament_coefficients(c: Float[np.ndarray, "9 3"]) -> Float[np.ndarray, "9 3"]:
    """Filament's pre-scaled coefficients ``s`` (module docstring) of the irradiance ``E = sum c_i Y_i``.

    E/pi is a band-2 function; in the engine frame it is again one (rotations keep bands), so ``s`` solves
    ``sum_k s_k P_k(M n) = E(n)/pi`` exactly; it is found by least squares on 26 directions (exact up to
    rounding: the 9 polynomials are independent on them).
    """
    g = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if (i, j, k) != (0, 0, 0)], float)
    n = g / np.linalg.norm(g, axis=1, keepdims=True)
    e = sh9_basis(n) @ np.asarray(c, np.float64) / np.pi
    s, *_ = np.linalg.lstsq(sh9_polynomials(n @ _TO_Y_UP.T), e, rcond=None)
    return s


def sh9_error(c: Float[np.ndarray, "9 3"], env: Environment, size: int = 16) -> dict:
    """SH9's irradiance against the exact one on a cube of face ``size`` (solid-angle weights):
    ``nrmse`` (per channel, then the mean over RGB) and ``max_rel`` (largest |error| / mean exact E)."""
    n = mappers.texel_directions("cube", size).reshape(-1, 3).astype(np.float64)
    w = mappers.texel_solid_angles("cube", size).reshape(-1).astype(np.float64)[:, None]
    exact = np.asarray(exact_irradiance(env, n.astype(np.float32)), np.float64)
    approx = sh9_basis(n) @ c
    err = approx - exact
    nrmse = np.sqrt((w * err**2).sum(0)) / np.maximum(np.sqrt((w * exact**2).sum(0)), 1e-300)
    mean = (w * exact).sum(0) / w.sum()
    max_rel = np.abs(err).max(0) / np.maximum(mean, 1e-300)
    return {"nrmse": float(nrmse.mean()), "nrmse_rgb": nrmse.tolist(), "max_rel": float(max_rel.max()),
            "directions": int(n.shape[0]), "grid": f"cube texel centres, face {size}"}


@dataclass(frozen=True)
class SH9:
    """The 9 RGB irradiance coefficients of an environment and their error (see the module docstring).

    Attributes:
        coefficients: (9, 3) float64, ``E(n) = sum_i c_i Y_i(n)`` in the pinned order and frame.
        error: SH9 against the exact irradiance (:func:`sh9_error`), or an empty dict when not measured.
    """

    coefficients: np.ndarray
    error: dict = field(default_factory=dict)

    def irradiance(self, n: Float[np.ndarray, "N 3"]) -> Float[np.ndarray, "N 3"]:
        """E(n) at unit normals ``n`` (N, 3) (+z-up world frame), not divided by pi."""
        return sh9_basis(n) @ self.coefficients

    def filament(self) -> np.ndarray:
        """Filament's pre-scaled, y-up coefficients (9, 3) (:func:`filament_coefficients`)."""
        return filament_coefficients(self.coefficients)

    def document(self) -> dict:
        """The content of ``sh9.json``: the pinned ``irradiance`` and the additive keys."""
        return {"irradiance": [[float(x) for x in row] for row in self.coefficients],
                "basis": "real SH, order " + ", ".join(SH9_NAMES) + "; E(n) = sum c_i Y_i(n), not divided by pi",
                "frame": "homofac world, right-handed, +z up", "error": self.error}

    def save_json(self, path: str | os.PathLike) -> Path:
        """Write ``sh9.json`` atomically; returns its path."""
        text = json.dumps(self.document(), indent=1) + "\n"
        return write_atomically(path, "JSON", lambda tmp: Path(tmp).write_text(text))

    def filament_text(self) -> str:
        """Filament's ``sh.txt`` (cmgen's ``outputSh`` layout: 15 decimals, width 18)."""
        s = self.filament()
        return "".join(f"({r:18.15f}, {g:18.15f}, {b:18.15f}); // {name}, irradiance, pre-scaled base\n"
                       for (r, g, b), name in zip(s, SH9_NAMES))

    def save_filament(self, path: str | os.PathLike) -> Path:
        """Write Filament's ``sh.txt`` atomically; returns its path."""
        text = self.filament_text()
        return write_atomically(path, "SH text", lambda tmp: Path(tmp).write_text(text))


def sh9(env: Environment, *, error_size: int | None = 16) -> SH9:
    """The SH9 irradiance of ``env`` with its error against the exact irradiance (``error_size=None``: not
    measured)."""
    c = sh9_coefficients(env)
    return SH9(c, sh9_error(c, env, error_size) if error_size else {})


__all__ = ["SH9", "SH9_COSINE", "SH9_NAMES", "SH9_NORM", "filament_coefficients", "sh9", "sh9_basis",
           "sh9_coefficients", "sh9_error", "sh9_irradiance", "sh9_polynomials"]
