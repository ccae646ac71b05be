"""The YAML configuration: assembled from the option models of the layers, read strictly.

:class:`Config` is the top level of a config file. It *extends* :class:`homofac.fit.options.FitOptions`
(the keywords of ``hf.fit.factorize``) with ``target`` (the BRDF option models generated from the BRDF
registry, :class:`homofac.light.options.EnvironmentOptions`), ``output``
(:class:`homofac.output.OutputOptions`) and ``limits``. So a key or value is checked in exactly one
place, for the CLI and the Python API alike; unknown keys name the key and suggest the closest one.

The YAML reader refuses what PyYAML would silently accept or crash on: duplicate keys (last-wins),
invalid UTF-8, nesting deeper than :data:`MAX_DEPTH`, files larger than :data:`MAX_BYTES`. Relative
paths are relative to the config file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal, Optional

import yaml
from pydantic import Field, model_validator

from .. import brdf
from ..errors import HomofacError
from ..fit.options import DEFAULT_PRESET, FitOptions, names_a_fit, upgrade_record
from ..fit.scene import bundled_path as bundled_scene
from ..io.files import check_regular, read_bounded
from ..light import BUNDLED, EnvironmentOptions
from ..options import Options, validate
from ..output import OutputOptions

#: Config files larger than this are refused (a config is a few hundred bytes).
MAX_BYTES = 1 << 20
#: Deepest nesting of mappings and lists accepted in a config.
MAX_DEPTH = 32


#: A material's name: a plain file name (its output directory), letters, digits, ``_`` and ``-``.
MATERIAL_NAME = r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$"
#: Most materials in one config (a library).
MAX_MATERIALS = 256
#: The BRDF option models of the registry, as one union tagged by ``model``.
BrdfOptions = brdf.options_union()


class MaterialOptions(Options):
    """``target.materials[]``: one material of a library: its name (the name of its output directory)
    and its BRDF (one of the BRDF registry's option models, by ``model``)."""

    name: str = Field(pattern=MATERIAL_NAME, description="the material's output directory under output.dir: "
                      "letters, digits, _ and - (at most 64; unique, ignoring case)")
    brdf: BrdfOptions  # type: ignore[valid-type]


class TargetOptions(Options):
    """``target``: what is factored. ``brdf`` is one of the BRDF registry's option models (by ``model``);
    ``materials`` instead of ``brdf`` makes a material library (one layout, one output directory per
    material, docs/refit.md)."""

    kind: Literal["brdf", "lighting"] = "lighting"
    brdf: Optional[BrdfOptions] = None  # type: ignore[valid-type]
    materials: Optional[list[MaterialOptions]] = Field(
        None, min_length=1, max_length=MAX_MATERIALS,
        description="a material library instead of one brdf: [{name, brdf}, ...], fitted on one layout "
                    "(hf.fit.factorize_many) into output.dir/<name>/ plus output.dir/index.json")
    environment: Optional[EnvironmentOptions] = None
    quantity: Optional[Literal["brdf", "brdf_cos"]] = None
    clamp: Optional[float] = Field(None, gt=0, allow_inf_nan=False)
    # lobe culling while sampling (Phong family): skip lights where every lobe < lobe_cull x its peak
    lobe_cull: Optional[float] = Field(None, gt=0, lt=1)
    # beta of the off-specular reflection r_off (parametrizations NRO, RO); default: the BRDF's roughness
    shift: Optional[float] = Field(None, ge=0, le=0.9, allow_inf_nan=False)

    @model_validator(mode="after")
    def _one_material_or_a_library(self):
        if self.brdf is None and self.materials is None:
            raise ValueError("missing brdf: give target.brdf (one material) or target.materials (a library)")
        if self.brdf is not None and self.materials is not None:
            raise ValueError("give target.brdf (one material) or target.materials (a library), not both")
        if self.materials is not None:
            seen: dict[str, str] = {}
            for m in self.materials:
                if m.name.lower() in seen:
                    raise ValueError(f"materials: the name {m.name!r} is used twice"
                                     + ("" if m.name == seen[m.name.lower()] else f" (as {seen[m.name.lower()]!r}; "
                                        "names differing only in case collide on some file systems)"))
                seen[m.name.lower()] = m.name
        return self


class LimitsOptions(Options):
    """``limits``: refuse runs estimated to need more memory (app/budget.py) before any work starts."""

    memory_gb: Optional[float] = Field(None, gt=0, le=1 << 20, allow_inf_nan=False)  # default: see budget


class Config(FitOptions):
    """A whole config file: the fit options (``preset``, ``parametrization``, ``mapper``, ``texture_size``,
    ``target_error``, ``max_lookups``, ``terms``, ``diffuse``, ``nv_factor``, ``sampling``, ``solver`` and the
    research keys under ``advanced``) plus ``target``, ``output`` and ``limits``."""

    target: TargetOptions
    output: OutputOptions = Field(default_factory=OutputOptions)
    limits: LimitsOptions = Field(default_factory=LimitsOptions)

    @model_validator(mode="before")
    @classmethod
    def _brdf_family(cls, data):
        """A preset on a BRDF target (``target.kind: brdf``, no ``parametrization``) fits PQP products (the
        lighting default NR has no BRDF meaning)."""
        if not (isinstance(data, dict) and data.get("parametrization") is None
                and isinstance(data.get("target"), dict) and data["target"].get("kind") == "brdf"):
            return data
        named = names_a_fit(data)
        return {**data, "parametrization": "PQP", **({} if named or data.get("preset") else {"preset": DEFAULT_PRESET})}

    def fit_options(self) -> dict:
        """The keywords of :func:`homofac.fit.factorize` this config gives."""
        return {k: getattr(self, k) for k in FitOptions.model_fields}

    @property
    def is_library(self) -> bool:
        """True for a material library (``target.materials``)."""
        return self.target.materials is not None

    def material_configs(self) -> list[tuple[str, "Config"]]:
        """(name, the one-material config) of every material of a library (``[]`` for one material):
        each is this config with ``target.brdf`` the material's and no ``materials``, what a single run
        of that material would be given (and what its output directory records)."""
        if self.target.materials is None:
            return []
        return [(m.name, self.model_copy(update={"target": self.target.model_copy(update={"brdf": m.brdf,
                                                                                          "materials": None})}))
                for m in self.target.materials]


def default_config_path() -> Path:
    """The bundled default config (what ``python -m homofac.fit`` runs with no argument)."""
    return Path(__file__).resolve().parent.parent / "data" / "default.yaml"


def parse(data: Any, source: str = "config") -> Config:
    """Validate a config mapping; HomofacError with a one-line message naming the key on failure."""
    if not isinstance(data, dict):
        raise HomofacError(f"{source}: the top level must be a mapping of keys, got {type(data).__name__}")
    try:
        return validate(Config, data, "")
    except HomofacError as e:
        raise HomofacError(f"{source}: {e}") from None


def parse_record(data: Any, source: str = "recorded config") -> Config:
    """A config recorded by a run (factorization.json's ``config``), also in the layout of earlier
    versions (research keys at the top level: :func:`homofac.fit.options.upgrade_record`)."""
    return parse(upgrade_record(data) if isinstance(data, dict) else data, source)


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys (PyYAML keeps the last one silently)."""


def _mapping(loader: _StrictLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    loader.flatten_mapping(node)
    out = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=deep)
        try:
            hash(key)
        except TypeError:
            raise yaml.constructor.ConstructorError(None, None, "a mapping key must be a plain value",
                                                    key_node.start_mark) from None
        if key in out:
            raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", key_node.start_mark)
        out[key] = loader.construct_object(value_node, deep=deep)
    return out


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping)


def _depth(node: yaml.Node) -> int:
    """Nesting depth of a composed YAML node tree (iterative: no recursion limit)."""
    deepest, stack = 0, [(node, 1)]
    while stack:
        n, d = stack.pop()
        deepest = max(deepest, d)
        if d > MAX_DEPTH:
            return d
        if isinstance(n, yaml.MappingNode):
            stack.extend((v, d + 1) for pair in n.value for v in pair)
        elif isinstance(n, yaml.SequenceNode):
            stack.extend((v, d + 1) for v in n.value)
    return deepest


def read_yaml(p: Path) -> Any:
    """The data of a YAML file, read strictly (see the module docstring)."""
    try:
        size = check_regular(p, "a config").st_size
        if size > MAX_BYTES:
            raise HomofacError(f"{p}: {size} bytes is not a config file (at most {MAX_BYTES})")
        text = read_bounded(p, "a config", MAX_BYTES).decode("utf-8")
    except UnicodeDecodeError as e:
        raise HomofacError(f"{p}: not UTF-8 text (byte {e.start})") from None
    try:
        loader = _StrictLoader(text)
        try:
            node = loader.get_single_node()
            if node is not None and _depth(node) > MAX_DEPTH:
                raise HomofacError(f"{p}: nested deeper than {MAX_DEPTH} levels")
            return loader.construct_document(node) if node is not None else None
        finally:
            loader.dispose()
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise HomofacError(f"{p}: malformed YAML{where}: {problem}") from None
    except RecursionError:
        raise HomofacError(f"{p}: nested too deeply") from None


def load(path) -> tuple[Config, Path]:
    """Read and validate a YAML config file; returns (config, directory relative paths refer to)."""
    p = Path(path)
    data = read_yaml(p)
    if data is None:
        raise HomofacError(f"{p}: the config file is empty")
    cfg, base = parse(data, str(p)), p.resolve().parent
    mesh = cfg.sampling.mesh  # a scene's mesh is relative to the config file (a bundled name stays a name)
    q = Path(mesh).expanduser() if mesh is not None else None
    if q is not None and not q.is_absolute() and ((base / q).exists() or bundled_scene(mesh) is None):
        cfg = cfg.model_copy(update={"sampling": cfg.sampling.model_copy(update={"mesh": str(base / q)})})
    return cfg, base


def resolve_path(value: str, base: Path) -> str:
    """A path relative to the config file's directory; a bare bundled environment name (``forest``,
    ``forest.exr``) that is not a file there is kept as it is, for the loader to resolve."""
    q = Path(value).expanduser()
    if q.is_absolute():
        return str(q)
    cand = base / q
    if not cand.exists() and "/" not in value and q.stem in BUNDLED:
        return value
    return str(cand)


__all__ = ["Config", "LimitsOptions", "MATERIAL_NAME", "MAX_BYTES", "MAX_DEPTH", "MAX_MATERIALS", "MaterialOptions",
           "TargetOptions", "default_config_path", "load", "parse", "parse_record",
           "read_yaml", "resolve_path"]
