"""A run: the target a config describes, the factorization, and its output directory.

:func:`run` is the whole CLI as one Python call: refuse what cannot work before any work (output
directory, memory estimate, prescale weights), build the target, :func:`homofac.fit.factorize` it,
and write the pinned output directory (with preview.png and shaders when asked) under the output
lock. :func:`run_refit` does the same for a refit of a saved factorization (``--refit OUT_DIR``) and
:mod:`homofac.app.library` for a config with ``target.materials``. :func:`target_from_config`
rebuilds the exact target of a saved result from its recorded config.
"""

from __future__ import annotations

import copy
import errno
import sys
from pathlib import Path

from PIL import Image

from .. import brdf as brdf_mod
from ..errors import HomofacError
from ..fit import factorize, prepare_refit, refit, scene
from ..fit.draw import default_mapper
from ..fit.options import FitOptions, recorded_fit_options
from ..fit.metrics import measure
from ..fit.precision import prescale_factors
from ..fit.pipeline import validation_count
from ..fit.result import Result
from ..gl.picture import preview
from ..io.files import write_atomically
from ..light import EnvironmentOptions, environment_from_options, lighting_target
from ..param import parametrizations as pz
from ..options import validate
from ..output import JSON_NAME, OutputLock, check_output_dir, is_homofac_dir, load
from ..target import Target, brdf_target
from . import budget
from .config import Config, parse_record, resolve_path


def build_target(cfg: Config, base: Path) -> tuple[Target, dict]:
    """The Target (and a description of it) that a config describes; relative paths against ``base``."""
    if cfg.is_library:
        raise HomofacError("config: target.materials describes a library, not one target (Config.material_configs())")
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
    e = cfg.target.environment or EnvironmentOptions()
    env, env_info = environment_from_options(e, file=resolve_path(e.file, base))
    info["environment"] = env_info
    if cfg.target.lobe_cull is not None:
        info["lobe_cull"] = cfg.target.lobe_cull
    return lighting_target(brdf, env, parametrization=cfg.parametrization, clamp=cfg.target.clamp,
                           lobe_tolerance=cfg.target.lobe_cull, shift=cfg.target.shift), info


def target_from_config(fac: Result, base: str | Path | None = None) -> Target | None:
    """Rebuild the exact target of a result from its recorded config (None when it has none).

    The environment is read from the recorded absolute source path when the config's (relative) path
    cannot be found; ``base`` is the directory relative paths refer to (default: the current one).
    Raises HomofacError when the config is there but cannot be rebuilt.
    """
    if not fac.config:
        return None
    data = copy.deepcopy(dict(fac.config))
    base = Path(base) if base is not None else Path(".")
    env_info = (fac.target_info or {}).get("environment") or {}
    env_cfg = (data.get("target") or {}).get("environment")
    src = env_info.get("source")
    if isinstance(env_cfg, dict) and isinstance(src, str) and Path(src).is_file():
        f = env_cfg.get("file", "forest")
        if not Path(resolve_path(f, base)).exists():
            env_cfg["file"] = src
    cfg = parse_record(data, "factorization.json config")
    target, _ = build_target(cfg, base)
    return target


def preview_writer(fac: Result, target: Target | None, log=None):
    """A writer ``path -> None`` of preview.png for :func:`homofac.output.save` (``extra_files``).

    Without GL (no EGL, no moderngl) or when rendering fails it prints one line ``homofac: warning: ...``
    and writes nothing: a preview never fails a fit. Failing to *write* the file (a full disk) is an
    error of the output, like any other file.
    """

    def write(path) -> None:
        if log is not None:
            log("rendering preview.png")
        try:
            img = preview(fac, target)
        except Exception as e:  # noqa: BLE001 - a preview never fails the fit
            msg = " ".join(str(e).split()) or type(e).__name__
            print(f"homofac: warning: preview.png skipped: {msg[:300]}", file=sys.stderr)
            return
        write_atomically(path, "PNG", lambda tmp: Image.fromarray(img).save(tmp, format="PNG"), suffix=".tmp.png")

    return write


def output_path(cfg: Config, base: Path, out_dir: str | None) -> Path:
    """The output directory of a run: ``out_dir`` (the CLI's ``--out``), else ``output.dir`` relative to
    the config file's directory ``base``."""
    return Path(out_dir) if out_dir else base / Path(cfg.output.dir).expanduser()


