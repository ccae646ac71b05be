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
* :func:`encode` chains prescale, split, alpha and 8-bit rounding into the textures an RGBA8 PNG
  stores (:class:`~homofac.factorization.Quantized`, with the pinned decode rule of
  :mod:`homofac.factorization`), and :func:`quantize` is the plain 8-bit rounding of normalized
  textures (no alpha, no prescale).

For one product the decode rule is the thesis' (eq. 50; a GPU's texture units interpolate each RGBA
channel, the shader multiplies)::

    value(a, b) = colour * scale * prod_j rgb_k(j)(d_j) * prod_j alpha_k(j)(d_j)
    rgb = R/255, G/255, B/255;  alpha = A/255   (linear values, no sRGB transfer)

where ``rgb(d)`` and ``alpha(d)`` are bilinear lookups (thesis eq. 33-34) of the four channels.
"""

from __future__ import annotations

import functools
from typing import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, UInt8

from ..compiling import jit
from ..errors import HomofacError
from ..factorization import Factorization, Quantized, Term
from ..param import mappers

__all__ = [
    "LEVELS", "alpha_split", "decode_rgba8", "encode", "exponentiate", "normalize", "prescale", "prescale_factors",
    "quantize", "split_correction", "texture_uses",
]

#: Largest 8-bit code: a channel value v is stored as round(v * 255).
LEVELS = 255.0


def exponentiate(x_textures: list, alpha, n_factors: int) -> list:
    """Linear textures ``exp(x_k) alpha^(1/J)`` from log textures (eq. 27 with the alpha^(1/J) split)."""
    s = jnp.asarray(alpha) ** (1.0 / n_factors)
    return [jnp.exp(x) * s for x in x_textures]


def normalize(model: Factorization) -> Factorization:
    """Scale each texture channel to a maximum |value| of 1 over its valid texels and move the scale into
    the corrections of the terms that read it (thesis §4.3, step 7): the evaluated sum is unchanged.

    Invalid texels (outside :func:`~homofac.param.mappers.valid_mask`) are filled with their nearest valid
    texel ("dilated"), so a GPU's hardware bilinear filter reads the same values as the pinned lookup.
    One compiled program per texture mapper and size (:func:`_normalized`), shared by every model with such
    a texture (a chooser's candidates), and traceable: a library's fits call it under ``vmap``.
    """
    data, scale = [], {}
    for t in model.textures:
        d, mx = _normalized(jnp.asarray(t.data), mapper=t.mapper, size=t.size)
        data.append(d)
        scale[t.name] = mx
    terms = []
    for term in model.terms:
        c = jnp.asarray(term.correction)
        for f in term.factors:
            c = c * scale[f.texture]
        terms.append(Term(term.factors, c, term.kind))
    out = model.replace_data(data)
    return eqx.tree_at(lambda m: m.terms, out, tuple(terms))


@jit(kind="lookup", static_argnames=("mapper", "size"))
def _normalized(d, *, mapper: str, size: int):
    """A texture divided by its largest |value| over the valid texels per channel (1 where that is 0), dilated
    (:func:`~homofac.param.mappers.dilate`), and that largest value: :func:`normalize`'s step per texture."""
    valid = jnp.asarray(mappers.valid_mask(mapper, size))[..., None]
    mx = jnp.max(jnp.where(valid, jnp.abs(d), 0.0).reshape(-1, d.shape[-1]), axis=0)
    mx = jnp.where(mx > 0, mx, 1.0)
    return mappers.dilate(mapper, size, d / mx), mx


def quantize(textures: list, bits: int = 8) -> list:
    """Round textures in [0, 1] to ``bits`` bits per channel (unsigned normalized integers).

    The naive conversion of thesis §4.3 (no prescale, no alpha); :func:`encode_rgba8` is the real one.
    """
    q = float(2**bits - 1)
    return [jnp.round(jnp.clip(t, 0.0, 1.0) * q) / q for t in textures]


def texture_uses(model: Factorization) -> tuple[int, ...]:
    """f(k) of thesis §4.3.1: how many factors read texture k (PQP: (2, 1)), in texture order."""
    return tuple(model.uses(t.name) for t in model.textures)


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
    uses: Sequence[int],
    textures: Sequence[Float[Array, "H W 3"]],
    correction: Float[Array, "3"],
    weights: Sequence[float] | None = None,
) -> tuple[list, Float[np.ndarray, "3"], Float[np.ndarray, "T+1"]]:
    """Apply thesis eq. 48: ``(s_0 c) prod_j (s_k(j) t_k(j))``; returns (textures, correction, s).

    ``uses`` is f(k) per texture (:func:`texture_uses`). Without weights (or all equal) every ``s_i`` is
    1. Prescaled textures may exceed 1; the 8-bit encoding clamps them (the thesis' compromise between
    clamped highlights and dark-value precision).
    """
    s = np.ones(len(uses) + 1) if weights is None else prescale_factors(weights, uses)
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


def _positive(model: Factorization) -> bool:
    return all(float(jnp.min(t.data)) >= 0 for t in model.textures)


