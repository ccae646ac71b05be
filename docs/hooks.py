"""mkdocs hooks: the reference tables of the docs, generated from homofac's registries at build time.

A page asks for generated text with a marker comment::

    <!-- homofac:mappers -->
    <!-- homofac:api homofac.fit -->

and :func:`on_page_markdown` replaces the marker by the text of the generator of that name
(:data:`GENERATORS`). So a registered BRDF model, mapper, projection, parametrization, solver, shading
language or config key appears in the docs exactly as the code defines it, the way Filament generates
its shader blocks from one field list. Every generator is a plain function returning Markdown; the
tests (tests/test_docs.py) import this module and call them.

Generators that run homofac (the example output directory, the shader) do it once per build, in a
temporary directory, with the sample cache off. Like the CLI they use JAX's persistent compilation
cache (``~/.cache/homofac/jax``; ``HOMOFAC_JAX_CACHE=0`` turns it off, ``HOMOFAC_JAX_CACHE=DIR`` moves it),
which makes a second build about 10 s faster.
"""

from __future__ import annotations

import ast
import functools
import importlib
import inspect
import json
import logging
import os
import pkgutil
import re
import tempfile
import types
import typing
from pathlib import Path
from typing import Any, Callable

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    tomllib = None

import annotated_types
import pydantic
import yaml
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

import homofac
from homofac import baselines, brdf
from homofac.errors import HomofacError
from homofac.options import validate
from homofac.app import cli
from homofac.app import config as config_mod
from homofac.app.run import run
from homofac.brdf import core as brdf_core
from homofac.fit import options as fit_options
from homofac.fit import pipeline as fit_pipeline
from homofac.fit import solvers
from homofac.param import mappers, parametrizations, projections
from homofac.shader import languages

log = logging.getLogger("mkdocs.hooks.homofac")

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
MARKER = re.compile(r"<!--\s*homofac:([a-z_0-9]+)((?:[ \t]+[^\s>]+)*)[ \t]*-->")


# --------------------------------------------------------------------------------------------------
# Small helpers


def escape_pipes(text: str) -> str:
    """``|`` escaped for a Markdown table cell, except inside code spans (the tables extension keeps those)."""
    parts = re.split(r"(`+[^`]*`+)", text)
    return "".join(p if p.startswith("`") else p.replace("|", "\\|") for p in parts)


def cell(text: Any) -> str:
    """Text for one Markdown table cell: one line, pipes escaped."""
    return escape_pipes(" ".join(str(text).split()))


def code(text: Any) -> str:
    """A code span (backticks inside become a longer fence)."""
    s = str(text)
    fence = "``" if "`" in s else "`"
    pad = " " if "`" in s else ""
    return f"{fence}{pad}{s}{pad}{fence}"


def table(header: list[str], rows: list[list[Any]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(cell(c) for c in row) + " |" for row in rows]
    return "\n".join(out)


def fenced(text: str, lang: str = "") -> str:
    fence = "```"
    while fence in text:
        fence += "`"
    return f"{fence}{lang}\n{text.rstrip()}\n{fence}"


def yaml_value(v: Any) -> str:
    """A value as the config (YAML) spells it."""
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(yaml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k}: {yaml_value(x)}" for k, x in v.items()) + "}"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def first_paragraph(doc: str | None) -> str:
    doc = inspect.cleandoc(doc or "")
    return doc.split("\n\n", 1)[0].replace("\n", " ").strip()


def rst_to_md(text: str) -> str:
    """The reStructuredText roles of a docstring as code spans (``:func:`a.b``` -> ```a.b```)."""
    text = re.sub(r":[a-z]+:`~?([^`]+)`", lambda m: f"`{m.group(1)}`", text)
    return text.replace("``", "`")


def shape_text(m: mappers.Mapper) -> str:
    """The texture shape of a mapper in terms of S: ``(S, 2S)``, ``(1, S)``."""
    rows = "1" if m.scalar else "S"
    cols = "S" if m.faces == 1 else f"{m.faces}S"
    return f"({rows}, {cols})"


def domain_text(m: mappers.Mapper) -> str:
    if m.scalar:
        return "scalar x in [0, 1]"
    return "sphere" if m.covers_sphere else "hemisphere z >= 0"


# --------------------------------------------------------------------------------------------------
# Registries


def mappers_table() -> str:
    """The direction mappers (``homofac.param.mappers.MAPPERS``)."""
    rows = []
    for name, m in mappers.MAPPERS.items():
        rows.append([code(name), m.faces, code(shape_text(m)), domain_text(m),
                     "yes" if m.wraps else "no", m.doc])
    return table(["name", "faces", "texture (H, W)", "domain", "Laplacian across face edges", "doc"], rows)


def mapper_figures() -> str:
    """One figure per mapper (docs/img/mapper_<name>.png, made by docs/make_figures.py)."""
    out = []
    for name, m in mappers.MAPPERS.items():
        out.append(f"### `{name}`\n\n{m.doc}. Texture {code(shape_text(m))}, {domain_text(m)}.\n\n"
                   f"![texel layout of the {name} mapper](img/mapper_{name}.png)\n")
    return "\n".join(out)


def projections_table() -> str:
    """The projections (``homofac.param.projections.PROJECTIONS``)."""
    rows = []
    for name, p in projections.PROJECTIONS.items():
        value = "scalar in [0, 1] (`line` texture)" if p.scalar else (
            "direction, z >= 0" if p.hemisphere else "direction on the sphere")
        rows.append([code(name), p.kind, value, ", ".join(code(c) for c in p.context) or "-", p.doc])
    return table(["name", "target kind", "value", "context", "doc"], rows)


def _factor_formula(p: parametrizations.Parametrization) -> str:
    return " ".join(f"{p.textures[f.texture]}({f.projection})" for f in p.factors)