def encoding_of(cfg: Config) -> dict:
    """The 8-bit encoding ``output`` asks for; refuses bad ``output.prescale`` weights before any work."""
    o = cfg.output
    encoding = {"alpha": o.alpha, **({"weights": list(o.prescale)} if o.prescale is not None else {})}
    if o.prescale is not None and cfg.target_error is None:
        p = pz.get(cfg.parametrization, cfg.target.kind)
        try:
            prescale_factors(o.prescale, [len(p.uses(k)) for k in range(p.T)])
        except HomofacError as e:
            raise HomofacError(f"config: output.prescale: {e}") from None
    return encoding


def keeps_samples(cfg: Config) -> bool:
    """Whether a fit of this config must keep its samples (written, or re-measured for a custom encoding)."""
    return bool(cfg.output.samples or encoding_of(cfg) != {"alpha": True})


def write_result(fac: Result, target: Target, cfg: Config, out: Path, log=None, preview: bool | None = None,
                 shaders: list[str] | None = None) -> Result:
    """Write a fitted result as the pinned output directory ``out`` the config's ``output`` describes
    (custom 8-bit encoding re-measured, samples, preview.png, shaders); returns the result written."""
    o = cfg.output
    encoding = encoding_of(cfg)
    if encoding != {"alpha": True}:  # the quantized metrics must describe the 8-bit textures that are written
        fac = fac.replace(encoding=encoding)
        eps = float(cfg.solver.epsilon)
        metrics = measure(fac, target, fac.samples, eps=eps)
        if "scene" in fac.metrics:  # the scene's image-space error, of the textures that are written
            metrics["scene"] = scene.load(cfg.sampling).metrics(fac, target, eps)
        fac = fac.replace(metrics=metrics, samples=fac.samples if o.samples else None)
    extra = {}
    if o.preview if preview is None else preview:
        extra["preview.png"] = preview_writer(fac, target, log=log)
    langs = list(dict.fromkeys(list(o.shaders) + list(shaders or [])))
    try:
        fac.save(out, samples=fac.samples if o.samples else None, png=o.png, exr=o.exr, ktx2=o.ktx2, extra_files=extra,
                 shaders=langs)
    except OSError as e:
        if e.errno == errno.ENOSPC:
            raise HomofacError(f"cannot write {out}: no space left on device") from None
        raise
    return fac


def run(cfg: Config, base: Path = Path("."), out_dir: str | None = None, log=None, preview: bool | None = None,
        shaders: list[str] | None = None):
    """Run the factorization a config describes and write its output directory; returns (result, path).

    ``out_dir`` (e.g. the CLI's ``--out``) overrides ``output.dir``; a relative ``output.dir`` is
    relative to the config file's directory ``base``. ``preview`` overrides ``output.preview``,
    ``shaders`` extends ``output.shaders``. A material library (``target.materials``) is
    :func:`homofac.app.library.run_library`.
    """
    if cfg.is_library:
        raise HomofacError("config: target.materials is a material library; run it with homofac.app.library.run_library")
    out = output_path(cfg, base, out_dir)
    check_output_dir(out)  # refuse before any work is done
    with OutputLock(out):  # exclusive, and taken before the work: a second run is refused at once
        lim = cfg.limits.memory_gb
        budget.check(cfg, base, int(lim * budget.GB) if lim is not None else None)
        encoding_of(cfg)  # refuse bad weights before any work
        target, info = build_target(cfg, base)
        fac = factorize(target, **cfg.fit_options(), config=cfg.model_dump(mode="json"), target_info=info, log=log,
                        keep_samples=keeps_samples(cfg))
        fac = write_result(fac, target, cfg, out, log=log, preview=preview, shaders=shaders)
    return fac, out


#: Fit options that do not describe the layout of a fit (a refit may change them).
NOT_LAYOUT = ("advanced.analysis", "sampling.cache")


