"""The factorization model (schema 2, docs/format.md): a sum of terms, each a correction times a product.

    value(a, b) = sum_terms correction_t * prod_(factors of t) bilinear(texture, mapper(projection(a, b)))

on the *linear* textures, which is what a renderer computes per pixel. Each texture has its own
mapper and size (a 1D ``line`` table beside 2D direction maps); a factor names a projection
(:mod:`homofac.param.projections`) and a texture. Today's single product of a parametrization
(McCool 2001, Latta & Kolb 2002) is the one-term case (:meth:`Factorization.product`); sums of products
and the baselines (split-sum, Kautz-McCool) are the same model with more terms.

:class:`Factorization` is a pytree (an equinox module): the texel arrays and corrections are leaves,
names and structure are static, so ``jax.grad`` flows through :meth:`Factorization.evaluate` and
``jax.jit`` compiles one program per structure. It is only the model; how it was made (config,
metrics, timings) is the run record of :mod:`homofac.fit.result`.

8-bit textures (:class:`Quantized`) carry the pinned decode rule
``texel = offset + scale * rgb * (alpha if alpha else 1)`` with ``rgb = RGB/255``, ``alpha = A/255``
per channel, each channel interpolated bilinearly before the products; a term's 8-bit value is its
8-bit correction times the product of decoded texels (the thesis' alpha trick, §4.3.2, is the case
offset 0, scale 1, alpha on).
"""

from __future__ import annotations

import functools
import re
from typing import Any, NamedTuple, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, UInt8

from .compiling import jit
from .errors import HomofacError
from .param import mappers
from .param import parametrizations as pz
from .param import projections as pj

KINDS = ("brdf", "lighting")
QUANTITIES = ("brdf", "brdf_cos", "lighting")

# Names (pinned, docs/format.md "Names"): what a factorization.json may call things. Texture names and term
# kinds reach generated code (``hf_<texture>``, comments); the model's name only its comments and pages.
#: A texture name or a term kind: an ASCII identifier, a letter first, at most 64 characters, no ``__``.
IDENTIFIER = re.compile(r"[A-Za-z](?!.*__)[A-Za-z0-9_]{0,63}")
#: The model's name (schema 1's ``parametrization``): a label such as ``E'+NRW x2+R``, at most 128 characters
#: of letters, digits, space and ``_ ' + . , = -``; may be empty.
LABEL = re.compile(r"[A-Za-z0-9_ '+.,=-]{0,128}")
#: Texture names that would collide with the shader generator's own ``hf_`` identifiers
#: (:mod:`homofac.shader.generate`: ``hf_normalize``, ``hf_local``, ``hf_flip_v``, the MSL ``hf_sampler``;
#: the previews' ``hf_srgb``, ``hf_viridis``) ...
RESERVED_TEXTURE_NAMES = frozenset({"normalize", "local", "flip_v", "sampler", "srgb", "viridis"})
#: ... or with the per-texture and per-record ones (``hf_sample_<t>``, ``hf_sample_alpha_<t>``,
#: ``hf_map_<mapper>``, ``hf_proj_<projection>``, WGSL's ``hf_<t>_sampler``).
RESERVED_TEXTURE_PREFIXES = ("sample_", "alpha_", "map_", "proj_")
RESERVED_TEXTURE_SUFFIXES = ("_sampler",)


def _shown(value) -> str:
    """``value`` for an error message: its repr, cut to 80 characters (one line, whatever it holds)."""
    r = repr(value)
    return r if len(r) <= 80 else r[:77] + "..."


def check_identifier(value, what: str) -> str:
    """``value`` when it is an :data:`IDENTIFIER`, else a one-line :class:`HomofacError` naming ``what``."""
    if not isinstance(value, str) or IDENTIFIER.fullmatch(value) is None:
        raise HomofacError(f"{what} must be an identifier (a letter, then letters, digits or single underscores; "
                           f"at most 64 characters), got {_shown(value)}")
    return value