def parametrizations_table() -> str:
    """The parametrizations (``homofac.param.parametrizations.PARAMETRIZATIONS``)."""
    rows = []
    for name, p in parametrizations.PARAMETRIZATIONS.items():
        tex = ", ".join(code(t) + (" (line)" if p.scalar(k) else "") for k, t in enumerate(p.textures))
        rows.append([code(name), p.kind, code(_factor_formula(p)), p.J, p.T, tex, p.doc])
    return table(["name", "target kind", "product (texture(projection) ...)", "J", "T", "textures", "doc"], rows)


def solvers_table() -> str:
    """The solvers (``homofac.fit.solvers.SOLVERS``) with their option models."""
    rows = []
    for name, s in solvers.SOLVERS.items():
        fields = ", ".join(code(f) for f in s.options.model_fields if f != "method")
        rows.append([code(name) + (" (default)" if name == solvers.DEFAULT else ""), s.doc,
                     code(s.options.__name__), rst_to_md(first_paragraph(s.options.__doc__)), fields])
    return table(["method", "doc", "option model", "options", "option fields"], rows)


def baselines_table() -> str:
    """The baselines (``homofac.baselines.BASELINES``): computed, not fitted, into the same model."""
    rows = []
    for name, b in baselines.BASELINES.items():
        fields = ", ".join(code(f) for f in b.options.model_fields)
        rows.append([code(name), rst_to_md(b.doc), code(b.options.__name__), fields or "-"])
    return table(["parametrization", "doc", "option model (`advanced.baseline`)", "option fields"], rows)


def baseline_options_section() -> str:
    """The ``advanced.baseline`` section: the option model of each baseline."""
    out = ["## `advanced.baseline` {#baseline-options}\n",
           "Options of a baseline `parametrization` (computed, not fitted; [Baselines](architecture.md#baselines)), "
           "validated by that baseline's option model. Refused with any other parametrization.\n"]
    for name, b in baselines.BASELINES.items():
        out.append(f"### `{name}` {{#baseline-{name.replace('_', '-')}}}\n")
        out.append(f"Model: `{b.options.__module__}.{b.options.__name__}`. {rst_to_md(first_paragraph(b.options.__doc__))}\n")
        out.append(model_table(b.options, "advanced.baseline", {}))
        out.append("")
    return "\n".join(out)


def languages_table() -> str:
    """The shading languages (``homofac.shader.languages.LANGUAGES``)."""
    rows = []
    for name, lang in languages.LANGUAGES.items():
        stem, ext = lang.file.rsplit(".", 1)
        rows.append([code(name), lang.title, code(lang.file), code(f"{stem}_8bit.{ext}")])
    return table(["name", "language", "file", "8-bit variant (with output.png)"], rows)


# --------------------------------------------------------------------------------------------------
# Layers (pyproject.toml, [tool.importlinter]) and validation


#: The layer names the docs use (L0 ... L7) for the packages of the import-linter contract.
LAYER_NAMES = {
    "homofac.app": "L7", "homofac.output": "L6", "homofac.gl": "L6", "homofac.fit": "L5", "homofac.light": "L4",
    "homofac.shader": "L4", "homofac.target": "L3", "homofac.factorization": "L3", "homofac.brdf": "L2",
    "homofac.param": "L2", "homofac.io": "L1", "homofac.baselines": "L5 (below fit)", "homofac.sphere": "L0", "homofac.options": "L0",
    "homofac.errors": "L0 (bottom)", "homofac._version": "L0 (bottom)",
}


def layer_contract() -> list[list[str]]:
    """The layers of the import-linter contract in pyproject.toml, top first; each a list of modules."""
    text = (ROOT / "pyproject.toml").read_text()
    if tomllib is not None:
        contract = next(c for c in tomllib.loads(text)["tool"]["importlinter"]["contracts"] if c["type"] == "layers")
        layers = contract["layers"]
    else:  # Python 3.10: the one list this needs, read directly
        block = re.search(r'type\s*=\s*"layers"\s*\nlayers\s*=\s*\[(.*?)\]', text, re.S).group(1)
        layers = re.findall(r'"([^"]+)"', block)
    return [[m.strip() for m in layer.split("|")] for layer in layers]


def _summary(module: str) -> str:
    doc = first_paragraph(importlib.import_module(module).__doc__)
    doc = re.sub(r"^homofac\.[a-z_.]+:\s*", "", doc)
    return rst_to_md(doc)


def layers_table() -> str:
    """One row per module of the layer contract, top layer first."""
    rows = []
    for layer in layer_contract():
        for k, module in enumerate(layer):
            rows.append([LAYER_NAMES.get(module, "") if k == 0 else "", code(module),
                         ", ".join(code(m) for m in layer if m != module) or "-", _summary(module)])
    return table(["layer", "module", "sibling (no imports either way)", "what it holds"], rows)


def _config(**keys) -> Callable[[], Any]:
    return lambda: config_mod.parse({"target": {"brdf": {"model": "ggx"}}, **keys})


#: Inputs the validation examples refuse: (what, the call that refuses it).
VALIDATION_EXAMPLES: list[tuple[str, Callable[[], Any]]] = [
    ("config: a key misspelt", _config(sampling={"sise": 8})),
    ("Python API: the same key", lambda: validate(fit_options.SamplingOptions, {"sise": 8}, "sampling")),
    ("config: a value out of range", _config(texture_size=2)),
    ("config: a BRDF parameter's rule", lambda: config_mod.parse({"target": {"brdf": {"model": "ggx", "roughness": 0}}})),
    ("config: an unknown solver", _config(solver={"method": "gmres"})),
    ("config: a string where a number belongs", _config(solver={"tolerance": "small"})),
    ("Python API: `factorize(..., texture_size=1.5)`", lambda: fit_pipeline.options("NR", texture_size=1.5)),
]


def validation_examples() -> str:
    """The one-line messages homofac gives for a few bad inputs (computed, not copied)."""
    rows = []
    for what, call in VALIDATION_EXAMPLES:
        try:
            call()
            msg = "(accepted)"
        except HomofacError as e:
            msg = str(e)
        rows.append([what, code(msg)])
    return table(["input", "message"], rows)


