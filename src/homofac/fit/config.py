"""The YAML configuration (DESIGN.md "Config", pinned keys), validated by pydantic.

Unknown keys and wrong types are errors that name the key (``target.brdf.roughness``). Relative
paths are relative to the config file. :func:`run` is the whole CLI as one Python call.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal, Optional, Union

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from ..errors import HomofacError

Colour = Union[float, list[float]]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)


class BRDFConfig(_Strict):
    """``target.brdf``: a model name and its parameters (names as in homofac.brdf)."""

    model: str
    kd: Optional[Colour] = None
    ks: Optional[Colour] = None
    roughness: Optional[float] = None
    f0: Optional[Colour] = None
    exponent: Optional[float] = None
    file: Optional[str] = None

    def params(self) -> dict:
        return {k: v for k, v in self.model_dump().items() if k != "model" and v is not None}


class BoostConfig(_Strict):
    """Highlight boost of thesis §5.7: pixels above threshold * max luminance scaled by factor."""

    threshold: float = 0.9
    factor: float = 10.0


class LightConfig(_Strict):
    """An extra light added to the environment."""

    type: Literal["directional", "point"] = "directional"
    direction: list[float]
    irradiance: Colour = 1.0


class EnvironmentConfig(_Strict):
    """``target.environment`` (lighting only)."""

    file: str = "forest"
    resolution: int = Field(32, ge=1, le=512)
    boost: Optional[BoostConfig] = None
    lights: list[LightConfig] = Field(default_factory=list)
    # drop the weakest lights holding at most this fraction of the total power (light.cull_lights)
    cull: Optional[float] = Field(None, ge=0, lt=1)


class TargetConfig(_Strict):
    kind: Literal["brdf", "lighting"] = "lighting"
    brdf: BRDFConfig
    environment: Optional[EnvironmentConfig] = None
    quantity: Optional[Literal["brdf", "brdf_cos"]] = None
    clamp: Optional[float] = Field(None, gt=0)
    # lobe culling while sampling (Phong family): skip lights where every lobe < lobe_cull x its peak
    lobe_cull: Optional[float] = Field(None, gt=0, lt=1)


class SamplingConfig(_Strict):
    kind: Literal["texels", "latlong", "random"] = "texels"
    size: int = Field(24, ge=2, le=512)
    view_size: Optional[int] = Field(None, ge=2, le=512)
    validation: int = Field(20000, ge=0, le=10_000_000)
    seed: int = 0
    count: int = Field(0, ge=0)
    mapper: Optional[str] = None
    cache: bool = True  # reuse samples from $HOMOFAC_CACHE_DIR (~/.cache/homofac/samples), see fit/cache.py


class SolverConfig(_Strict):
    method: Literal["lsmr", "qmr", "cg", "optimistix", "direct"] = "lsmr"
    tolerance: float = Field(1e-6, gt=0, lt=1)
    max_iterations: int = Field(1000, ge=1)
    laplacian: float = Field(1.0, ge=0)
    epsilon: float = Field(1e-5, gt=0, lt=1)
    levels: int = Field(1, ge=1, le=8)


class OutputConfig(_Strict):
    """``output``: where and what to write (DESIGN.md output directory).

    ``png`` writes the 8-bit RGBA textures; ``exr`` is the EXR pixel type (``float32`` or ``half``);
    ``alpha`` turns the thesis' alpha precision trick (§4.3.2) of the 8-bit textures on or off;
    ``prescale`` gives the T + 1 weights ``w_0 .. w_T`` of thesis §4.3.1 (correction, then textures).
    """

    dir: str = "out"
    png: bool = False
    samples: bool = True
    exr: Literal["float32", "half"] = "float32"
    alpha: bool = True
    prescale: Optional[list[float]] = None
    preview: bool = True  # preview.png (homofac.gl; skipped with a one-line warning when GL is unavailable)


class LimitsConfig(_Strict):
    """``limits``: refuse runs estimated to need more memory (fit/budget.py) before any work starts."""

    memory_gb: Optional[float] = Field(None, gt=0)  # default: half of the machine's RAM


class Config(_Strict):
    target: TargetConfig
    parametrization: str = "NR"
    mapper: Optional[str] = None
    texture_size: int = 32
    # validation nrmse to meet: pick the cheapest parametrization and size (<= texture_size), fit/auto.py
    target_error: Optional[float] = Field(None, gt=0, lt=10)
    sampling: SamplingConfig = Field(default_factory=SamplingConfig)
    solver: SolverConfig = Field(default_factory=SolverConfig)
    output: OutputConfig = Field(default_factory=OutputConfig)
    limits: LimitsConfig = Field(default_factory=LimitsConfig)


def default_config_path() -> Path:
    """The bundled default config (what ``python -m homofac.fit`` runs with no argument)."""
    return Path(__file__).resolve().parent.parent / "data" / "default.yaml"


def _format_error(e: ValidationError, source: str) -> str:
    err = e.errors()[0]
    loc = ".".join(str(x) for x in err["loc"]) or "(top level)"
    if err["type"] == "extra_forbidden":
        return f"{source}: unknown key {loc}"
    if err["type"] == "missing":
        return f"{source}: missing key {loc}"
    got = err.get("input")
    got_s = repr(got)
    if len(got_s) > 60:
        got_s = got_s[:57] + "..."
    more = f" (and {len(e.errors()) - 1} more problems)" if len(e.errors()) > 1 else ""
    return f"{source}: {loc}: {err['msg']} (got {got_s}){more}"


def parse(data: dict, source: str = "config") -> Config:
    """Validate a config mapping; HomofacError with a one-line message naming the key on failure."""
    if not isinstance(data, dict):
        raise HomofacError(f"{source}: the top level must be a mapping of keys, got {type(data).__name__}")
    try:
        return Config.model_validate(data)
    except ValidationError as e:
        raise HomofacError(_format_error(e, source)) from None


def load(path) -> tuple[Config, Path]:
    """Read and validate a YAML config file; returns (config, directory relative paths refer to)."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as e:
        raise HomofacError(f"cannot read config {p}: {e.strerror or e}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise HomofacError(f"{p}: malformed YAML{where}: {problem}") from None
    if data is None:
        raise HomofacError(f"{p}: the config file is empty")
    return parse(data, str(p)), p.resolve().parent


def resolve_path(value: str, base: Path) -> str:
    """A path relative to the config file's directory; a bare bundled environment name (``forest``,
    ``forest.exr``) that is not a file there is kept as it is, for the loader to resolve."""
    from ..light.environment import BUNDLED

    q = Path(value).expanduser()
    if q.is_absolute():
        return str(q)
    cand = base / q
    if not cand.exists() and "/" not in value and q.stem in BUNDLED:
        return value
    return str(cand)


def build_target(cfg: Config, base: Path):
    """The Target (and a description of it) that a config describes."""
    from .. import brdf as brdf_mod
    from .target import brdf_target

    b = cfg.target.brdf
    params = b.params()
    if "file" in params:
        params["file"] = resolve_path(params["file"], base)
    brdf = brdf_mod.make(b.model, **params)
    info = {"brdf": {"model": b.model, **b.params()}}
    if cfg.target.kind == "brdf":
        if cfg.target.environment is not None:
            raise HomofacError("config: target.environment is only for target.kind lighting")
        return brdf_target(brdf, cfg.target.quantity or "brdf"), info
    if cfg.target.quantity is not None:
        raise HomofacError("config: target.quantity is only for target.kind brdf")
    from ..light import lighting_target, load_environment

    e = cfg.target.environment or EnvironmentConfig()
    env = load_environment(
        resolve_path(e.file, base),
        resolution=e.resolution,
        boost=e.boost.model_dump() if e.boost else None,
        lights=[lc.model_dump() for lc in e.lights],
    )
    info["environment"] = {k: v for k, v in env.info.items()}
    if e.cull:
        from ..light import cull_lights

        env, culling = cull_lights(env, e.cull)
        # the stated bound: |change of L(v, n)| <= max f * dropped_power per channel
        info["environment"]["culling"] = {"tolerance": e.cull, **culling}
    if cfg.target.lobe_cull is not None:
        info["lobe_cull"] = cfg.target.lobe_cull
    return lighting_target(brdf, env, parametrization=cfg.parametrization, clamp=cfg.target.clamp,
                           lobe_tolerance=cfg.target.lobe_cull), info


def run(cfg: Config, base: Path = Path("."), out_dir: str | None = None, log=None, preview: bool | None = None):
    """Run the factorization a config describes and write its output directory; returns (result, path).

    ``out_dir`` (e.g. the CLI's ``--out``) overrides ``output.dir``; a relative ``output.dir`` is
    relative to the config file's directory ``base``. ``preview`` overrides ``output.preview``.
    """
    from ..io.output import check_output_dir
    from .pipeline import factorize

    from . import budget

    out = Path(out_dir) if out_dir else base / Path(cfg.output.dir).expanduser()
    check_output_dir(out)  # refuse before any work is done
    lim = cfg.limits.memory_gb
    budget.check(cfg, int(lim * budget.GB) if lim is not None else None)
    target, info = build_target(cfg, base)
    o = cfg.output
    encoding = {"alpha": o.alpha, **({"weights": list(o.prescale)} if o.prescale is not None else {})}
    if o.prescale is not None:  # refuse bad weights before any work is done
        from ..param import parametrizations as pz
        from .precision import prescale_factors, texture_uses

        try:
            prescale_factors(o.prescale, texture_uses(pz.get(cfg.parametrization)))
        except HomofacError as e:
            raise HomofacError(f"config: output.prescale: {e}") from None
    custom = encoding != {"alpha": True}
    common = dict(sampling=cfg.sampling.model_dump(), solver=cfg.solver.model_dump(),
                  config=cfg.model_dump(mode="json"), target_info=info, keep_samples=o.samples or custom)
    if cfg.target_error is not None:
        from .auto import choose

        fac = choose(target, cfg.target_error, mapper=cfg.mapper, max_size=cfg.texture_size, log=log, **common)
    else:
        fac = factorize(target, cfg.parametrization, mapper=cfg.mapper, texture_size=cfg.texture_size, log=log,
                        **common)
    if custom:  # the quantized metrics must describe the 8-bit textures that are written
        import dataclasses

        from .pipeline import measure

        fac = dataclasses.replace(fac, encoding=encoding)
        fac = dataclasses.replace(
            fac, metrics=measure(fac, target, fac.samples, eps=float(cfg.solver.epsilon)),
            samples=fac.samples if o.samples else None,
        )
    extra = {}
    if o.preview if preview is None else preview:
        from ..gl.picture import safe_writer

        extra["preview.png"] = safe_writer(fac, target, log=log)
    fac.save(out, samples=fac.samples, png=o.png, exr=o.exr, extra_files=extra)
    return fac, out