def check_texture_name(value, what: str = "texture name") -> str:
    """``value`` when it is a valid texture name: an :data:`IDENTIFIER` that is not reserved by the shader
    generator (:data:`RESERVED_TEXTURE_NAMES`, ``..._PREFIXES``, ``..._SUFFIXES``); else one line."""
    check_identifier(value, what)
    if (value in RESERVED_TEXTURE_NAMES or value.startswith(RESERVED_TEXTURE_PREFIXES)
            or value.endswith(RESERVED_TEXTURE_SUFFIXES)):
        raise HomofacError(f"{what} {value!r} is reserved: it would collide with the generated shaders' own names "
                           f"(hf_{value}); rename the texture")
    return value


def check_label(value, what: str = "name") -> str:
    """``value`` when it is a :data:`LABEL` (the model's name), else a one-line :class:`HomofacError`."""
    if not isinstance(value, str) or LABEL.fullmatch(value) is None:
        raise HomofacError(f"{what} must be at most 128 characters of letters, digits, space and _ ' + . , = -; "
                           f"got {_shown(value)}")
    return value


class Texture(eqx.Module):
    """One texture: its name, mapper, size S and linear RGB texels ``(H, W, 3)`` (``(1, S, 3)`` for line)."""

    name: str = eqx.field(static=True)
    mapper: str = eqx.field(static=True)
    size: int = eqx.field(static=True)
    data: Float[Array, "H W 3"]

    @property
    def shape(self) -> tuple[int, int]:
        return mappers.texture_shape(self.mapper, self.size)

    @property
    def texels(self) -> int:
        """Texels that hold data (valid texels; what a renderer must store at least)."""
        return int(np.count_nonzero(mappers.valid_mask(self.mapper, self.size)))


class Factor(NamedTuple):
    """A factor of a term: the texture named ``texture`` looked up at ``projection(a, b)``."""

    projection: str
    texture: str


class Term(eqx.Module):
    """``correction * prod_factors``; ``kind`` is informational (fitted, irradiance, prefiltered, lut, ...)."""

    factors: tuple[Factor, ...] = eqx.field(static=True)
    correction: Float[Array, "3"]
    kind: str = eqx.field(static=True, default="fitted")