# --------------------------------------------------------------------------------------------------
# BRDF models


def _kind_text(kind: str) -> str:
    return {"color": "colour: a number or [r, g, b]", "scalar": "a number", "array": "an array"}.get(kind, kind)


def model_parameters(name: str) -> list[list[str]]:
    """Rows (parameter, default, value, rule) of a registered BRDF model, from its ModelSpec and the rules."""
    spec = brdf.MODELS[name]
    rows = []
    if spec.schema is not None:  # the config takes other parameters than Python (merl: file, not table)
        for pname, (typ, default) in spec.schema.items():
            d = "required" if default is ... else code(yaml_value(default))
            value = "a string (a file path, relative to the config file)" if typ is str else getattr(typ, "__name__", str(typ))
            rows.append([code(pname), d, value, "the config; Python: `make(..., file=)`"])
    for pname, default in spec.defaults.items():
        kind, _, _, _, rule = brdf_core._rule_for(pname, default)
        d = "required" if default is None else code(yaml_value(_plain(default)))
        where = f"Python only (`make({name!r}, {pname}=...)`)" if spec.schema is not None else "config and Python"
        rows.append([code(pname), d, _kind_text(kind), rule + ("" if spec.schema is None else f"; {where}")])
    return rows


def _plain(v: Any) -> Any:
    if isinstance(v, tuple):
        return [_plain(x) for x in v]
    return v


def _title(doc: str) -> str:
    """The model's name from the first line of its doc: ``Name: formula`` or ``Name (source).``"""
    head = inspect.cleandoc(doc or "").split("\n", 1)[0]
    if ":" in head:
        return head.split(":", 1)[0].strip()
    return head.split(" (", 1)[0].rstrip(".").strip()


def models_summary() -> str:
    """One line per registered BRDF model."""
    rows = []
    for name, spec in brdf.MODELS.items():
        params = list(spec.schema) if spec.schema is not None else list(spec.defaults)
        rows.append([f"[{code(name)}](#{name})", _title(spec.doc),
                     ", ".join(code(p) for p in params), "yes" if spec.reciprocal else "no",
                     spec.energy_conserving or "none guaranteed"])
    return table(["model", "name", "parameters", "reciprocal", "energy conserved if"], rows)


def models_page() -> str:
    """A section per registered BRDF model: formula and source, parameters, reciprocity, energy."""
    out = []
    for name, spec in brdf.MODELS.items():
        doc = inspect.cleandoc(spec.doc or "")
        head, _, rest = doc.partition("\n")
        title, _, formula = head.partition(":")
        out.append(f"## `{name}` {{#{name}}}\n")
        out.append(f"**{title.strip()}**" + (f": {code(formula.strip().rstrip('.'))}" if formula.strip() else ""))
        out.append("")
        if rest.strip():
            out.append(fenced(rest.strip("\n"), "text"))
            out.append("")
        out.append(table(["parameter", "default", "value", "rule"], model_parameters(name)))
        out.append("")
        facts = [
            f"- **Reciprocal** (f(wi, wo) = f(wo, wi)): {'yes' if spec.reciprocal else 'no'}.",
            f"- **Energy conservation** (directional albedo <= 1 for every view): "
            + (code(spec.energy_conserving) if spec.energy_conserving else "not guaranteed by any condition on the parameters") + ".",
            f"- **Lobe form** (kd/pi + sum of scalar lobes times RGB colours, one matmul per lobe in the lighting sum): "
            f"{_lobes_text(name)}.",
            f"- **Lobe culling** (`target.lobe_cull`): {'supported' if spec.support is not None else 'not supported (ignored)'}.",
            f"- **Split-sum baseline** (needs a microfacet distribution): "
            f"{'supported' if getattr(spec, 'microfacet', None) is not None else 'refused'}.",
            f"- Python: `hf.brdf.make({name!r}, ...)`" + (f" or `hf.brdf.{name}(...)`" if hasattr(brdf, name) else "") + ".",
        ]
        out.append("\n".join(facts))
        out.append("")
    return "\n".join(out)


def _lobes_text(name: str) -> str:
    spec = brdf.MODELS[name]
    if spec.lobes is None:
        return "no (evaluated in RGB per light)"
    count = _lobe_count(name)
    if count == 0:
        return "yes, no lobe: only kd/pi E(n), no per-light evaluation"
    return f"yes, {count} lobe{'s' if count > 1 else ''}"


def _lobe_count(name: str) -> int:
    spec = brdf.MODELS[name]
    try:
        return len(spec.colors(brdf.make(name).params))
    except Exception:  # noqa: BLE001 - a model that needs a file to be made
        return 0


# --------------------------------------------------------------------------------------------------
# The config reference, from the pydantic option models


def _anchor(model: type) -> str:
    return model.__name__.lower()


def type_text(ann: Any, links: dict) -> str:
    """A readable type of a pydantic annotation (nested option models link to their section)."""
    origin = typing.get_origin(ann)
    args = typing.get_args(ann)
    if ann is type(None):
        return "null"
    if origin is typing.Annotated:
        return type_text(args[0], links)
    if origin is typing.Literal:
        return " or ".join(code(yaml_value(a)) for a in args)
    if origin in (typing.Union, types.UnionType):
        members = [a for a in args if a is not type(None)]
        models = [typing.get_args(a)[0] if typing.get_origin(a) is typing.Annotated else a for a in members]
        def every(base: type) -> bool:
            return bool(models) and all(isinstance(m, type) and issubclass(m, base) for m in models)

        if every(solvers.SolverOptions):
            text = "[one of the solver option models](#solver-options), by `method`"
        elif every(brdf_core.BRDFOptionsBase):
            text = "[one of the BRDF models' option models](models.md), by `model`"
        else:
            text = " or ".join(type_text(a, links) for a in members)
        return text + (" or null" if type(None) in args else "")
    if origin in (list, tuple):
        return "list of " + (type_text(args[0], links) if args else "values")
    if origin is dict:
        return "mapping"
    if isinstance(ann, type) and issubclass(ann, pydantic.BaseModel):
        name = links.get(ann, ann.__name__)
        return f"[{name}](#{_anchor(ann)})"
    return {int: "integer", float: "number", bool: "boolean", str: "string", typing.Any: "any"}.get(ann, getattr(ann, "__name__", str(ann)))


