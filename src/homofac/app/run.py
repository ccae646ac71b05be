"""A run: the target a config describes, the factorization, and its output directory.

:func:`run` is the whole CLI as one Python call: refuse what cannot work before any work (output
directory, memory estimate, prescale weights), build the target, :func:`homofac.fit.factorize` it,
and write the pinned output directory (with preview.png and shaders when asked) under the output
lock. :func:`target_from_config` rebuilds the exact target of a saved result from its recorded config.
"""

from __future__ import annotations

import copy
import errno
import sys
from pathlib import Path

from PIL import Image

from .. import brdf as brdf_mod
from ..errors import HomofacError
from ..fit import factorize
from ..fit.metrics import measure
from ..fit.precision import prescale_factors
from ..fit.result import Result
from ..gl.picture import preview
from ..io.files import write_atomically
from ..light import EnvironmentOptions, environment_from_options, lighting_target
from ..param import parametrizations as pz
from ..output import OutputLock, check_output_dir
from ..target import Target, brdf_target
from . import budget
from .config import Config, parse, resolve_path


def build_target(cfg: Config, base: Path) -> tuple[Target, dict]:
    """The Target (and a description of it) that a config describes; relative paths against ``base``."""
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
                           lobe_tolerance=cfg.target.lobe_cull), info


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
    cfg = parse(data, "factorization.json config")
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


def run(cfg: Config, base: Path = Path("."), out_dir: str | None = None, log=None, preview: bool | None = None,
        shaders: list[str] | None = None):
    """Run the factorization a config describes and write its output directory; returns (result, path).

    ``out_dir`` (e.g. the CLI's ``--out``) overrides ``output.dir``; a relative ``output.dir`` is
    relative to the config file's directory ``base``. ``preview`` overrides ``output.preview``,
    ``shaders`` extends ``output.shaders``.
    """
    out = Path(out_dir) if out_dir else base / Path(cfg.output.dir).expanduser()
    check_output_dir(out)  # refuse before any work is done
    with OutputLock(out):  # exclusive, and taken before the work: a second run is refused at once
        lim = cfg.limits.memory_gb
        budget.check(cfg, base, int(lim * budget.GB) if lim is not None else None)
        o = cfg.output
        encoding = {"alpha": o.alpha, **({"weights": list(o.prescale)} if o.prescale is not None else {})}
        if o.prescale is not None and cfg.target_error is None:  # refuse bad weights before any work
            p = pz.get(cfg.parametrization, cfg.target.kind)
            try:
                prescale_factors(o.prescale, [len(p.uses(k)) for k in range(p.T)])
            except HomofacError as e:
                raise HomofacError(f"config: output.prescale: {e}") from None
        target, info = build_target(cfg, base)
        custom = encoding != {"alpha": True}
        fac = factorize(target, **cfg.fit_options(), config=cfg.model_dump(mode="json"), target_info=info, log=log,
                        keep_samples=o.samples or custom)
        if custom:  # the quantized metrics must describe the 8-bit textures that are written
            fac = fac.replace(encoding=encoding)
            fac = fac.replace(metrics=measure(fac, target, fac.samples, eps=float(cfg.solver.epsilon)),
                              samples=fac.samples if o.samples else None)
        extra = {}
        if o.preview if preview is None else preview:
            extra["preview.png"] = preview_writer(fac, target, log=log)
        langs = list(dict.fromkeys(list(o.shaders) + list(shaders or [])))
        try:
            fac.save(out, samples=fac.samples, png=o.png, exr=o.exr, extra_files=extra, shaders=langs)
        except OSError as e:
            if e.errno == errno.ENOSPC:
                raise HomofacError(f"cannot write {out}: no space left on device") from None
            raise
    return fac, out


__all__ = ["build_target", "preview_writer", "run", "target_from_config"]
