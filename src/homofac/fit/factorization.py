"""The result of a factorization and its evaluation as a GPU computes it.

``value(a, b) = correction * prod_j bilinear(t_k(j), mapper(pi_j(a, b)))`` on the *linear* textures
(DESIGN.md, factorization.json), which is what a renderer multiplies together per pixel.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..param import mappers
from ..param import parametrizations as pz


def evaluate_textures(
    parametrization: str,
    mapper: str,
    textures,
    correction: Float[Array, "3"],
    a: Float[Array, "N 3"],
    b: Float[Array, "N 3"],
    context: dict | None = None,
) -> Float[Array, "N 3"]:
    """Pure, differentiable evaluation of eq. 45 on linear textures with bilinear lookups."""
    p = pz.get(parametrization)
    m = mappers.get(mapper)
    out = jnp.broadcast_to(jnp.asarray(correction, a.dtype), a.shape[:-1] + (3,))
    for f, d in zip(p.factors, pz.project(p, a, b, context or {})):
        out = out * mappers.lookup(m, textures[f.texture], d)
    return out


_evaluate_jit = eqx.filter_jit(evaluate_textures)


def evaluate_rgba8(
    parametrization: str,
    mapper: str,
    rgba,
    colour_scale: Float[Array, "3"],
    a: Float[Array, "N 3"],
    b: Float[Array, "N 3"],
    context: dict | None = None,
) -> Float[Array, "N 3"]:
    """The decode rule of 8-bit RGBA textures (thesis eq. 50, :mod:`homofac.fit.precision`).

    ``rgba``: per texture the ``(H, W, 4)`` channel values ``code / 255``. Each of the four channels is
    interpolated bilinearly (as texture units do), then ``colour * scale * prod_j rgb_j * prod_j alpha_j``.
    """
    p = pz.get(parametrization)
    m = mappers.get(mapper)
    out = jnp.broadcast_to(jnp.asarray(colour_scale, a.dtype), a.shape[:-1] + (3,))
    for f, d in zip(p.factors, pz.project(p, a, b, context or {})):
        v = mappers.lookup(m, rgba[f.texture], d)
        out = out * v[..., :3] * v[..., 3:4]
    return out


_evaluate_rgba8_jit = eqx.filter_jit(evaluate_rgba8)


@dataclasses.dataclass(frozen=True)
class Factorization:
    """Textures, correction colour and the record of how they were made.

    Attributes:
        kind: ``brdf`` or ``lighting``.
        parametrization: registry name (``PQP``, ``NR`` ...).
        mapper: direction mapper of every texture.
        texture_size: S of the mapper table.
        textures: linear float textures (H, W, 3), each channel normalized to a maximum of 1.
        correction: RGB correction colour; value = correction * product of texture lookups.
        context: projection context (``dominant`` light direction for NRHD).
        quantity: ``brdf``, ``brdf_cos`` or ``lighting``: what the product approximates.
        metrics: {train, validation} x {float, quantized} -> pinned metric dict.
        solver: method, iterations, converged, residual, objective.
        timings: sample_s, solve_s, total_s (and compile/aux entries).
        counts: train, validation, lights.
        config: the full resolved configuration (for factorization.json).
        target_info: description of the target (model and parameters, environment provenance).
        selection: with ``target_error``, the candidates tried and why this one was chosen.
    """

    kind: str
    parametrization: str
    mapper: str
    texture_size: int
    textures: tuple
    correction: Any
    context: dict = dataclasses.field(default_factory=dict)
    quantity: str = "brdf"
    metrics: dict = dataclasses.field(default_factory=dict)
    solver: dict = dataclasses.field(default_factory=dict)
    timings: dict = dataclasses.field(default_factory=dict)
    counts: dict = dataclasses.field(default_factory=dict)
    config: dict = dataclasses.field(default_factory=dict)
    target_info: dict = dataclasses.field(default_factory=dict)
    warnings: tuple = ()
    samples: Any = None  # the Samples used, when kept (written as samples.npz)
    encoding: dict = dataclasses.field(default_factory=dict)  # encode_rgba8 options: weights, alpha
    rgba8: Any = None  # precision.Encoded8 as stored (PNG files); None: encoded from ``textures``
    source: str = "float"  # "png" when loaded from the 8-bit textures only: evaluate() decodes them
    selection: dict | None = None  # target_error: the candidates tried and why this one (fit/auto.py)

    @property
    def texture_names(self) -> tuple[str, ...]:
        return pz.get(self.parametrization).textures

    def encoded(self):
        """The 8-bit RGBA textures and decode constants (:class:`~homofac.fit.precision.Encoded8`).

        The stored ones when loaded from PNG files, else :func:`~homofac.fit.precision.encode_rgba8` of
        the float textures with the options in ``encoding`` (``weights``: thesis §4.3.1 prescale
        weights; ``alpha``: the §4.3.2 alpha trick, default on).
        """
        from .precision import encode_rgba8

        if self.rgba8 is not None:
            return self.rgba8
        return encode_rgba8(pz.get(self.parametrization), self.textures, self.correction, **self.encoding)

    def evaluate(self, a, b, *, quantized: bool | None = None) -> Float[Array, "N 3"]:
        """Factorized values at direction pairs (a, b): (wi, wo) for BRDFs, (n, v) for lighting.

        ``quantized=True`` evaluates the 8-bit RGBA textures with their decode rule (thesis eq. 50, the
        textures a PNG stores, see :meth:`encoded`); ``False`` the float textures (eq. 45). The default
        is the float path, or the 8-bit one for a result loaded with ``textures="png"``.
        """
        if quantized is None:
            quantized = self.source == "png"
        a = jnp.asarray(a, jnp.asarray(self.textures[0]).dtype)
        b = jnp.asarray(b, a.dtype)
        if quantized:
            from .precision import decode_rgba8

            enc = self.encoded()
            rgba = tuple(jnp.asarray(decode_rgba8(q), a.dtype) for q in enc.rgba)
            cs = jnp.asarray(enc.colour * enc.scale, a.dtype)
            return _evaluate_rgba8_jit(self.parametrization, self.mapper, rgba, cs, a, b, self.context)
        return _evaluate_jit(self.parametrization, self.mapper, self.textures, jnp.asarray(self.correction), a, b, self.context)

    def __call__(self, a, b):
        return self.evaluate(a, b)

    def save(self, out_dir, **kwargs):
        """Write the pinned output directory (see :func:`homofac.io.output.save`)."""
        from ..io.output import save

        return save(self, out_dir, **kwargs)