def constraint_text(info: FieldInfo) -> str:
    parts = []
    lengths = {type(m).__name__: m for m in info.metadata if isinstance(m, (annotated_types.MinLen, annotated_types.MaxLen))}
    if len(lengths) == 2 and lengths["MinLen"].min_length == lengths["MaxLen"].max_length:
        parts.append(f"length {lengths['MinLen'].min_length}")
    for m in info.metadata:
        if parts and isinstance(m, (annotated_types.MinLen, annotated_types.MaxLen)) and len(lengths) == 2 and \
                lengths["MinLen"].min_length == lengths["MaxLen"].max_length:
            continue
        if isinstance(m, annotated_types.Ge):
            parts.append(f">= {m.ge}")
        elif isinstance(m, annotated_types.Gt):
            parts.append(f"> {m.gt}")
        elif isinstance(m, annotated_types.Le):
            parts.append(f"<= {m.le}")
        elif isinstance(m, annotated_types.Lt):
            parts.append(f"< {m.lt}")
        elif isinstance(m, annotated_types.MinLen):
            parts.append(f"length >= {m.min_length}")
        elif isinstance(m, annotated_types.MaxLen):
            parts.append(f"length <= {m.max_length}")
        elif type(m).__name__ == "AllowInfNan" and not getattr(m, "allow_inf_nan", True):
            parts.append("finite")
    return ", ".join(parts)


#: Notes for fields that carry no pydantic ``description`` (the description wins when there is one).
NOTES = {
    "Config.parametrization": "a registered parametrization of the target's kind ([table](architecture.md#parametrizations)), "
                              "or a [baseline](architecture.md#baselines)",
    "Config.preset": "`fast`, `balanced` or `best`: 4, 8 or 16 texture lookups per pixel with the settings measured "
                     "for that budget ([Choosing a preset](presets.md)); null: `balanced` unless a key names the fit",
    "Config.max_lookups": "the lookup budget: homofac chooses the structure within this many texture lookups per "
                          "pixel by validation error; null: the preset's",
    "Config.terms": "K products of the parametrization summed (a sum of products, [Sums of products](sums.md))",
    "Config.diffuse": "`exact`: the computed term kd/pi E(n); `fitted`: an n-only texture started from it; null: none",
    "Config.nv_factor": "a 1D `line` texture w(n.v) in each product",
    "Config.advanced": "the research keys ([below](#advancedoptions)): a preset sets what they decide",
    "AdvancedOptions.reflection": "lighting: one more fitted term, an r-only texture q(r)",
    "AdvancedOptions.prefiltered": "lighting: the split sum's P(r) W(n.v) computed and kept; the products fit "
                                   "corrections to it",
    "AdvancedOptions.rw_terms": "lighting: this many more fitted terms q(r) w(n.v) beside the K products",
    "AdvancedOptions.highlights": "the highlight terms of the brightest lights ([below](#highlightoptions))",
    "AdvancedOptions.line_size": "texels of a sum's `line` textures; null: 32, or the `best` preset's vote "
                                 "between 32 and 4 x texture_size",
    "AdvancedOptions.linear": "the linear-space fit of a sum ([below](#linearoptions)); null: the defaults and the preset's "
                              "nv_balance, polish and ridge",
    "AdvancedOptions.baseline": "options of a baseline parametrization ([below](#baseline-options)); null: its defaults",
    "HighlightOptions.terms": "J highlight terms d(nh_dom) w(n.v) of the J brightest lights; with a chooser, only "
                              "candidates with J (0: none); null: the chooser's 0-2",
    "HighlightOptions.fresnel": "each highlight term also reads f(v.h') of its light (one lookup more)",
    "HighlightOptions.cosine": "each highlight term also reads c(n.i) of its light (one lookup more)",
    "HighlightOptions.table": "each highlight term reads a 2D table T(n.i, n.v) in place of c(n.i) w(n.v)",
    "HighlightOptions.disc": "each highlight term reads its light's coordinate at the disc's point closest to r; "
                             "null: the `best` preset's vote",
    "Config.mapper": "mapper of the direction textures; null: parabolic (BRDF) or dual_paraboloid (lighting). "
                     "`line` is refused here (it is the mapper of scalar factors)",
    "Config.texture_size": "S of the mapper: textures are (S, S), (S, 2S) dual_paraboloid, (S, 6S) cube",
    "Config.target_error": "validation nrmse (float textures) to meet with the cheapest candidate; "
                           "parametrization and texture_size are then the limits of the search",
    "Config.sampling": "training pairs and the validation set",
    "Config.solver": "solver and system parameters; the `method` key selects the option model",
    "Config.target": "what is factored",
    "Config.output": "what is written",
    "Config.limits": "resource limits checked before any work",
    "TargetOptions.kind": "`lighting`: L(v, n) under an environment; `brdf`: the BRDF itself",
    "TargetOptions.brdf": "`{model: name, ...parameters}`; the parameters of each model are on the [Models](models.md) page",
    "TargetOptions.environment": "lighting only; null: the defaults (bundled `forest`, resolution 32)",
    "TargetOptions.quantity": "brdf only: `brdf` (f, as McCool et al.) or `brdf_cos` (f cos theta_i); null: `brdf`",
    "TargetOptions.clamp": "lighting only: factor min(L(v, n), clamp) (Latta & Kolb clamp to 1 ... 4)",
    "TargetOptions.lobe_cull": "Phong family only: skip lights where every lobe is below this fraction of its peak",
    "SamplingOptions.kind": "`texels`: reverse-projected texel centres of `mapper`; `latlong`: a lat-long grid; "
                            "`random`: `count` uniform valid pairs",
    "SamplingOptions.size": "grid size of the first direction (wi, h or n): mapper S, or phi steps for latlong",
    "SamplingOptions.view_size": "the same for the second direction (wo, d or v); null: `size`",
    "SamplingOptions.validation": "number of random validation pairs (seed `seed + 1`)",
    "SamplingOptions.seed": "seed of `random` training pairs; the validation set uses `seed + 1`",
    "SamplingOptions.count": "number of `random` pairs; 0: size^2 view_size^2 / 4",
    "SamplingOptions.mapper": "mapper whose texel grid `texels` reverse-projects; null: parabolic (BRDF) or dual_paraboloid (lighting)",
    "SamplingOptions.cache": "reuse the samples of an identical (target, sampling) from `$HOMOFAC_CACHE_DIR` "
                             "(default `~/.cache/homofac/samples`)",
    "SolverOptions.method": "the solver ([table](#solver-options))",
    "EnvironmentOptions.file": "a bundled name (" + ", ".join(homofac.light.BUNDLED) + "), a lat-long EXR or HDR file, "
                               "a cube map file, or a directory of six faces; relative to the config file",
    "EnvironmentOptions.boost": "highlight boost before resampling; null: off",
    "EnvironmentOptions.lights": "extra lights beside the map",
    "EnvironmentOptions.cull": "drop the weakest lights holding at most this fraction of the total power; null: off",
    "BoostOptions.threshold": "pixels above threshold x the maximum luminance are boosted",
    "BoostOptions.factor": "their scale factor",
    "LightOptions.type": "`directional`, or `point` (treated as directional: the environment is distant)",
    "LightOptions.direction": "direction towards the light, world frame (+z up)",
    "LightOptions.position": "point lights: position; irradiance = intensity / |position|^2",
    "LightOptions.irradiance": "irradiance at a surface facing the light (a number or [r, g, b]); null: 1",
    "LightOptions.intensity": "point lights: intensity (a number or [r, g, b])",
    "OutputOptions.dir": "output directory, relative to the config file (the CLI's --out overrides it)",
    "OutputOptions.png": "also write the 8-bit RGBA textures `<name>.png` with their decode rule",
    "OutputOptions.ktx2": "also write each texture as `<name>.ktx2` (KTX 2.0, half float; [KTX2 textures](format.md#ktx2-textures)); "
                          "`--ktx2` on the CLI",
    "OutputOptions.samples": "write `samples.npz` (a, b, y, val_a, val_b, val_y)",
    "OutputOptions.exr": "pixel type of the EXR textures",
    "OutputOptions.alpha": "use the alpha channel of the 8-bit textures (thesis §4.3.2)",
    "OutputOptions.prescale": "the T + 1 weights w_0 ... w_T of thesis §4.3.1 (correction, then textures); "
                              "one-term factorizations with non-negative textures only",
    "OutputOptions.preview": "write `preview.png` (needs OpenGL through EGL; skipped with a warning otherwise)",
    "OutputOptions.shaders": "shader files to write ([languages](shaders.md))",
    "AdvancedOptions.analysis": "record Mahajan et al.'s in-out analysis of the target in factorization.json "
                                "(`analysis`); null: the preset's",
    "AnalysisOptions.pair": "grid the target on (n, r) or (n, v)",
    "AnalysisOptions.mapper": "mapper whose texel centres are the grid",
    "AnalysisOptions.size": "S of that mapper",
    "SplitSumOptions.irradiance": "E(n) exactly (the clamped-cosine texel integrals) or from 9 spherical-harmonic coefficients",
    "SplitSumOptions.weighting": "P(r) weights the NDF by max(r.l, 0) (`karis`) or not (`plain`)",
    "SplitSumOptions.line_size": "texels of the 1D W(n.v) texture (the DFG table)",
    "KautzMcCoolOptions.slices": "view-elevation slices: 1 is the single 2D lobe, K > 1 gives K terms",
    "LimitsOptions.memory_gb": "refuse configs whose estimated peak memory exceeds this; null: half of what "
                               "the process may use (RAM, ulimit -v, cgroup memory.max)",
}