def _leaves(d, prefix: str = "") -> dict:
    if not isinstance(d, dict):
        return {prefix: d}
    out = {}
    for k, v in d.items():
        out.update(_leaves(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


def layout_difference(saved: dict, cfg: Config, kind: str) -> str | None:
    """The first fit option (dotted key) on which a config and a saved result's recorded config disagree,
    as ``"key: config value vs saved value"``; None when the layouts agree. Compared: every fit option
    (parametrization, mapper with its default resolved, texture size, sampling, solver, structure)
    except those of :data:`NOT_LAYOUT`."""
    try:
        old = validate(FitOptions, recorded_fit_options(saved), "")
    except HomofacError as e:
        raise HomofacError(f"--refit: the saved factorization's recorded config is not valid here: {e}") from None
    a = cfg.model_dump(mode="json", include=set(FitOptions.model_fields))
    b = old.model_dump(mode="json")
    for d, opts in ((a, cfg), (b, old)):
        d["mapper"] = d.get("mapper") or default_mapper(kind)
        d["sampling"]["validation"] = validation_count(opts)  # not given: the rule's count (None in records)
    la, lb = _leaves(a), _leaves(b)
    for key in list(dict.fromkeys(list(lb) + list(la))):
        if any(key == n or key.startswith(n + ".") for n in NOT_LAYOUT):
            continue
        if la.get(key) != lb.get(key) and not _unset_or_off(la.get(key), lb.get(key)):
            return f"{key}: {la.get(key)!r} in the config, {lb.get(key)!r} in the saved factorization"
    return None


def _unset_or_off(a, b) -> bool:
    """Whether two recorded values differ only as "not set" (None: the preset's) against off (0, False), as
    records written before presets hold the structure keys (``highlight_terms: 0``, ``linear.ridge: 0``)."""
    return None in (a, b) and all(v in (None, 0, False) for v in (a, b))


def load_for_refit(saved_dir) -> Result:
    """The factorization saved in ``saved_dir``, read for a refit (one-line errors for what is not one)."""
    d = Path(saved_dir)
    if not d.is_dir():
        raise HomofacError(f"--refit {d}: no such directory" if not d.exists() else f"--refit {d}: not a directory")
    if not is_homofac_dir(d):
        raise HomofacError(f"--refit {d} is not a homofac output directory (no valid {JSON_NAME})")
    fac = load(d)
    if not fac.config:
        raise HomofacError(f"--refit {d}: the factorization records no config to rebuild its layout from")
    return fac


def run_refit(cfg: Config, base: Path, saved_dir, out_dir: str | None = None, log=None, preview: bool | None = None,
              shaders: list[str] | None = None):
    """Refit the factorization saved in ``saved_dir`` to the target a config describes (a new
    environment and / or BRDF on the saved layout, :func:`homofac.fit.refit`) and write it like
    :func:`run` writes a run; returns (result, path).

    The config's fit options must describe the saved layout (:func:`layout_difference`; a one-line
    error names the first field that differs). Everything is checked before any work; nothing is
    written on failure.
    """
    if cfg.is_library:
        raise HomofacError("--refit takes a config of one material (target.brdf), not a library (target.materials)")
    saved = load_for_refit(saved_dir)
    if saved.kind != cfg.target.kind:
        raise HomofacError(f"--refit: target.kind: {cfg.target.kind!r} in the config, {saved.kind!r} in the saved "
                           "factorization")
    diff = layout_difference(saved.config, cfg, saved.kind)
    if diff is not None:
        raise HomofacError(f"--refit: the config's layout differs from the saved factorization's: {diff}")
    out = output_path(cfg, base, out_dir)
    check_output_dir(out)
    with OutputLock(out):
        lim = cfg.limits.memory_gb
        budget.check(cfg, base, int(lim * budget.GB) if lim is not None else None)
        encoding_of(cfg)
        target, info = build_target(cfg, base)
        if log is not None:
            log(f"preparing the refit state of {saved_dir}")
        ready = prepare_refit(saved)
        # one right-hand side in a fresh process: the configured solver from the saved solution (factoring
        # the normal equations pays only when the state is refitted again; docs/refit.md)
        fac = refit(ready, target=target, config=cfg.model_dump(mode="json"), target_info=info,
                    keep_samples=keeps_samples(cfg), log=log, solve="lsmr")
        fac = write_result(fac, target, cfg, out, log=log, preview=preview, shaders=shaders)
    return fac, out


__all__ = ["NOT_LAYOUT", "build_target", "encoding_of", "keeps_samples", "layout_difference", "load_for_refit",
           "output_path", "preview_writer", "run", "run_refit", "target_from_config", "write_result"]