class Factorization(eqx.Module):
    """A sum of products of texture lookups: the schema-2 model (see the module docstring).

    Attributes:
        kind: ``brdf`` (a = wi, b = wo, local frame) or ``lighting`` (a = n, b = v, world frame).
        quantity: ``brdf`` (f), ``brdf_cos`` (f cos theta_i) or ``lighting`` (L(v, n)).
        textures: the textures, each with its own mapper and size; names are unique.
        terms: the terms; each factor names one of the textures.
        context: projection context (``dominant``: the light direction of NRHD, thesis eq. 66).
        name: what made it (a parametrization such as ``NR``, or ``split_sum``, ...); informational.
    """

    kind: str = eqx.field(static=True)
    quantity: str = eqx.field(static=True)
    textures: tuple[Texture, ...]
    terms: tuple[Term, ...]
    context: dict = eqx.field(default_factory=dict)
    name: str = eqx.field(static=True, default="")

    def __check_init__(self):
        check_label(self.name, "factorization name")
        for t in self.textures:
            check_texture_name(t.name)
        for i, term in enumerate(self.terms):
            check_identifier(term.kind, f"term {i}: kind")
        if self.kind not in KINDS:
            raise HomofacError(f"factorization kind must be one of {', '.join(KINDS)}, got {self.kind!r}")
        if self.quantity not in QUANTITIES:
            raise HomofacError(f"factorization quantity must be one of {', '.join(QUANTITIES)}, got {self.quantity!r}")
        names = [t.name for t in self.textures]
        if len(set(names)) != len(names):
            raise HomofacError(f"factorization texture names must be unique, got {names}")
        if not self.terms:
            raise HomofacError("a factorization needs at least one term")
        by_name = {t.name: t for t in self.textures}
        for i, term in enumerate(self.terms):
            for f in term.factors:
                if f.texture not in by_name:
                    raise HomofacError(f"term {i}: factor texture {f.texture!r} is not one of {names}")
                proj = pj.get(f.projection, self.kind)
                m = mappers.get(by_name[f.texture].mapper)
                if proj.scalar != m.scalar:
                    raise HomofacError(
                        f"term {i}: projection {f.projection} is {'a scalar' if proj.scalar else 'a direction'}, "
                        f"but texture {f.texture} uses mapper {m.name}"
                    )
                if not proj.scalar and not proj.hemisphere and self.kind == "lighting" and not m.covers_sphere:
                    raise HomofacError(
                        f"term {i}: lighting projection {f.projection} spans the sphere; mapper {m.name} covers "
                        "only the upper hemisphere (use dual_paraboloid, cube or octahedral)"
                    )
                for key in proj.context:
                    if key not in self.context:
                        raise HomofacError(f"projection {f.projection} needs context[{key!r}] (thesis eq. 66)")

    # --- construction -------------------------------------------------------------------------------
    @staticmethod
    def product(kind: str, quantity: str, parametrization: str, mapper: str, size: int, data: Sequence,
                correction, context: dict | None = None, line_size: int | None = None) -> "Factorization":
        """The one-term model of a registered parametrization (schema 1's single product).

        Direction textures use ``mapper`` at ``size``; textures read by scalar projections use the
        ``line`` mapper at ``line_size`` (default ``size``).
        """
        p = pz.get(parametrization, kind)
        textures = tuple(
            Texture(name, "line" if p.scalar(k) else mapper, int(line_size or size) if p.scalar(k) else int(size),
                    jnp.asarray(data[k]))
            for k, name in enumerate(p.textures)
        )
        term = Term(tuple(Factor(f.projection, p.textures[f.texture]) for f in p.factors), jnp.asarray(correction))
        return Factorization(kind, quantity, textures, (term,), dict(context or {}), p.name)

    # --- structure ----------------------------------------------------------------------------------
    def texture(self, name: str) -> Texture:
        for t in self.textures:
            if t.name == name:
                return t
        raise HomofacError(f"no texture {name!r}; textures: {', '.join(t.name for t in self.textures)}")

    def index(self, name: str) -> int:
        """Position of the texture called ``name``."""
        return [t.name for t in self.textures].index(name)

    @property
    def lookups(self) -> int:
        """Texture lookups per pixel (one per factor of every term)."""
        return sum(len(t.factors) for t in self.terms)

    @property
    def texels(self) -> int:
        """Valid texels over all textures (the memory a renderer pays, in texels)."""
        return sum(t.texels for t in self.textures)

    def uses(self, name: str) -> int:
        """How many factors (over all terms) read the texture ``name``."""
        return sum(1 for term in self.terms for f in term.factors if f.texture == name)

    def replace_data(self, data: Sequence) -> "Factorization":
        """The same structure with new texel arrays (in texture order)."""
        return eqx.tree_at(lambda m: [t.data for t in m.textures], self, [jnp.asarray(d) for d in data])

    # --- evaluation ---------------------------------------------------------------------------------
    def evaluate(self, a: Float[Array, "N 3"], b: Float[Array, "N 3"]) -> Float[Array, "N 3"]:
        """The model's value at direction pairs: (wi, wo) for BRDFs, (n, v) for lighting. Jitted,
        differentiable w.r.t. the texels, the corrections and the directions."""
        dtype = jnp.asarray(self.textures[0].data).dtype
        return _evaluate(self, jnp.asarray(a, dtype), jnp.asarray(b, dtype))

    def term_values(self, a, b) -> Float[Array, "T N 3"]:
        """Each term's value separately, ``(terms, N, 3)`` (their sum is :meth:`evaluate`)."""
        dtype = jnp.asarray(self.textures[0].data).dtype
        return _term_values(self, jnp.asarray(a, dtype), jnp.asarray(b, dtype))

    def __call__(self, a, b):
        return self.evaluate(a, b)


