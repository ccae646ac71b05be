"""The run record of a fit: the model (a pytree) and how it was made (config, metrics, timings, ...).

:class:`Result` is what :func:`homofac.fit.factorize` returns and what the output directory stores:

* ``model``: the :class:`~homofac.factorization.Factorization` (schema 2: textures and terms), the
  only part a renderer needs, and the only part that is a JAX pytree;
* the record: ``metrics`` {train, validation} x {float, quantized}, ``solver``, ``timings``, ``counts``,
  the resolved ``config``, ``target_info``, ``warnings``, ``selection`` (target_error), and optionally
  the ``samples`` and the refit ``state`` (:mod:`homofac.fit.refit`).

It also offers the conveniences a notebook wants: ``fac.evaluate(n, v)``, ``fac.metrics``,
``fac.shader("glsl")``, ``fac.save("out/")``, and schema 1's single-product view (``parametrization``,
``mapper``, ``texture_size``, ``textures``, ``correction``). Saving belongs to the output layer above
this one: :mod:`homofac.output` registers itself as the writer (:func:`register_writer`), so this
module never imports it.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import jax.numpy as jnp
from jaxtyping import Array, Float

from ..errors import HomofacError
from ..factorization import Factorization, Quantized, evaluate_quantized
from ..param import mappers
from ..shader import generate
from .precision import encode

_WRITERS: list[Callable] = []


def register_writer(save: Callable) -> None:
    """Register ``save(result, out_dir, **kwargs)`` as what :meth:`Result.save` calls (the output layer)."""
    _WRITERS[:] = [save]


@dataclasses.dataclass(frozen=True)
class Result:
    """A fitted (or computed) factorization and its run record (see the module docstring)."""

    model: Factorization
    metrics: dict = dataclasses.field(default_factory=dict)
    solver: dict = dataclasses.field(default_factory=dict)
    timings: dict = dataclasses.field(default_factory=dict)
    counts: dict = dataclasses.field(default_factory=dict)
    config: dict = dataclasses.field(default_factory=dict)
    target_info: dict = dataclasses.field(default_factory=dict)
    warnings: tuple = ()
    samples: Any = None  # the Samples used, when kept (written as samples.npz)
    encoding: dict = dataclasses.field(default_factory=dict)  # precision.encode options: weights, alpha
    quantized: Quantized | None = None  # the 8-bit textures as stored (PNG files); None: encoded on demand
    source: str = "float"  # "png" when loaded from the 8-bit textures only: evaluate() decodes them
    selection: dict | None = None  # target_error: the candidates tried and why this one (fit/auto.py)
    state: Any = None  # what a refit reuses (fit/refit.py): layout, sample directions, solver state
    target: Any = None  # the exact target it was fitted to, when known (not saved; the preview compares to it)
    analysis: dict | None = None  # Mahajan's in-out analysis of the target, when asked (baselines.svd)

    # --- the model's view ---------------------------------------------------------------------------
    @property
    def kind(self) -> str:
        return self.model.kind

    @property
    def quantity(self) -> str:
        return self.model.quantity

    @property
    def context(self) -> dict:
        return self.model.context

    @property
    def parametrization(self) -> str:
        """What made the model (a parametrization name, ``split_sum``, ...)."""
        return self.model.name

    @property
    def textures(self) -> tuple:
        """The texel arrays, in texture order."""
        return tuple(t.data for t in self.model.textures)

    @property
    def texture_names(self) -> tuple[str, ...]:
        return tuple(t.name for t in self.model.textures)

    @property
    def correction(self):
        """The first term's correction (schema 1's ``correction`` of a single product)."""
        return self.model.terms[0].correction

    @property
    def mapper(self) -> str:
        """The mapper of the direction textures (the first one that is not ``line``)."""
        return self._main().mapper

    @property
    def texture_size(self) -> int:
        """S of the direction textures (the first one that is not ``line``)."""
        return self._main().size

    def _main(self):
        for t in self.model.textures:
            if not mappers.get(t.mapper).scalar:
                return t
        return self.model.textures[0]

    # --- evaluation ---------------------------------------------------------------------------------
    def encoded(self) -> Quantized:
        """The 8-bit textures and decode rule: the stored ones, or :func:`~homofac.fit.precision.encode`
        of the model with the options in ``encoding`` (``weights``: thesis §4.3.1; ``alpha``: §4.3.2)."""
        if self.quantized is not None:
            return self.quantized
        return encode(self.model, **self.encoding)

    def evaluate(self, a, b, *, quantized: bool | None = None) -> Float[Array, "N 3"]:
        """Values at direction pairs (a, b): (wi, wo) for BRDFs, (n, v) for lighting.

        ``quantized=True`` evaluates the 8-bit textures with their decode rule (what the PNG files hold);
        ``False`` the float textures. The default is the float path, or the 8-bit one for a result loaded
        with ``textures="png"``.
        """
        if quantized is None:
            quantized = self.source == "png"
        if quantized:
            return evaluate_quantized(self.model, self.encoded(), a, b)
        return self.model.evaluate(a, b)

    def __call__(self, a, b):
        return self.evaluate(a, b)

    # --- export -------------------------------------------------------------------------------------
    def shader(self, language: str = "glsl", *, quantized: bool = False, y_up: bool = False) -> str:
        """The shader source of ``homofac_radiance(n, v)`` (lighting) or ``homofac_brdf(wi, wo)`` (BRDF)
        in ``language`` (glsl, glsl_es, hlsl, msl, wgsl); see :mod:`homofac.shader.generate`."""
        return generate.source(self.model, language, quantized=self.encoded() if quantized else None, y_up=y_up)

    def save(self, out_dir, **kwargs):
        """Write the pinned output directory (:func:`homofac.output.save`)."""
        if not _WRITERS:
            raise HomofacError("no output writer registered: import homofac.output (import homofac does)")
        return _WRITERS[0](self, out_dir, **kwargs)

    def replace(self, **changes) -> "Result":
        """A copy with some fields replaced (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)


def value_dtype(result: Result):
    """The float dtype of the model's texels."""
    return jnp.asarray(result.model.textures[0].data).dtype


__all__ = ["Result", "register_writer", "value_dtype"]