def default_text(info: FieldInfo) -> str:
    if info.default_factory is not None:
        v = info.default_factory()
        if isinstance(v, pydantic.BaseModel):
            return "its defaults"
        return code(yaml_value(v))
    if info.default is PydanticUndefined:
        return "**required**"
    if isinstance(info.default, pydantic.BaseModel):
        return "its defaults"
    return code(yaml_value(info.default))


#: The order of the top-level keys in the config reference: what a user decides first, ``advanced`` last.
TOP_ORDER = ("target", "preset", "max_lookups", "texture_size", "output", "parametrization", "mapper", "terms",
             "diffuse", "nv_factor", "target_error", "sampling", "solver", "limits", "advanced")


def _top_rank(key: str) -> int:
    top = key.split(".")[0].removesuffix("[]")
    return TOP_ORDER.index(top) if top in TOP_ORDER else len(TOP_ORDER) - 1


def model_table(model: type[pydantic.BaseModel], key: str, links: dict, notes_for: tuple[str, ...] = ()) -> str:
    """The fields of one option model: key, type, default, constraints, description (the top level in
    :data:`TOP_ORDER`)."""
    rows = []
    owners = (model.__name__,) + notes_for
    fields = list(model.model_fields.items())
    if not key:
        fields.sort(key=lambda kv: _top_rank(kv[0]))
    for name, info in fields:
        desc = info.description or next((NOTES[f"{o}.{name}"] for o in owners if f"{o}.{name}" in NOTES), "")
        full = f"{key}.{name}" if key else name
        rows.append([code(full), type_text(info.annotation, links), default_text(info), constraint_text(info) or "-",
                     desc or "-"])
    return table(["key", "type", "default", "constraints", "description"], rows)


