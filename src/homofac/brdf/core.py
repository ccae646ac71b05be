"""The BRDF registry: a model is data (:class:`ModelSpec`) plus a pure function, registered by name.

Convention (docs/conventions.md, pinned): a BRDF is ``f(wi, wo) -> (..., 3)`` RGB in the local frame (z = normal),
*without* the cosine factor, and exactly zero where ``wi.z <= 0`` or ``wo.z <= 0``. Directions are
``(..., 3)`` unit vectors; all models here are isotropic.

A model function ``fn(params, wi, wo)`` only ever sees directions strictly above the horizon:
:class:`BRDF` substitutes the normal for invalid directions before calling it and zeroes the result
afterwards (the "double where" that keeps gradients finite), so model functions need no horizon logic.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from typing import Annotated, Any, Literal, NamedTuple, Union

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array
from pydantic import AfterValidator, Field, create_model

from ..errors import HomofacError
from ..options import Options, validate

#: Smallest cosine used in denominators (1 / (n.l), 1 / (n.h)^4, ...) so that directions a hair
#: above the horizon give large but finite values, also in float32.
COS_EPS = 1e-12


class ModelSpec(NamedTuple):
    """A registered BRDF model (imitates a Mitsuba plugin: data plus a pure function).

    Attributes:
        name: registry key, also the config's ``model:`` value.
        fn: ``(params, wi, wo) -> (..., 3)``; pure ``jnp``, jittable, differentiable w.r.t. params.
            Called only with directions above the horizon (see module docstring).
        defaults: default parameter values; also the list of the model's parameter names.
        reciprocal: ``f(wi, wo) == f(wo, wi)``.
        energy_conserving: human-readable condition under which the directional albedo is <= 1
            for every view direction, or ``""`` if never guaranteed.
        doc: formula and source.
        prepare: optional hook ``dict -> dict`` run by :func:`make` on the user's parameters before
            defaults and validation (``merl`` uses it to turn ``file=`` into ``table=``).
        lobes: optional ``(params, wi, wo) -> tuple of M arrays``, directions given as component
            triples ``(x, y, z)`` of broadcastable arrays: scalar lobes such that
            ``fn = kd/pi + sum_m colors(params)[m] * lobes[m]`` (the *lobe form*). The lighting
            computation then sums over lights with one matmul per lobe instead of RGB per light.
        colors: ``params -> tuple of M RGB colours (3,)`` of the lobe form (with ``lobes``).
        support: optional ``(params, delta) -> (cos_theta, peaks)`` for lobe culling: every lobe m is at
            most ``delta * peaks[m]`` for lights more than ``theta`` away from the mirror direction
            r = 2 (n.v) n - v. Models whose lobes are not concentrated around r leave it None.
        schema: optional ``{name: (python type, default)}`` of the parameters a *config* gives, when they
            differ from ``defaults`` (``merl`` takes ``file`` in a config, ``table`` in Python); the
            option model of :func:`options_model` is derived from it (or from ``defaults``).
        microfacet: optional :class:`Microfacet` (the model's NDF), for the split-sum baseline
            (:mod:`homofac.baselines.split_sum`); None for models without one.
        shaped: optional :class:`Shaped`, the lobe form split into the part that depends on the
            directions only and the part that depends on the shape parameters (roughness): what
            :func:`stacked_lobe_terms` uses to evaluate many roughnesses at once with the geometry
            computed once. Must equal ``lobes`` (tested for every model that has it).
    """

    name: str
    fn: Callable[[dict[str, Array], Array, Array], Array]
    defaults: dict[str, Any]
    reciprocal: bool
    energy_conserving: str
    doc: str
    prepare: Callable[[dict[str, Any]], dict[str, Any]] | None = None
    lobes: Callable[[dict[str, Array], Array, Array], tuple[Array, ...]] | None = None
    colors: Callable[[dict[str, Array]], tuple[Array, ...]] | None = None
    support: Callable[[dict[str, Array], float], tuple[Array, tuple[Array, ...]]] | None = None
    schema: dict[str, tuple[Any, Any]] | None = None
    microfacet: "Microfacet | None" = None
    shaped: "Shaped | None" = None


class Microfacet(NamedTuple):
    """The microfacet distribution of a model, for the split-sum baseline (Karis 2013).

    ``ndf(params, cos_h) -> D``: the normal distribution function, normalized so that the integral of
    D cos(theta_h) over the hemisphere of h is 1 (the model's own D, with its roughness convention).
    ``fresnel``: the model's Fresnel is Schlick's F0 + (1 - F0)(1 - v.h)^5 with ``f0`` and ``ks`` params,
    so its specular albedo splits into F0 A + B (the "DFG" table).
    """

    ndf: Callable[[dict[str, Array], Array], Array]
    doc: str
    fresnel: str = "schlick"


class Shaped(NamedTuple):
    """A lobe form split for stacked shapes: ``lobes(p, wi, wo) == shape(p, geometry(wi, wo))``.

    ``geometry(wi, wo) -> tuple of arrays``: everything that does not depend on the parameters
    (half vector, cosines, shadowing, Fresnel weight); ``shape(params, geometry) -> tuple of M
    lobes``: the few operations that do (for Beckmann, ``exp(-s tan^2 theta_h) s`` times the
    geometry). Directions reach ``geometry`` above the horizon only, as for ``lobes``.
    """

    geometry: Callable[[tuple, tuple], tuple]
    shape: Callable[[dict[str, Array], tuple], tuple]


#: All registered models by name.
MODELS: dict[str, ModelSpec] = {}


def register(spec: ModelSpec) -> ModelSpec:
    """Add ``spec`` to :data:`MODELS` (replacing a model of the same name) and return it."""
    if not isinstance(spec, ModelSpec):
        raise HomofacError(f"brdf.register expects a ModelSpec, got {type(spec).__name__}")
    MODELS[spec.name] = spec
    options_model.cache_clear()
    return spec


class BRDF(eqx.Module):
    """A BRDF instance: a registered model name (static) and its parameters (a pytree).

    ``jax.grad`` w.r.t. ``brdf.params["roughness"]`` works as for any equinox module; tables (``merl``)
    are leaves too, so under ``eqx.filter_jit`` they are arguments, never captured constants.
    Construct with :func:`make` (or a per-model constructor) to get defaults and validation.
    """

    model: str = eqx.field(static=True)
    params: dict[str, Array]

    def __call__(self, wi: Array, wo: Array) -> Array:
        """``f(wi, wo)``, shape ``broadcast(wi, wo).shape[:-1] + (3,)``; exactly 0 below the horizon.

        Jitted (one compilation per model and input shapes; params are traced arguments), and
        usable inside other jitted / differentiated functions.
        """
        return _call(self, _as_float(wi), _as_float(wo))

    @property
    def spec(self) -> ModelSpec:
        """The :class:`ModelSpec` of this BRDF's model."""
        return MODELS[self.model]


@eqx.filter_jit
def _call(brdf: BRDF, wi: Array, wo: Array) -> Array:
    mask = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    up = jnp.zeros(3, wi.dtype).at[2].set(1.0)
    m = mask[..., None]
    # "double where": the model only sees valid directions, so masked entries cannot produce
    # inf / nan that would leak into gradients through the final where.
    wi_s = jnp.where(m, wi, up)
    wo_s = jnp.where(m, wo, up)
    val = MODELS[brdf.model].fn(brdf.params, wi_s, wo_s)
    shape = jnp.broadcast_shapes(wi.shape, wo.shape)
    return jnp.where(m, jnp.broadcast_to(val, shape), jnp.zeros((), val.dtype))


def has_lobes(brdf: Any) -> bool:
    """True when ``brdf`` is a :class:`BRDF` whose model has a lobe form (see :class:`ModelSpec`)."""
    return isinstance(brdf, BRDF) and MODELS[brdf.model].lobes is not None


def lobe_terms(brdf: BRDF, wi, wo) -> tuple[Array, ...]:
    """The scalar lobes of ``brdf``'s lobe form at (wi, wo), each exactly 0 below the horizon.

    ``brdf(wi, wo) == kd/pi + sum_m lobe_colors(brdf)[m] * lobe_terms(brdf, wi, wo)[m]`` above it.
    ``wi`` and ``wo`` are ``(..., 3)`` arrays or component triples ``(x, y, z)`` of arrays that
    broadcast against each other (what the lighting computation passes: no (P, K, 3) array is built).
    Masked with the same "double where" as :meth:`BRDF.__call__` (finite gradients).
    """
    m, wi_s, wo_s = _above(wi, wo)
    terms = MODELS[brdf.model].lobes(brdf.params, wi_s, wo_s)
    return tuple(jnp.where(m, g, jnp.zeros((), g.dtype)) for g in terms)


def _above(wi, wo):
    """(mask of pairs above the horizon, wi, wo) as component triples, the masked entries replaced by the
    normal direction, so that no model divides by zero there (the first half of the "double where")."""
    wi = _triple(wi)
    wo = _triple(wo)
    m = (wi[2] > 0) & (wo[2] > 0)
    safe = lambda w: (jnp.where(m, w[0], 0.0), jnp.where(m, w[1], 0.0), jnp.where(m, w[2], 1.0))  # noqa: E731
    return m, safe(wi), safe(wo)


def stacked_lobe_terms(brdfs: BRDF, wi, wo) -> Array:
    """The lobes of B BRDFs of one model stacked along their parameters' leading axis (see
    :func:`homofac.fit.transport.stack`): ``(B, M) + broadcast(wi, wo)`` -- :func:`lobe_terms` of each.

    With a :class:`Shaped` split and B > 1 the direction-only geometry is computed once and only the
    shape part is vmapped over the B shapes (4 Beckmann roughnesses: 0.9 -> 0.7 s of a library's
    lighting, measured; for one shape the direct form is ~10 % faster); otherwise :func:`lobe_terms` is vmapped (parts that do not depend on the parameters are
    still traced once, but XLA's fusion may evaluate them again per shape).
    """
    spec = MODELS[brdfs.model]
    wi = _triple(wi)
    wo = _triple(wo)
    count = jax.tree_util.tree_leaves(brdfs.params)[0].shape[0]
    if spec.shaped is None or count == 1:  # one shape: the direct form (measured faster alone)
        def one(b):
            g = lobe_terms(b, wi, wo)
            shape = jnp.broadcast_shapes(*(c.shape for c in wi + wo))
            return jnp.stack(g) if g else jnp.zeros((0,) + shape, wi[0].dtype)
        return jax.vmap(one)(brdfs)
    m, wi_s, wo_s = _above(wi, wo)
    geom = spec.shaped.geometry(wi_s, wo_s)
    g = jax.vmap(lambda params: jnp.stack(spec.shaped.shape(params, geom)))(brdfs.params)
    return jnp.where(m, g, jnp.zeros((), g.dtype))


def _triple(w):
    if isinstance(w, (tuple, list)):
        return tuple(_as_float(c) for c in w)
    w = _as_float(w)
    return (w[..., 0], w[..., 1], w[..., 2])


def lobe_support(brdf: Any, delta: float):
    """``(cos_theta, peaks)`` of :attr:`ModelSpec.support` for ``brdf``, or None when it has none."""
    if not has_lobes(brdf) or MODELS[brdf.model].support is None:
        return None
    return MODELS[brdf.model].support(brdf.params, delta)


def lobe_colors(brdf: BRDF) -> tuple[Array, ...]:
    """The RGB colours (3,) of ``brdf``'s lobes (see :func:`lobe_terms`)."""
    return tuple(jnp.broadcast_to(c, (3,)) for c in MODELS[brdf.model].colors(brdf.params))


def evaluate(brdf: BRDF, wi: Array, wo: Array) -> Array:
    """``brdf(wi, wo)`` (an alias; the call is jitted already)."""
    return brdf(wi, wo)


def _as_float(x: Any) -> Array:
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


# --------------------------------------------------------------------------------------------
# Validation. Rules are per parameter name (names are pinned across models, docs/models.md).

#: name -> (kind, lower bound, lower bound inclusive, upper bound or None, description for errors)
_RULES: dict[str, tuple[str, float | None, bool, float | None, str]] = {
    "kd": ("color", 0.0, True, None, "finite and >= 0"),
    "ks": ("color", 0.0, True, None, "finite and >= 0"),
    "f0": ("color", 0.0, True, 1.0, "finite and in [0, 1]"),
    "base_color": ("color", 0.0, True, 1.0, "finite and in [0, 1]"),
    "metallic": ("scalar", 0.0, True, 1.0, "a number in [0, 1]"),
    "roughness": ("scalar", 0.0, False, None, "a finite number > 0"),
    "exponent": ("scalar", 0.0, True, None, "a finite number >= 0"),
    "table": ("array", None, True, None, "finite (negative entries are holes)"),
}


def _fmt(a: np.ndarray) -> str:
    if a.ndim == 0:
        return repr(float(a)) if np.isfinite(a) else str(float(a))
    if a.size <= 6:
        return "[" + ", ".join(str(float(v)) for v in a.ravel()) + "]"
    return f"array of shape {a.shape}"


def _concrete(value: Any) -> np.ndarray | None:
    """``value`` as a numpy array, or None if it is a tracer (abstract: skip value checks)."""
    if isinstance(value, jax.core.Tracer):
        return None
    try:
        return np.asarray(value)
    except (jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError):
        return None


def _rule_for(name: str, default: Any) -> tuple[str, float | None, bool, float | None, str]:
    if name in _RULES:
        return _RULES[name]
    shape = np.shape(default) if default is not None else None
    kind = "color" if shape == (3,) else ("scalar" if shape == () else "array")
    return (kind, None, True, None, "finite")


def check_value(name: str, value: Any, default: Any = None) -> str | None:
    """The problem with a concrete parameter value under the rule of ``name`` (``None`` when it is fine).

    The one place where parameter limits live: :func:`make` and the option models of
    :func:`options_model` both call it.
    """
    kind, lo, lo_incl, hi, what = _rule_for(name, default)
    try:
        conc = np.asarray(value)
    except Exception:  # noqa: BLE001 - ragged lists and other junk
        return f"must be {'a number or 3 numbers' if kind == 'color' else 'a number'}, got {value!r}"
    if conc.dtype == object or conc.dtype.kind not in "iuf":
        return f"must be {'a number or 3 numbers' if kind == 'color' else 'a number'}, got {value!r}"
    shape = tuple(conc.shape)
    if kind == "color" and shape not in ((), (1,), (3,)):
        return f"must be a scalar or 3 values (RGB), got shape {shape}"
    if kind == "scalar" and shape not in ((), (1,)):
        return f"must be a single number, got shape {shape}"
    if kind == "array":
        return None if np.all(np.isfinite(conc)) else f"must be {what}, got non-finite values"
    a = conc.astype(np.float64)
    bad = ~np.isfinite(a)
    if lo is not None:
        bad |= (a < lo) if lo_incl else (a <= lo)
    if hi is not None:
        bad |= a > hi
    if np.any(bad):
        shown = a.reshape(()) if a.size == 1 else a
        return f"must be {what}, got {_fmt(shown)}"
    return None


def _convert(name: str, value: Any, default: Any) -> Array:
    """Validate one parameter and convert it to a jnp array ((3,) colour, () scalar)."""
    kind = _rule_for(name, default)[0]
    where = f"brdf.{name}"
    conc = _concrete(value)
    if conc is not None:
        if conc.dtype.kind == "b":
            raise HomofacError(f"{where} must be a number, got {value!r}")
        problem = check_value(name, value, default)
        if problem:
            raise HomofacError(f"{where} {problem}")
        if kind == "array":  # tables: keep their float dtype
            return jnp.asarray(conc if conc.dtype.kind == "f" else conc.astype(np.float32))
        out = jnp.asarray(conc.astype(np.float64), dtype=jnp.result_type(float))
    else:
        shape = tuple(jnp.shape(value))
        if kind == "color" and shape not in ((), (1,), (3,)):
            raise HomofacError(f"{where} must be a scalar or 3 values (RGB), got shape {shape}")
        if kind == "scalar" and shape not in ((), (1,)):
            raise HomofacError(f"{where} must be a single number, got shape {shape}")
        out = jnp.asarray(value)
        if not jnp.issubdtype(out.dtype, jnp.floating):
            out = out.astype(jnp.result_type(float))
    if kind == "color":
        out = jnp.broadcast_to(out.reshape(-1) if out.ndim else out, (3,))
    elif kind == "scalar":
        out = out.reshape(())
    return out


def make(model: str, **params: Any) -> BRDF:
    """A :class:`BRDF` of a registered ``model``: fills defaults, validates, converts to jnp arrays.

    Colours (``kd``, ``ks``, ``f0``) accept a scalar or 3 values and become ``(3,)`` arrays; scalars
    (``roughness``, ``exponent``) become ``()`` arrays. Value checks (finite, >= 0, roughness > 0, ...)
    run only on concrete values, so ``make`` can be called inside ``jax.grad`` with tracers.

    Raises:
        HomofacError: unknown model (lists the known ones), unknown parameter (names it and lists the
            model's parameters), or a bad value (names the parameter).
    """
    if not isinstance(model, str) or model not in MODELS:
        known = ", ".join(MODELS)
        raise HomofacError(f"brdf.model: unknown model {model!r}; known models: {known}")
    spec = MODELS[model]
    if spec.prepare is not None:
        params = spec.prepare(dict(params))
    allowed = list(spec.defaults)
    for name in params:
        if name not in spec.defaults:
            raise HomofacError(
                f"brdf.{name}: unknown parameter for model {model!r}; its parameters: {', '.join(allowed)}"
            )
    full: dict[str, Array] = {}
    for name, default in spec.defaults.items():
        value = params.get(name, default)
        if value is None:
            raise HomofacError(f"brdf.{name}: model {model!r} needs a value for {name!r}")
        full[name] = _convert(name, value, default)
    return BRDF(model, full)


def _rule_validator(name: str, default: Any):
    def check(value):
        if value is None:
            return value
        problem = check_value(name, value, default)
        if problem:
            raise ValueError(problem)
        return value

    return AfterValidator(check)


@functools.lru_cache(maxsize=None)
def options_model(model: str) -> type[Options]:
    """The pydantic option model of a registered model's config entry ``{model: name, params...}``.

    Derived from the registry (``ModelSpec.schema`` or ``defaults`` with the parameter rules), so the
    config, ``--help`` and the docs' parameter tables list exactly what :func:`make` accepts.
    """
    spec = MODELS[model]
    fields: dict[str, Any] = {"model": (Literal[model], ...)}
    if spec.schema is not None:
        for name, (typ, default) in spec.schema.items():
            fields[name] = (typ, default)
    else:
        for name, default in spec.defaults.items():
            # the rule (check_value) decides what a value may be: a number, or 3 numbers for colours
            fields[name] = (Annotated[Any, _rule_validator(name, default)], None)
    cls = create_model(f"{model}_options", __base__=BRDFOptionsBase, **fields)
    cls.TAG = model
    cls.__doc__ = spec.doc.splitlines()[0] if spec.doc else model
    return cls


class BRDFOptionsBase(Options):
    """Base of the per-model option models: ``params()`` are the values given (``None`` = default)."""

    def params(self) -> dict[str, Any]:
        return {k: v for k, v in self.model_dump().items() if k != "model" and v is not None}


def options_union():
    """The tagged union (by ``model``) of every registered model's option model, for config schemas."""
    members = tuple(options_model(name) for name in MODELS)
    if len(members) == 1:
        return members[0]
    return Annotated[Union[members], Field(discriminator="model")]  # type: ignore[valid-type]


def from_config(cfg: Mapping[str, Any] | BRDFOptionsBase, where: str = "brdf") -> BRDF:
    """A BRDF from a config entry like ``{model: cook_torrance, kd: [...], ...}`` (validated as the CLI does)."""
    if isinstance(cfg, BRDFOptionsBase):
        return make(cfg.model, **cfg.params())
    if not isinstance(cfg, Mapping) or "model" not in cfg:
        raise HomofacError(f"{where}.model: missing; known models: " + ", ".join(MODELS))
    name = cfg["model"]
    if not isinstance(name, str) or name not in MODELS:
        raise HomofacError(f"{where}.model: unknown model {name!r}; known models: {', '.join(MODELS)}")
    opts = validate(options_model(name), dict(cfg), where)
    return make(name, **opts.params())