def _lookups(model: Factorization, data: Sequence, a, b) -> list:
    """Per term the list of looked-up values ``(N, C)`` of its factors (projections computed once)."""
    by_name = {t.name: (t, d) for t, d in zip(model.textures, data)}
    projected: dict[str, Any] = {}
    out = []
    for term in model.terms:
        vals = []
        for f in term.factors:
            if f.projection not in projected:
                projected[f.projection] = pj.apply(f.projection, a, b, model.context)
            tex, d = by_name[f.texture]
            vals.append(mappers.lookup(tex.mapper, d, projected[f.projection].astype(d.dtype)))
        out.append(vals)
    return out


def _term_values_impl(model: Factorization, a, b):
    data = [t.data for t in model.textures]
    out = []
    for term, vals in zip(model.terms, _lookups(model, data, a, b)):
        v = jnp.broadcast_to(term.correction.astype(a.dtype), a.shape[:-1] + (3,))
        for x in vals:
            v = v * x
        out.append(v)
    return jnp.stack(out)


@eqx.filter_jit
def _term_values(model: Factorization, a, b):
    return _term_values_impl(model, a, b)


@eqx.filter_jit
def _evaluate(model: Factorization, a, b):
    return jnp.sum(_term_values_impl(model, a, b), axis=0)


def evaluate_by_factor(model: Factorization, a, b) -> np.ndarray:
    """The model's value at direction pairs (:meth:`Factorization.evaluate`: the sum over terms of the
    correction times the factors' bilinear lookups), each factor's lookup a program compiled once per
    projection, mapper and texture shape and shared by every model with such a factor (a chooser's
    candidates: one program per structure compiled each), the products and the sum on the host in the
    float type of the textures, in :meth:`~Factorization.evaluate`'s order (the same values to float
    rounding). Not differentiable: for measuring. Returns (N, 3) as a NumPy array."""
    dtype = np.asarray(model.textures[0].data).dtype
    a, b = jnp.asarray(a, dtype), jnp.asarray(b, dtype)
    by_name = {t.name: t for t in model.textures}
    seen: dict = {}
    out = None
    for term in model.terms:
        v = np.broadcast_to(np.asarray(term.correction, dtype), a.shape[:-1] + (3,))
        for f in term.factors:
            if (f.projection, f.texture) not in seen:
                tex = by_name[f.texture]
                ctx = {k: jnp.asarray(model.context[k], dtype) for k in pj.get(f.projection).context
                       if k in model.context}
                seen[f.projection, f.texture] = np.asarray(
                    _factor_lookup(jnp.asarray(tex.data), a, b, ctx, proj=f.projection, mapper=tex.mapper))
            v = v * seen[f.projection, f.texture]
        out = v if out is None else out + v
    return np.zeros(a.shape[:-1] + (3,), dtype) if out is None else np.asarray(out, dtype)


@jit(kind="lookup", static_argnames=("proj", "mapper"))
def _factor_lookup(data, a, b, context: dict, *, proj: str, mapper: str):
    """One factor's bilinear lookup ``mapper(data)`` at the projection ``proj`` of the pairs (a, b)."""
    return mappers.lookup(mapper, data, pj.apply(proj, a, b, context).astype(data.dtype))


# --------------------------------------------------------------------------------------------------
# 8-bit textures


class Quantized(NamedTuple):
    """The 8-bit RGBA textures of a model and their decode rule (pinned, see the module docstring).

    Attributes:
        rgba: per texture (model order) an ``(H, W, 4)`` uint8 array, what a PNG stores.
        offset: per texture (3,) offsets of the decode rule (0 for positive textures).
        scale: per texture (3,) scales of the decode rule.
        alpha: per texture, whether A multiplies the colour channels (the thesis' alpha trick); else A is 255.
        corrections: per term the (3,) correction applied to the 8-bit product.
        rule: a JSON-friendly description of how they were encoded (prescale, power-of-two scale, ...).
    """

    rgba: tuple
    offset: tuple
    scale: tuple
    alpha: tuple
    corrections: tuple
    rule: dict