def _models_in(annotation: Any) -> list[type[pydantic.BaseModel]]:
    """The pydantic models inside an annotation (``Optional[M]``, ``list[M]``, unions, ``Annotated``)."""
    out, stack = [], [annotation]
    while stack:
        a = stack.pop(0)
        if isinstance(a, type) and issubclass(a, pydantic.BaseModel):
            out.append(a)
            continue
        stack.extend(typing.get_args(a))
    return out


def _is_list(annotation: Any) -> bool:
    if typing.get_origin(annotation) in (list, tuple):
        return True
    return any(_is_list(a) for a in typing.get_args(annotation) if a is not type(None))


def config_sections() -> list[tuple[type, str]]:
    """Every option model of the config with its key, walked from ``Config`` depth first in field order.

    A union of solver option models is documented once as their common base ``SolverOptions`` (plus the
    per-method table); the BRDF models' union is the [Models](models.md) page.
    """
    out: list[tuple[type, str]] = []

    def visit(model: type, key: str) -> None:
        if any(m is model for m, _ in out):
            return
        out.append((model, key))
        for name, info in model.model_fields.items():
            sub = f"{key}.{name}" if key else name
            models = _models_in(info.annotation)
            if _is_list(info.annotation):
                sub += "[]"
            if len(models) == 1:
                visit(models[0], sub)
            elif models and all(issubclass(m, solvers.SolverOptions) for m in models):
                visit(solvers.SolverOptions, sub)

    visit(config_mod.Config, "")
    return sorted(out, key=lambda mk: -1 if not mk[1] else _top_rank(mk[1]))


def config_models() -> list[type]:
    """Every option model the config reference documents (the tests check them all)."""
    return [m for m, _ in config_sections()] + [s.options for s in solvers.SOLVERS.values()] + \
        [b.options for b in baselines.BASELINES.values()]


def config_reference() -> str:
    """The config reference: one table per option model the config is assembled from."""
    sections = config_sections()
    links = {m: (key or "top level") for m, key in sections}
    out = []
    for model, key in sections:
        out.append(f"## `{key}` {{#{_anchor(model)}}}\n" if key else f"## Top level {{#{_anchor(model)}}}\n")
        out.append(f"Model: `{model.__module__}.{model.__name__}`. {rst_to_md(first_paragraph(model.__doc__))}\n")
        notes = ("Config", "FitOptions") if model is config_mod.Config else ()
        out.append(model_table(model, key, links, notes))
        out.append("")
        if model is solvers.SolverOptions:
            out.append(solver_options_section())
    out.append(baseline_options_section())
    return "\n".join(out)


def solver_options_section() -> str:
    out = ["### Solver options {#solver-options}\n",
           "`solver.method` selects the option model; every model has the common fields above "
           "(unknown keys are errors for each).\n"]
    rows = []
    for name, s in solvers.SOLVERS.items():
        rows.append([code(name), code(f"{s.options.__module__}.{s.options.__name__}"),
                     rst_to_md(first_paragraph(s.options.__doc__)), s.doc])
    out.append(table(["method", "option model", "notes", "solver"], rows))
    out.append("")
    return "\n".join(out)


def default_config() -> str:
    """The bundled default config, verbatim."""
    path = config_mod.default_config_path()
    return fenced(path.read_text(), "yaml")


def brdf_config_keys() -> str:
    """The ``target.brdf`` keys of every model (from the option models the registry generates)."""
    rows = []
    for name in brdf.MODELS:
        model = brdf.options_model(name)
        keys = [k for k in model.model_fields if k != "model"]
        rows.append([code(f"model: {name}"), ", ".join(code(k) for k in keys), f"[{name}](models.md#{name})"])
    return table(["target.brdf", "keys", "parameters"], rows)


# --------------------------------------------------------------------------------------------------
# CLI


def _help(parser) -> str:
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"
    try:
        return parser.format_help()
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old


def cli_fit() -> str:
    """``python -m homofac.fit --help``."""
    return fenced("$ python -m homofac.fit --help\n" + _help(cli.fit_parser()), "text")


def cli_preview() -> str:
    """``python -m homofac.preview --help``."""
    return fenced("$ python -m homofac.preview --help\n" + _help(cli.preview_parser()), "text")


def cli_view() -> str:
    """``python -m homofac.view --help``."""
    return fenced("$ python -m homofac.view --help\n" + _help(cli.view_parser()), "text")


def version() -> str:
    return homofac.__version__


# --------------------------------------------------------------------------------------------------
# A real output directory, written with the Python API at build time

#: The example of the Output format page: the default config's material and environment, small sizes.
EXAMPLE_CONFIG = {
    "target": {
        "kind": "lighting",
        "brdf": {"model": "cook_torrance", "kd": [0.05, 0.04, 0.02], "ks": 1.0, "roughness": 0.3,
                 "f0": [1.0, 0.78, 0.34]},
        "environment": {"file": "forest", "resolution": 8},
    },
    "parametrization": "NR",
    "mapper": "dual_paraboloid",
    "texture_size": 8,
    "sampling": {"kind": "texels", "size": 8, "validation": 2000, "seed": 0, "cache": False},
    "solver": {"method": "lsmr"},
    "output": {"png": True, "samples": True, "preview": False, "shaders": ["glsl"]},
}


@functools.lru_cache(maxsize=1)
def example() -> dict:
    """Run the example config through :func:`homofac.app.run.run` (as the CLI does) and read back what it wrote.

    Returns ``{"doc": factorization.json, "files": [(name, bytes)], "shader": shader.glsl,
    "two_terms": the document of the split-sum baseline of the same target (several terms)}``.
    """
    cli.enable_compilation_cache()  # as the CLI does: ~/.cache/homofac/jax, HOMOFAC_JAX_CACHE=0 turns it off
    with tempfile.TemporaryDirectory(prefix="homofac-docs-") as tmp:
        base = Path(tmp)
        cfg = config_mod.parse(EXAMPLE_CONFIG, "docs example")
        fac, out = run(cfg, base, str(base / "out"), preview=False)
        doc = json.loads((out / "factorization.json").read_text())
        files = sorted((p.name, p.stat().st_size) for p in out.iterdir())
        shader = (out / "shader.glsl").read_text()
        # Schema 2 with several terms: the split-sum baseline of the same target, with the Python API.
        split = homofac.fit.factorize(fac.target, "split_sum", mapper=cfg.mapper, texture_size=cfg.texture_size,
                                      samples=fac.samples)
        split_out = split.save(base / "split_sum", png=True)
        two_doc = json.loads((split_out / "factorization.json").read_text())
    return {"doc": doc, "files": files, "shader": shader, "two_terms": two_doc}


