"""Texture range and precision: exponentiation, normalization, prescaling, alpha trick, 8-bit RGBA.

The steps follow the thesis' BRDFSeparator (§6.1.8, steps 5 and 7-10):

* :func:`exponentiate` undoes the log transform of eq. 26-27: each factor receives alpha^(1/J) so the
  product of the J factors carries alpha (thesis §3.1.2, end of "Basic Approach"); the tiny
  ``- eps alpha`` of eq. 27 is neglected as the thesis does.
* :func:`normalize` scales every texture channel to a maximum of 1 and moves the scale into a
  correction colour, so ``correction * prod_j t_k(j)`` is unchanged (thesis §4.3, Latta-Kolb §3.4).
* :func:`split_correction` splits the correction into a colour ``c <= 1`` and a power-of-two scale
  factor ``z`` (thesis eq. 47: ``c (n.l) p_i q_h p_o z``, ``z`` the texture-combiner scale).
* :func:`prescale_factors` / :func:`prescale` implement thesis §4.3.1 (eq. 48): weights ``w_0 .. w_T``
  become factors ``s_0 .. s_T`` with ``s_0 prod_k s_k^f(k) = 1`` that scale the correction and the
  textures, trading clamped highlights against 8-bit precision of the darker values.
* :func:`alpha_split` is the alpha-blending contouring prevention of thesis §4.3.2 (eq. 49-50, 57-58):
  ``t = rgb * alpha`` with ``alpha = clamp(max_c(t_c c_c z))``, so small values are carried by the
  alpha channel that the renderer multiplies in after the scale ``z``.
* :func:`encode_rgba8` chains prescale, split, alpha and 8-bit rounding into the textures an RGBA8
  PNG stores, :func:`decode_rgba8` is the decode rule (also written into factorization.json), and
  :func:`quantize` is the plain 8-bit rounding of normalized textures (no alpha, no prescale).

The decode rule of the 8-bit textures (a GPU's texture units interpolate each RGBA channel, the
shader multiplies; thesis eq. 50)::

    value(a, b) = colour * scale * prod_j rgb_k(j)(d_j) * prod_j alpha_k(j)(d_j)
    rgb = R/255, G/255, B/255;  alpha = A/255   (linear values, no sRGB transfer)

where ``rgb(d)`` and ``alpha(d)`` are bilinear lookups (thesis eq. 33-34) of the four channels.
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, UInt8

from ..errors import HomofacError
from ..param.parametrizations import Parametrization

__all__ = [
    "Encoded8", "alpha_split", "decode_rgba8", "encode_rgba8", "exponentiate", "normalize", "prescale",
    "prescale_factors", "quantize", "split_correction", "texel_values", "texture_uses", "LEVELS",
]

#: Largest 8-bit code: a channel value v is stored as round(v * 255).
LEVELS = 255.0


def exponentiate(x_textures: list, alpha, n_factors: int) -> list:
    """Linear textures ``exp(x_k) alpha^(1/J)`` from log textures (eq. 27 with the alpha^(1/J) split)."""
    s = jnp.asarray(alpha) ** (1.0 / n_factors)
    return [jnp.exp(x) * s for x in x_textures]


def normalize(param: Parametrization, textures: list, valid: np.ndarray | None = None):
    """Scale each texture channel to max 1; returns (textures, correction (3,)) (thesis §4.3, step 7).

    The correction colour is prod_j max(t_k(j)) per channel, so the evaluated product is unchanged.
    ``valid`` (H, W) restricts the maximum to texels that hold data.
    """
    out, corr = [], jnp.ones((3,), textures[0].dtype)
    for k, t in enumerate(textures):
        tv = t if valid is None else jnp.where(jnp.asarray(valid)[..., None], t, 0.0)
        mx = jnp.max(tv.reshape(-1, 3), axis=0)
        mx = jnp.where(mx > 0, mx, 1.0)
        out.append(tv / mx)
        corr = corr * mx ** len(param.uses(k))
    return out, corr


def quantize(textures: list, bits: int = 8) -> list:
    """Round textures in [0, 1] to ``bits`` bits per channel (unsigned normalized integers).

    The naive conversion of thesis §4.3 (no prescale, no alpha); :func:`encode_rgba8` is the real one.
    """
    q = float(2**bits - 1)
    return [jnp.round(jnp.clip(t, 0.0, 1.0) * q) / q for t in textures]


def texture_uses(param: Parametrization) -> tuple[int, ...]:
    """f(k) of thesis §4.3.1: how many factors read texture k (PQP: (2, 1))."""
    return tuple(len(param.uses(k)) for k in range(param.T))


def split_correction(correction: Float[np.ndarray, "3"]) -> tuple[Float[np.ndarray, "3"], float]:
    """Split a correction colour ``C`` into ``(c, z)``, ``C = c z``, ``max(c) <= 1`` (thesis eq. 47).

    ``z = 2^max(0, ceil(log2 max C))`` is a power of two >= 1 (the texture-combiner scale of §4.3,
    exactly representable); so ``max(c)`` lies in (1/2, 1] whenever ``max C > 1/2``.
    """
    c = np.asarray(correction, np.float64).reshape(3)
    if not np.all(np.isfinite(c)) or np.any(c < 0):
        raise HomofacError(f"correction colour must be finite and >= 0, got {c.tolist()}")
    m = float(np.max(c))
    e = int(np.ceil(np.log2(m))) if m > 0 else 0
    z = float(2.0 ** max(e, 0))
    colour = c / z
    if np.max(colour) > 1.0:  # log2 rounding at an exact power of two
        z *= 2.0
        colour = c / z
    return colour, z


def prescale_factors(weights: Sequence[float], uses: Sequence[int]) -> Float[np.ndarray, "T+1"]:
    """Prescale factors ``s_0 .. s_T`` from weights ``w_0 .. w_T`` (thesis §4.3.1, steps 1-3).

    ``a = w_0 prod_k w_k^f(k)``, ``s_0 = w_0 / a^(1/(T+1))``, ``s_k = w_k / a^(1/((T+1) f(k)))``, so that
    ``s_0 prod_k s_k^f(k) = 1`` (eq. 48: the rendered product is unchanged). ``uses`` is f(k) per
    texture (:func:`texture_uses`); index 0 of ``weights`` scales the correction colour.
    """
    w = np.asarray(weights, np.float64).reshape(-1)
    f = np.asarray(uses, np.float64).reshape(-1)
    T = f.shape[0]
    if w.shape[0] != T + 1:
        raise HomofacError(f"prescale needs {T + 1} weights (correction and {T} textures), got {w.shape[0]}")
    if not np.all(np.isfinite(w)) or np.any(w <= 0):
        raise HomofacError(f"prescale weights must be finite and > 0, got {w.tolist()}")
    if np.any(f < 1):
        raise HomofacError("prescale: every texture must be used by at least one factor")
    log_a = np.log(w[0]) + np.sum(f * np.log(w[1:]))  # logs: no overflow for extreme weights
    s0 = w[0] * np.exp(-log_a / (T + 1))
    sk = w[1:] * np.exp(-log_a / ((T + 1) * f))
    return np.concatenate([[s0], sk])


def prescale(
    param: Parametrization,
    textures: Sequence[Float[Array, "H W 3"]],
    correction: Float[Array, "3"],
    weights: Sequence[float] | None = None,
) -> tuple[list, Float[np.ndarray, "3"], Float[np.ndarray, "T+1"]]:
    """Apply thesis eq. 48: ``(s_0 c) prod_j (s_k(j) t_k(j))``; returns (textures, correction, s).

    Without weights (or all equal) every ``s_i`` is 1. Prescaled textures may exceed 1; the 8-bit
    encoding clamps them (the thesis' compromise between clamped highlights and dark-value precision).
    """
    f = texture_uses(param)
    s = np.ones(param.T + 1) if weights is None else prescale_factors(weights, f)
    out = [np.asarray(t, np.float64) * s[k + 1] for k, t in enumerate(textures)]
    return out, np.asarray(correction, np.float64) * s[0], s


def alpha_split(
    texture: Float[np.ndarray, "H W 3"],
    colour: Float[np.ndarray, "3"],
    scale: float,
) -> tuple[Float[np.ndarray, "H W 3"], Float[np.ndarray, "H W"]]:
    """Alpha-blending contouring prevention, thesis §4.3.2 eq. 57-58: ``texture = rgb * alpha``.

    ``alpha = clamp(max_c(t_c b_c))`` and ``rgb = t / alpha`` with the per-channel threshold
    ``b_c = max(c_c z, 1)``: exactly eq. 58 (``a = f c z``) whenever ``c_c z >= 1`` (the thesis' case,
    "usually c will be greater than one"); the ``max(., 1)`` keeps ``rgb <= 1`` for texels of channels
    whose ``c z`` is below 1, where eq. 58 would need clamping. Texels that are 0 get alpha 0.
    """
    t = np.clip(np.asarray(texture, np.float64), 0.0, None)
    b = np.maximum(np.asarray(colour, np.float64) * float(scale), 1.0)
    alpha = np.clip(np.max(t * b, axis=-1), 0.0, 1.0)
    safe = np.where(alpha > 0, alpha, 1.0)
    return t / safe[..., None], alpha


class Encoded8(NamedTuple):
    """8-bit RGBA textures and their decode rule (thesis §6.1.8 step 9, ``clampTextureRange``).

    Attributes:
        rgba: per texture an ``(H, W, 4)`` uint8 array (what the PNG files store).
        colour: correction colour ``c`` (3,), ``max <= 1`` (float; a vertex colour / uniform).
        scale: power-of-two scale factor ``z`` (eq. 47).
        prescale: ``s_0 .. s_T`` of thesis §4.3.1 (already applied to ``colour * scale`` and ``rgba``).
        alpha: whether the alpha channel carries the eq. 57-58 split (else it is 255 everywhere).
        clamped: per texture, how many texel channels were clamped to 1 (prescale > 1).
    """

    rgba: tuple
    colour: np.ndarray
    scale: float
    prescale: np.ndarray
    alpha: bool
    clamped: tuple = ()

    def decode_rule(self) -> dict:
        """The JSON-friendly decode rule written beside the PNG entries in factorization.json."""
        return {
            "encoding": "rgba8",
            "value": "colour * scale * prod_j (rgb_k(j) * alpha_k(j)), rgb = RGB/255, alpha = A/255, "
                     "each channel bilinearly interpolated before the products (thesis eq. 50)",
            "colour": [float(x) for x in self.colour],
            "scale": float(self.scale),
            "prescale": [float(x) for x in self.prescale],
            "alpha": bool(self.alpha),
            "transfer": "linear",
            "clamped": [int(x) for x in self.clamped],
        }


def encode_rgba8(
    param: Parametrization,
    textures: Sequence[Float[Array, "H W 3"]],
    correction: Float[Array, "3"],
    *,
    weights: Sequence[float] | None = None,
    alpha: bool = True,
) -> Encoded8:
    """Float textures -> 8-bit RGBA textures + decode constants (thesis §4.3, §4.3.1, §4.3.2).

    1. prescale with ``weights`` (eq. 48; identity without weights), 2. split the correction into
    ``colour <= 1`` and a power-of-two ``scale`` (eq. 47), 3. with ``alpha``, split each texture into
    ``rgb * alpha`` (eq. 57-58), 4. round to 8 bits. Alpha is rounded *up* first and the colour is
    recomputed from the rounded alpha (``rgb = t / alpha_8``), so the alpha's rounding error is carried
    into the colour channels instead of the product, and ``rgb <= 1`` stays true. Without ``alpha``
    the A channel is 255 and ``rgb`` is the prescaled texture clamped to [0, 1].
    """
    tex, corr, s = prescale(param, textures, correction, weights)
    colour, scale = split_correction(corr)
    out, clamped = [], []
    for t in tex:
        t = np.clip(t, 0.0, None)
        clamped.append(int(np.sum(t > 1.0)))
        t = np.minimum(t, 1.0)
        if alpha:
            _, a = alpha_split(t, colour, scale)
            a8 = np.ceil(a * LEVELS - 1e-9)  # ceil: rgb = t / a8 never exceeds 1
            a8 = np.where(np.max(t, axis=-1) > 0, np.maximum(a8, 1.0), 0.0)
            rgb = t * (LEVELS / np.where(a8 > 0, a8, 1.0))[..., None]
        else:
            a8 = np.full(t.shape[:-1], LEVELS)
            rgb = t
        rgb8 = np.round(np.clip(rgb, 0.0, 1.0) * LEVELS)
        out.append(np.concatenate([rgb8, a8[..., None]], axis=-1).astype(np.uint8))
    return Encoded8(tuple(out), colour, scale, s, bool(alpha), tuple(clamped))


def decode_rgba8(rgba: UInt8[np.ndarray, "H W 4"]) -> Float[np.ndarray, "H W 4"]:
    """Channel values of an 8-bit RGBA texture: ``code / 255`` (linear; float32)."""
    return np.asarray(rgba, np.float32) / np.float32(LEVELS)


def texel_values(enc: Encoded8) -> list:
    """Per-texel float textures ``rgb * alpha / s_k`` of an encoding (the correction is ``colour scale s_0``)."""
    out = []
    for k, q in enumerate(enc.rgba):
        d = decode_rgba8(q).astype(np.float64)
        out.append((d[..., :3] * d[..., 3:] / enc.prescale[k + 1]).astype(np.float32))
    return out