def decode_texels(q: Quantized) -> list[np.ndarray]:
    """Per texture the float texels ``offset + scale * rgb * alpha`` the decode rule gives (float32)."""
    out = []
    for rgba, off, sc, alpha in zip(q.rgba, q.offset, q.scale, q.alpha):
        v = np.asarray(rgba, np.float32) / np.float32(255.0)
        rgb = v[..., :3] * (v[..., 3:] if alpha else 1.0)
        out.append((np.asarray(off, np.float32) + np.asarray(sc, np.float32) * rgb).astype(np.float32))
    return out


def evaluate_quantized(model: Factorization, q: Quantized, a, b) -> Float[Array, "N 3"]:
    """The model's value from its 8-bit textures with the pinned decode rule (what a GPU computes).

    Each RGBA channel is interpolated bilinearly (as texture units do) before decoding, so with the
    alpha trick the product is ``offset + scale * bilerp(rgb) * bilerp(alpha)`` per factor.
    """
    a = jnp.asarray(a)
    dt = a.dtype if jnp.issubdtype(a.dtype, jnp.floating) else jnp.result_type(float)
    a = a.astype(dt)
    b = jnp.asarray(b, dt)
    channels = tuple(jnp.asarray(np.asarray(r, np.float64) / 255.0, dt) for r in q.rgba)
    offsets = tuple(jnp.asarray(o, dt) for o in q.offset)
    scales = tuple(jnp.asarray(s, dt) for s in q.scale)
    corr = tuple(jnp.asarray(c, dt) for c in q.corrections)
    return _evaluate_q(model, channels, offsets, scales, corr, tuple(bool(x) for x in q.alpha), a, b)


@jit(kind="lookup", filter=True)
def _evaluate_q(model, channels, offsets, scales, corrections, alpha: tuple, a, b):
    index = {t.name: k for k, t in enumerate(model.textures)}
    lookups = _lookups(model, channels, a, b)
    out = jnp.zeros(a.shape[:-1] + (3,), a.dtype)
    for term, vals, c in zip(model.terms, lookups, corrections):
        v = jnp.broadcast_to(c, a.shape[:-1] + (3,))
        for f, x in zip(term.factors, vals):
            k = index[f.texture]
            rgb = x[..., :3] * (x[..., 3:4] if alpha[k] else 1.0)
            v = v * (offsets[k] + scales[k] * rgb)
        out = out + v
    return out


def check_rgba(q: Quantized, model: Factorization) -> None:
    """Refuse 8-bit textures that do not fit the model (count, shapes, dtype)."""
    if len(q.rgba) != len(model.textures) or len(q.corrections) != len(model.terms):
        raise HomofacError(f"8-bit textures: {len(q.rgba)} textures and {len(q.corrections)} corrections for a model "
                           f"of {len(model.textures)} textures and {len(model.terms)} terms")
    for t, r in zip(model.textures, q.rgba):
        r = np.asarray(r)
        if r.dtype != np.uint8 or r.shape != t.shape + (4,):
            raise HomofacError(f"8-bit texture {t.name}: expected uint8 {t.shape + (4,)}, got {r.dtype} {r.shape}")


def tree_arrays(model: Factorization) -> list[jax.Array]:
    """The model's leaves (texels, corrections, context), e.g. to count parameters."""
    return jax.tree_util.tree_leaves(model)


__all__ = ["Factor", "Factorization", "IDENTIFIER", "evaluate_by_factor", "KINDS", "LABEL", "QUANTITIES", "Quantized", "RESERVED_TEXTURE_NAMES",
           "RESERVED_TEXTURE_PREFIXES", "RESERVED_TEXTURE_SUFFIXES", "Term", "Texture", "check_identifier", "check_label",
           "check_rgba", "check_texture_name", "decode_texels", "evaluate_quantized", "tree_arrays"]