def compact_json(v: Any, indent: int = 0, width: int = 100, prefix: int = 0) -> str:
    """JSON with short lists and objects on one line (what a person reads), otherwise indented by 2.

    ``prefix`` is the width of what precedes the value on its line (a key).
    """
    flat = json.dumps(v)
    if indent + prefix + len(flat) <= width or not isinstance(v, (dict, list)) or not v:
        return flat
    pad, inner = " " * indent, " " * (indent + 2)
    if isinstance(v, dict):
        items = [f"{inner}{json.dumps(k)}: {compact_json(x, indent + 2, width, len(json.dumps(k)) + 2)}"
                 for k, x in v.items()]
        return "{\n" + ",\n".join(items) + "\n" + pad + "}"
    items = [inner + compact_json(x, indent + 2, width) for x in v]
    return "[\n" + ",\n".join(items) + "\n" + pad + "]"


def _display(doc: dict) -> dict:
    """A document as the docs show it: floats to 6 digits, the machine's absolute paths shortened."""
    text = json.dumps(_rounded(doc))
    text = re.sub(r'"[^"]*?/(homofac/data/[^"]*)"', r'".../\1"', text)
    return json.loads(text)


def _rounded(v: Any, digits: int = 6) -> Any:
    if isinstance(v, float):
        return float(f"{v:.{digits}g}")
    if isinstance(v, list):
        return [_rounded(x, digits) for x in v]
    if isinstance(v, dict):
        return {k: _rounded(x, digits) for k, x in v.items()}
    return v


def example_json() -> str:
    """The example's factorization.json, whole (floats rounded to 6 digits for reading)."""
    return fenced(compact_json(_display(example()["doc"])), "json")


def example_two_terms() -> str:
    """The keys of a several-term document that differ from the one-term example."""
    d = _display(example()["two_terms"])
    short = {k: d[k] for k in ("format", "schema_version", "kind", "name", "textures", "terms", "lookups")}
    short["metrics"] = {"validation": {"float": d["metrics"]["validation"]["float"]}}
    short["solver"] = d["solver"]
    return fenced(compact_json(short), "json")


def example_files() -> str:
    rows = [[code(name), f"{size:,}"] for name, size in example()["files"]]
    return table(["file", "bytes"], rows)


def example_config() -> str:
    return fenced(yaml.safe_dump(EXAMPLE_CONFIG, sort_keys=False, default_flow_style=None), "yaml")


def example_shader() -> str:
    return fenced(example()["shader"], "glsl")


def example_metric(path: str) -> str:
    """One number of the example's document, e.g. ``metrics.validation.float.nrmse``."""
    v: Any = example()["doc"]
    for part in path.split("."):
        v = v[part]
    return f"{v:.3g}" if isinstance(v, float) else str(v)


# --------------------------------------------------------------------------------------------------
# API pages