def encode(model: Factorization, *, weights: Sequence[float] | None = None, alpha: bool = True) -> Quantized:
    """The model's 8-bit RGBA textures and their decode rule (:class:`~homofac.factorization.Quantized`).

    One term with non-negative textures (schema 1's single product): the thesis' encoding, §4.3: 1.
    prescale with ``weights`` (eq. 48; identity without weights), 2. split the correction into ``colour
    <= 1`` and a power-of-two ``scale`` (eq. 47), 3. with ``alpha``, split each texture into ``rgb * alpha``
    (eq. 57-58), 4. round to 8 bits. Alpha is rounded *up* first and the colour is recomputed from the
    rounded alpha (``rgb = t / alpha_8``), so the alpha's rounding error is carried into the colour
    channels instead of the product, and ``rgb <= 1`` stays true. Without ``alpha`` the A channel is
    255 and ``rgb`` the prescaled texture clamped to [0, 1]. The decode rule is then offset 0, scale 1,
    and the term's 8-bit correction ``colour * scale``.

    Several terms, or textures with negative texels (linear-space fits): per texture and channel the
    range [min, max] over its texels is mapped to 0 ... 255 (``offset = min`` when negative, else 0;
    ``scale = max - offset``), A is 255, and each term keeps its float correction. (The alpha split
    is not used there: interpolating rgb and alpha separately and multiplying them afterwards, as a
    GPU does, costs more than the split gains on textures normalized per channel.)
    """
    uses = texture_uses(model)
    data = [np.asarray(t.data, np.float64) for t in model.textures]
    if len(model.terms) == 1 and _positive(model):
        tex, corr, s = prescale(uses, data, model.terms[0].correction, weights)
        colour, z = split_correction(corr)
        rgba, clamped = [], []
        for t in tex:
            q, n = _rgba8(t, colour, z, alpha)
            rgba.append(q)
            clamped.append(n)
        rule = {"encoding": "rgba8", "transfer": "linear",
                "value": "colour * scale * prod_j (rgb_k(j) * alpha_k(j)), rgb = RGB/255, alpha = A/255, "
                         "each channel bilinearly interpolated before the products (thesis eq. 50)",
                "colour": [float(x) for x in colour], "scale": float(z),
                "prescale": [float(x) for x in s], "alpha": bool(alpha), "clamped": [int(x) for x in clamped]}
        ones = tuple(np.ones(3) for _ in tex)
        return Quantized(tuple(rgba), tuple(np.zeros(3) for _ in tex), ones, tuple(bool(alpha) for _ in tex),
                         (colour * z,), rule)
    if weights is not None:
        raise HomofacError("output.prescale applies to one-term factorizations with non-negative textures only")
    rgba, offs, scales, alphas = [], [], [], []
    for t in data:
        lo = np.min(t.reshape(-1, 3), axis=0)
        off = np.where(lo < 0, lo, 0.0)
        hi = np.max(t.reshape(-1, 3), axis=0)
        sc = np.where(hi - off > 0, hi - off, 1.0)
        use_alpha = False
        q, _ = _rgba8((t - off) / sc, np.ones(3), 1.0, use_alpha)
        rgba.append(q)
        offs.append(off)
        scales.append(sc)
        alphas.append(use_alpha)
    rule = {"encoding": "rgba8-affine", "transfer": "linear", "alpha": [bool(a) for a in alphas],
            "value": "sum_terms png_correction * prod_factors (offset + scale * rgb * (alpha if alpha)), "
                     "rgb = RGB/255, alpha = A/255, each channel bilinearly interpolated first"}
    return Quantized(tuple(rgba), tuple(offs), tuple(scales), tuple(alphas),
                     tuple(np.asarray(term.correction, np.float64) for term in model.terms), rule)


def _rgba8(t: np.ndarray, colour: np.ndarray, z: float, alpha: bool) -> tuple[np.ndarray, int]:
    """One texture in [0, 1] (clamped above, counted) as RGBA8, with or without the alpha split."""
    t = np.clip(t, 0.0, None)
    clamped = int(np.sum(t > 1.0))
    t = np.minimum(t, 1.0)
    if alpha:
        _, a = alpha_split(t, colour, z)
        a8 = np.ceil(a * LEVELS - 1e-9)  # ceil: rgb = t / a8 never exceeds 1
        a8 = np.where(np.max(t, axis=-1) > 0, np.maximum(a8, 1.0), 0.0)
        rgb = t * (LEVELS / np.where(a8 > 0, a8, 1.0))[..., None]
    else:
        a8 = np.full(t.shape[:-1], LEVELS)
        rgb = t
    rgb8 = np.round(np.clip(rgb, 0.0, 1.0) * LEVELS)
    return np.concatenate([rgb8, a8[..., None]], axis=-1).astype(np.uint8), clamped


def decode_rgba8(rgba: UInt8[np.ndarray, "H W 4"]) -> Float[np.ndarray, "H W 4"]:
    """Channel values of an 8-bit RGBA texture: ``code / 255`` (linear; float32)."""
    return np.asarray(rgba, np.float32) / np.float32(LEVELS)