def submodules(package: str) -> list[str]:
    """Every public submodule of a package, recursively, in alphabetical order (``__main__`` excluded)."""
    mod = importlib.import_module(package)
    if not hasattr(mod, "__path__"):
        return []
    out = []
    for info in sorted(pkgutil.iter_modules(mod.__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        name = f"{package}.{info.name}"
        out.append(name)
        if info.ispkg:
            out += submodules(name)
    return out


def own_names(module: str) -> list[str]:
    """Public names a module defines itself (functions, classes, assignments), not the ones it imports.

    For a package these are what its ``__init__`` defines (``homofac.fit.solvers.solve``); its
    re-exports are documented in the submodules that define them.
    """
    mod = importlib.import_module(module)
    tree = ast.parse(inspect.getsource(mod))
    names: list[str] = []
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.append(node.name)
        elif isinstance(node, ast.Assign):
            names += [t.id for t in node.targets if isinstance(t, ast.Name)]
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.append(node.target.id)
    listed = getattr(mod, "__all__", None)
    return [n for n in dict.fromkeys(names) if not n.startswith("_") and (listed is None or n in listed)]


def _documents(module: str, name: str) -> bool:
    """True when the API pages render ``module.name`` (a homofac module's own public name)."""
    return module.startswith("homofac.") and name in own_names(module)


def _defined_in(package: str, name: str, subs: list[str]) -> str | None:
    """The module whose section of the API pages documents a name the package re-exports."""
    mod = importlib.import_module(package)
    obj = getattr(mod, name, None)
    if isinstance(obj, types.ModuleType):
        return obj.__name__
    where = getattr(obj, "__module__", None)
    if isinstance(where, str) and _documents(where, name):
        return where
    for sub in [package] + sorted(subs, key=lambda s: (s.count("."), s)):
        if _documents(sub, name) and getattr(importlib.import_module(sub), name) is obj:
            return sub
    return None


def exports_table(package: str) -> str:
    """What a package re-exports, each name linked to the section of the submodule that documents it."""
    subs = submodules(package)
    mod = importlib.import_module(package)
    rows = []
    own = set(own_names(package))
    for n in [n for n in getattr(mod, "__all__", ()) if not n.startswith("__") and n not in own]:
        where = _defined_in(package, n, subs)
        obj = getattr(mod, n, None)
        what = "module" if isinstance(obj, types.ModuleType) else ("class" if inspect.isclass(obj) else (
            "function" if callable(obj) else "data"))
        if what == "module":
            rows.append([f"[`{n}`][{where}]", what, f"`{where}`"])
        elif where is not None:
            rows.append([f"[`{n}`][{where}.{n}]", what, f"`{where}`"])
        else:
            rows.append([code(n), what, "-"])
    if not rows:
        return ""
    return f"`{package}` exports (`from {package} import ...`):\n\n" + table(["name", "kind", "defined in"], rows) + "\n"


def _directive(module: str, root: bool, members: list[str] | None) -> str:
    opts = ["    options:"]
    if root:
        opts += ["      show_root_heading: false", "      show_root_toc_entry: false"]
    else:
        opts += ["      show_root_heading: true", "      heading_level: 2"]
    if members is not None:
        opts.append(f"      members: {json.dumps(members) if members else 'false'}")
    return f"::: {module}\n" + "\n".join(opts) + "\n"


def api(package: str, mode: str = "page") -> str:
    """An API page: every module of a package with its docstring and public members (``__all__``).

    A package shows its docstring and a table of what it re-exports (linked to where each name is
    documented); each module shows its docstring and members, so every object is documented once.
    ``mode``: ``page`` (the package is the page's subject: no heading of its own) or ``section`` (one
    of several packages on a page: it gets a heading like its submodules).
    """
    out = []
    for k, name in enumerate([package] + submodules(package)):
        is_package = hasattr(importlib.import_module(name), "__path__")
        out.append(_directive(name, root=k == 0 and mode == "page", members=own_names(name) if is_package else None))
        if is_package:
            out.append(exports_table(name))
    return "\n".join(out)


# --------------------------------------------------------------------------------------------------
# The hook


class _DocstringRefs(logging.Filter):
    """Unresolvable cross-references written in homofac's docstrings are reported, not fatal.

    mkdocs-autorefs warns about every reference it cannot resolve, and ``--strict`` turns warnings into
    errors. A docstring may name an object that no page renders (a private helper, a module that moved);
    that must not break the docs build, so such warnings (their context is a ``.py`` file) become INFO.
    References in the Markdown pages stay warnings.
    """

    def filter(self, record: logging.LogRecord) -> bool:
        msg = record.getMessage()
        if record.levelno == logging.WARNING and "Could not find cross-reference target" in msg and ".py:" in msg:
            record.levelno, record.levelname = logging.INFO, "INFO"
        return True


def _install_filters() -> None:
    logger = logging.getLogger("mkdocs.plugins.mkdocs_autorefs._internal.plugin")
    if not any(isinstance(f, _DocstringRefs) for f in logger.filters):
        logger.addFilter(_DocstringRefs())


def on_startup(command, dirty) -> None:  # noqa: ARG001 - the mkdocs hook signature
    _install_filters()


_install_filters()

def presets_table() -> str:
    """What each preset sets (homofac.fit.plan.PRESETS)."""
    from homofac.fit.plan import PRESETS  # noqa: PLC0415

    rows = []
    for name, p in PRESETS.items():
        lines = "32" if not p.line_ratio else f"vote 32 / {p.line_ratio} x texture_size"
        rows.append([code(name), p.lookups, f"{p.grid_count:,}", f"{p.validation:,}", lines, "yes" if p.table else "no",
                     "vote" if p.disc_vote else "no", p.nv_balance,
                     f"{p.polish} steps" + (f" on every {p.polish_stride}th pair" if p.polish_stride > 1 else "") + ", kept by vote"
                     if p.polish else "none",
                     f"{p.ridge:,}" if p.ridge else "0", ", ".join(p.directions) or "all"])
    return table(["preset", "lookups", "grid pairs", "validation pairs", "line texels", "highlight tables",
                  "light disc", "nv_balance (kd > 0)", "polish", "ridge pairs", "grid directions"], rows)


GENERATORS: dict[str, Callable[..., str]] = {
    "presets": presets_table,
    "mappers": mappers_table,
    "mapper_figures": mapper_figures,
    "projections": projections_table,
    "parametrizations": parametrizations_table,
    "solvers": solvers_table,
    "languages": languages_table,
    "baselines": baselines_table,
    "layers": layers_table,
    "validation_examples": validation_examples,
    "models_summary": models_summary,
    "models": models_page,
    "config": config_reference,
    "brdf_config": brdf_config_keys,
    "default_config": default_config,
    "cli_fit": cli_fit,
    "cli_preview": cli_preview,
    "cli_view": cli_view,
    "version": version,
    "example_config": example_config,
    "example_json": example_json,
    "example_two_terms": example_two_terms,
    "example_files": example_files,
    "example_shader": example_shader,
    "example_metric": example_metric,
    "api": api,
}


def expand(markdown: str, where: str = "") -> str:
    """``markdown`` with every ``<!-- homofac:NAME ARGS -->`` marker replaced by its generated text."""

    def one(m: re.Match) -> str:
        name, args = m.group(1), m.group(2).split()
        if name not in GENERATORS:
            raise KeyError(f"{where}: unknown docs generator {name!r} (known: {', '.join(GENERATORS)})")
        return GENERATORS[name](*args)

    return MARKER.sub(one, markdown)


def format_keys() -> set[str]:
    """The keys format.md must document: those the example documents contain and those load() reads."""
    from homofac import output  # noqa: PLC0415

    keys: set[str] = set()
    for doc in (example()["doc"], example()["two_terms"]):
        keys |= set(doc)
        for part in ("textures", "terms"):
            for entry in doc[part]:
                keys |= set(entry)
        for term in doc["terms"]:
            for factor in term["factors"]:
                keys |= set(factor)
    for model in (output.Document, output.TextureEntry, output.TermEntry, output.FactorEntry, output.PngDecode):
        keys |= set(model.model_fields)
    return keys


def undocumented_keys(markdown: str) -> list[str]:
    """Keys of factorization.json that a page does not mention as ``key``."""
    return sorted(k for k in format_keys() if f"`{k}`" not in markdown)


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ARG001 - the mkdocs hook signature
    out = expand(markdown, page.file.src_path)
    if page.file.src_path == "format.md":
        missing = undocumented_keys(out)
        if missing:
            log.warning("format.md: factorization.json keys not documented: %s", ", ".join(missing))
    return out
