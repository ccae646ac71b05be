"""The command-line tools: ``python -m homofac.fit``, ``python -m homofac.preview`` and ``python -m homofac.view``.

They share one-line errors (status 2 for bad input, 1 for an unexpected failure, 130 on Ctrl-C;
``--debug`` shows the traceback) and JAX's persistent compilation cache: profiling the default fit
showed about 60 % of its run in XLA compilation (about 100 programs), so the second run of a config
(or of any config with the same shapes) skips most of it (:func:`enable_compilation_cache`).
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import textwrap
import time
import warnings
from pathlib import Path
from typing import Callable

import yaml
from PIL import Image
from rich.console import Console

from .. import baselines, gl
from ..errors import HomofacError
from ..fit import solvers, sums
from ..fit.programs import compilation_cache_dir, enable_compilation_cache
from ..fit.plan import build_plan
from ..fit.options import AdvancedOptions, FitOptions, HighlightOptions, LinearOptions
from ..fit.structures import Structure
from ..gl.asset import load_asset
from ..gl.bakes import preview_bake
from ..gl.picture import auto_exposure, check_finite
from ..gl.window import require_display, show
from ..io.files import write_atomically
from ..light import BUNDLED, load_environment
from ..output import JSON_NAME, is_bake_dir, is_homofac_dir, load, read_document
from ..param import mappers
from ..param import parametrizations as pz
from ..shader import LANGUAGES
from . import budget
from . import config as cfgmod
from .library import run_library
from .run import build_target, run, run_refit, target_from_config
from .view import write_bake_viewer, write_viewer


# --------------------------------------------------------------------------------------------------
# shared


def budgeted_load(d: Path, size: int, what: str, textures: str = "exr"):
    """Load an output directory for a view or preview after :func:`homofac.app.budget.check_view`: the
    textures it declares, the exact target its recorded config rebuilds and the frames, estimated from
    factorization.json alone and refused over the memory limit before any texture is read."""
    raw = read_document(d)
    cfg = None
    if isinstance(raw.get("config"), dict):
        try:
            cfg = cfgmod.parse_record(raw["config"], f"{d / JSON_NAME} config")
        except HomofacError:
            cfg = None  # the target is not rebuilt: the view warns and shows the factorization only
    budget.check_view(raw, cfg, size, d, what=what)
    return load(d, textures=textures, max_total_bytes=budget.default_limit())


def polish_line(pol: dict) -> str:
    """The run summary's line for ``selection.polish``: the steps, the errors voted on (with the ridge
    stratum where recorded: before, and after each stage) and what was kept. The quality mode's records
    since 2026-12-06 have three stages (the third with the ridge pairs from the ALS fit), before that two;
    a plan's ``polish_direct`` polish one (the ridge pairs from the ALS fit);
    records from before 2026-12-05 have no ``kept`` (the polish was always kept then) and older
    quality-mode records one stage."""
    key, words = sums.scored_by(f"{sums.RIDGE_METRIC}_before" in pol)
    stages = pol.get("stages")
    if stages:
        ridge = max(st["ridge"] for st in stages)
        direct = len(stages) == 1 and ridge  # only the ridge stage from the ALS fit (the plan's polish_direct)
        how = (f"{pol['steps']} Levenberg-Marquardt steps off the grid with {ridge} ridge pairs" if direct else
               ", ".join([f"{pol['steps']} Levenberg-Marquardt steps off the grid",
                          f"then {pol['steps']} more with {ridge} ridge pairs",
                          f"or {pol['steps']} with them from the ALS fit"][:len(stages)]))
        after = " / ".join(f"{st[key]:.4g}" for st in stages)
        kept = ("kept" if direct else f"stage {pol['stage'] + 1} kept") if pol.get("kept") else "not kept"
    elif pol.get("trial"):  # the trial did not lower the figure: no polish ran
        how = f"a {pol['trial']['steps']}-step trial of the polish"
        after = f"{pol[key + '_after']:.4g}"
        kept = "none run"
    else:
        ridge = f" and {pol['ridge']} ridge pairs" if pol.get("ridge") else ""
        how = f"{pol['steps']} Levenberg-Marquardt steps off the grid{ridge}"
        after = f"{pol[key + '_after']:.4g}"
        kept = "kept" if pol.get("kept", True) else "not kept"
    return f"polish: {how}, {words} {pol[key + '_before']:.4g} -> {after} ({kept})"


def disc_line(disc: dict) -> str:
    """The run summary's line for ``selection.disc`` (the quality mode's disc vote,
    the plan's disc vote, :mod:`homofac.fit.plan`): both structures with the error voted on, the lights' disc radii
    in degrees and which was kept."""
    key, words = sums.scored_by(sums.RIDGE_METRIC in disc)
    errs = disc.get(key, disc["validation_nrmse"])
    radii = ", ".join(f"{math.degrees(math.asin(r)):.2g}" for r in disc["radii"])
    tried = ", ".join(f"{label} {e:.4g}" for label, e in zip(disc["labels"], errs))
    return f"disc: {words} {tried} (disc radius {radii} degrees); {'the disc' if disc['kept'] else 'the point light'} kept"


def warning_line(message, category, filename, lineno, file=None, line=None) -> None:
    """``warnings.showwarning`` of the CLIs: a Python warning (homofac's, or a library's) as one line
    ``homofac: warning: <message>`` on stderr, not the two-line ``file:line: Category: message`` + source."""
    print(f"homofac: warning: {' '.join(str(message).split())}", file=sys.stderr if file is None else file)


def run_one_line(body: Callable[[], int], debug: bool, interrupted: str = "homofac: interrupted") -> int:
    """Run a CLI body; every failure becomes one line on stderr (status 2 for HomofacError, 1 for
    anything unexpected, 130 on Ctrl-C); with ``debug`` the exception propagates with its traceback.
    Warnings are one line each (:func:`warning_line`; with ``debug`` Python's own form).

    SIGXFSZ (a file grew past ``ulimit -f``) is ignored so that the write fails with an error the
    output layer reports (naming the file, nothing replaced) instead of killing the process."""
    if hasattr(signal, "SIGXFSZ"):
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    try:
        with warnings.catch_warnings():
            if not debug:
                warnings.showwarning = warning_line
            return body()
    except KeyboardInterrupt:
        print(interrupted, file=sys.stderr)
        return 130
    except Exception as e:  # noqa: BLE001 - the CLI turns every failure into one line
        if debug:
            raise
        if isinstance(e, HomofacError):
            print(f"homofac: error: {e}", file=sys.stderr)
            return 2
        if isinstance(e, RecursionError):
            print("homofac: error: input nested too deeply", file=sys.stderr)
            return 2
        msg = " ".join(str(e).split())
        print(f"homofac: error: {type(e).__name__}: {msg} (run with --debug for the traceback)", file=sys.stderr)
        return 1


# --------------------------------------------------------------------------------------------------
# python -m homofac.fit


def fit_epilog() -> str:
    """The config summary of ``--help``, derived from the registries and option models."""
    lighting = " | ".join(pz.names("lighting"))
    brdfs = " | ".join(pz.names("brdf"))
    maps = " | ".join(m for m, r in mappers.MAPPERS.items() if not r.scalar)
    pad = "\n" + " " * 19
    structure = ", ".join(k for k in AdvancedOptions.model_fields if k not in ("highlights", "line_size", "linear",
                                                                               "baseline", "analysis"))
    highlights = ", ".join(HighlightOptions.model_fields)
    advanced = pad.join(textwrap.wrap(
        f"{{{structure}, highlights {{{highlights}}}: the rest of a structure (docs/sums.md); line_size; "
        f"linear {{{', '.join(LinearOptions.model_fields)}}}: the linear-space fit of a sum; baseline: options of "
        "a baseline (split_sum: irradiance, weighting, line_size; kautz_mccool: slices); analysis {pair: nr | nv, "
        "mapper, size}: Mahajan's in-out analysis}: research keys a preset sets", 78, break_on_hyphens=False))
    return f"""\
config keys (docs/config.md; unknown keys are errors):
  target:          kind (brdf | lighting), brdf {{model, ...its parameters}} (docs/models.md)
                   or materials [{{name, brdf}}, ...] (a library: OUT/<name>/ each, OUT/index.json),
                   environment {{file ({' | '.join(BUNDLED)} | a file), resolution, boost, lights, cull}},
                   quantity (brdf | brdf_cos; brdf only), clamp, lobe_cull, shift (beta of r_off: NRO, RO)
  preset:          fast | balanced | best: 4, 8 or 16 texture lookups per pixel (docs/presets.md)
  max_lookups:     the lookup budget; terms, diffuse (exact | fitted), nv_factor: one sum of products
  parametrization: {brdfs} (brdf); {lighting} (lighting); baselines: {' | '.join(baselines.BASELINES)}
  mapper:          {maps}
  texture_size:    S of the mapper (4 ... 1024)
  sampling:        {{kind: auto | grid | texels | latlong | random | scene, size, view_size, validation, seed,
                   count, mapper, cache}}
  solver:          {{method: {' | '.join(solvers.SOLVERS)}, tolerance, max_iterations, laplacian, epsilon, levels}}
  target_error:    validation nrmse to meet with the cheapest candidate
  advanced:        {advanced}
  output:          {{dir, png, ktx2, samples, exr (float32 | half), alpha, prescale [w0 .. wT], preview,
                   shaders [{' | '.join(LANGUAGES)}]}}
  limits:          {{memory_gb}}
relative paths are relative to the config file; --out is relative to the current directory.
exit status: 0 success, 2 bad input (one line on stderr), 1 unexpected failure.
"""


def fit_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m homofac.fit",
        description="Factor a BRDF or the lighting of a BRDF under an environment map into 2D textures.",
        epilog=fit_epilog(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("config", nargs="?", help="YAML config file (default: the bundled default.yaml)")
    p.add_argument("--out", "-o", metavar="DIR", help="output directory (overrides output.dir)")
    p.add_argument("--refit", metavar="OUT_DIR",
                   help="refit the factorization saved in OUT_DIR to the config's target (a new environment "
                        "and / or BRDF on the saved layout; docs/refit.md)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress display, only the summary line")
    p.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    p.add_argument("--print-config", action="store_true", help="print the resolved config as YAML and exit")
    p.add_argument("--plan", action="store_true",
                   help="print the plan (samples, candidate structures, linear-fit options, votes) and exit")
    p.add_argument("--no-preview", action="store_true", help="do not write preview.png (output.preview: false)")
    p.add_argument("--ktx2", action="store_true",
                   help="also write each texture as <name>.ktx2 (KTX 2.0, half float; output.ktx2: true)")
    p.add_argument("--shaders", metavar="LANG", nargs="*", choices=list(LANGUAGES),
                   help=f"also write shaders ({', '.join(LANGUAGES)}; default all when given without names)")
    return p


def fit_main(argv: list[str] | None = None) -> int:
    args = fit_parser().parse_args(argv)
    enable_compilation_cache()
    return run_one_line(lambda: _fit(args), args.debug, "homofac: interrupted; nothing was written")


def _fit(args) -> int:
    path = Path(args.config) if args.config else cfgmod.default_config_path()
    cfg, base = cfgmod.load(path)
    if args.ktx2:
        cfg = cfg.model_copy(update={"output": cfg.output.model_copy(update={"ktx2": True})})
    if args.print_config:
        print(yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False), end="")
        return 0
    if args.plan:
        if cfg.is_library:
            cfg = cfg.material_configs()[0][1]  # one layout: the first material's plan is every material's
        target, _ = build_target(cfg, base)
        print(build_plan(target, None, cfg.fit_options()))
        return 0
    if args.out is None and not args.config:
        args.out = cfg.output.dir  # the bundled default writes below the current directory
    shaders = None if args.shaders is None else (args.shaders or list(LANGUAGES))
    console = Console(stderr=True, quiet=args.quiet, log_path=False, soft_wrap=True)
    t0 = time.perf_counter()
    with console.status("starting") as status:

        def log(msg: str) -> None:
            status.update(msg)
            console.log(msg)

        kw = dict(log=log, preview=False if args.no_preview else None, shaders=shaders)
        if args.refit is not None:
            fac, out = run_refit(cfg, base, args.refit, args.out, **kw)
        elif cfg.is_library:
            facs, out, index = run_library(cfg, base, args.out, **kw)
        else:
            fac, out = run(cfg, base, args.out, **kw)
    if args.refit is None and cfg.is_library:
        for name, fac in zip((m["name"] for m in index["materials"]), facs):
            _summary(fac, out / name, None)
        t = index["timings"]
        print(f"wrote library {out}: {len(facs)} materials on one layout ({facs[0].parametrization} on "
              f"{facs[0].mapper} {facs[0].texture_size}), {out / 'index.json'}, fit {t['fit_s']:.2f} s, "
              f"{time.perf_counter() - t0:.1f} s")
        return 0
    _summary(fac, out, time.perf_counter() - t0)
    if args.refit is not None:
        tm = fac.timings
        print(f"refit of {args.refit}: values {tm.get('sample_s', 0):.3f} s, solve {tm.get('solve_s', 0):.3f} s, "
              f"measure {tm.get('measure_s', 0):.3f} s, refit {tm.get('total_s', 0):.3f} s "
              f"({fac.solver.get('method', '')})")
    return 0


def _summary(fac, out, seconds: float | None) -> None:
    """The summary lines of one written result (stdout) and its warnings (stderr)."""
    val = fac.metrics.get("validation", fac.metrics.get("train", {})).get("float", {})
    s = fac.solver
    how = f"{s['method']} {s['iterations']} iterations{'' if s.get('converged', True) else ' (NOT converged)'}" if s else ""
    took = f", {seconds:.1f} s" if seconds is not None else ""
    rec = (s or {}).get("structure")
    what = fac.parametrization
    if isinstance(rec, dict):  # a sum of products: its structure's label and the nested model in words
        structure = Structure.of(rec)
        what = f"{structure.label()} ({structure.describe()})"
    print(
        f"wrote {out}: {what} on {fac.mapper} {fac.texture_size} ({fac.model.lookups} lookups), "
        f"validation nrmse {val.get('nrmse', float('nan')):.4g} avg_rel {val.get('avg_rel', float('nan')):.4g}, "
        f"{how}{took}"
    )
    if "scene" in fac.metrics:
        sc = fac.metrics["scene"]["float"]
        pixels = (fac.counts or {}).get("scene_pixels", 0)
        print(f"scene (image space, {pixels} covered pixels): nrmse {sc['nrmse']:.4g} avg_rel {sc['avg_rel']:.4g}")
    if fac.selection is not None and "max_lookups" in fac.selection:
        key, _ = sums.scored_by(fac.selection.get("metric") == sums.RIDGE_METRIC)
        tried = "; ".join(f"{t['label']} ({t['lookups']}) {t[key]:.4g}" for t in fac.selection["tried"])
        print(f"structure: {fac.selection['reason']} (tried: {tried})")
        lines = fac.selection.get("lines")
        if lines is not None:
            errs = lines.get(key, lines["validation_nrmse"])
            voted = ", ".join(f"{n} texels {e:.4g}" for n, e in zip(lines["sizes"], errs))
            print(f"lines: {voted}; {lines['kept']} kept")
        if fac.selection.get("disc") is not None:
            print(disc_line(fac.selection["disc"]))
        pol = fac.selection.get("polish")
        if pol is not None:
            print(polish_line(pol))
    if fac.analysis is not None:
        a = fac.analysis
        ranks = ", ".join(f"{t}: K = {k}" for t, k in a["rank_for"].items())
        print(f"in-out analysis ({a['pair']}) on {a['mapper']} {a['size']}: rank-1 error {a['error'][1]:.3g}; "
              f"terms for error {ranks}")
    for w in fac.warnings:
        print(f"homofac: warning: {w}", file=sys.stderr)


# --------------------------------------------------------------------------------------------------
# python -m homofac.preview


def _bake_arguments(p: argparse.ArgumentParser) -> None:
    """The options of preview and view that show a bake directory on a textured asset."""
    p.add_argument("--asset", default="material_sphere",
                   help="a bake's object: a glTF file (.glb/.gltf, one textured primitive) or material_sphere (default)")
    p.add_argument("--environment", metavar="ENV",
                   help="a bake's exact and split-sum lighting: an EXR/HDR file or a bundled name (default: the bake's source)")
    p.add_argument("--resolution", type=int, default=32,
                   help="a bake's exact and split-sum light resolution, cube face size (default 32)")


def preview_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m homofac.preview",
        description="Render a factorization (GL, headless) beside the exact lighting and an error heat map.",
        epilog="exit status: 0 success, 2 bad input (one line on stderr), 1 unexpected failure.",
    )
    p.add_argument("out_dir", metavar="OUT_DIR", help="output directory written by python -m homofac.fit, or a bake "
                   "directory written by python -m homofac.bake (then shown on a textured glTF asset)")
    p.add_argument("-o", "--output", metavar="FILE.png", help="picture to write (default: OUT_DIR/preview.png)")
    p.add_argument("--mesh", default="sphere", help="sphere (default), torus, or a mesh file (OBJ, PLY, ...)")
    _bake_arguments(p)
    p.add_argument("--size", type=int, default=256, help="pixels of each panel (default 256)")
    p.add_argument("--azimuth", type=float, default=30.0, help="camera azimuth in degrees (+z up)")
    p.add_argument("--elevation", type=float, default=20.0, help="camera elevation in degrees")
    p.add_argument("--exposure", type=float, help="linear scale before the sRGB curve (default: automatic)")
    p.add_argument("--error-scale", type=float, help="relative error at the top of the colour bar")
    p.add_argument("--textures", choices=("exr", "png"), default="exr",
                   help="preview the float EXR textures (default) or the 8-bit PNG ones")
    p.add_argument("--window", action="store_true", help="open the interactive viewer (needs a display)")
    p.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    return p


def preview_main(argv: list[str] | None = None) -> int:
    args = preview_parser().parse_args(argv)
    enable_compilation_cache()
    return run_one_line(lambda: _preview(args), args.debug)


def _preview(args) -> int:
    d = Path(args.out_dir)
    if not d.is_dir():
        raise HomofacError(f"{d}: no such directory" if not d.exists() else f"{d}: not a directory")
    if is_bake_dir(d):
        return _preview_bake(args, d)
    if not is_homofac_dir(d):
        raise HomofacError(f"{d} is not a homofac output directory (no valid {JSON_NAME})")
    _check_common(args, 8, 4096)
    fac = budgeted_load(d, args.size, "homofac.preview", textures=args.textures)
    check_finite(fac)  # before the window too: a picture of NaN says nothing
    camera = gl.Camera(azimuth=args.azimuth, elevation=args.elevation)
    mesh = gl.load_mesh(args.mesh)
    if args.window:
        require_display()  # refuse before any work
        exposure = args.exposure
        if exposure is None:
            try:
                f = gl.render(fac, mesh, size=128, camera=camera)
                exposure = auto_exposure(f.value[f.mask])
            except HomofacError:
                exposure = 1.0
        show(fac, mesh=mesh, camera=camera, exposure=exposure)
        return 0
    target = None
    try:
        target = target_from_config(fac, base=d)
    except HomofacError as e:
        print(f"homofac: warning: cannot rebuild the exact target ({e}); showing the factorization only",
              file=sys.stderr)
    img, data = gl.preview(fac, target, mesh=mesh, size=args.size, camera=camera, exposure=args.exposure,
                           error_scale=args.error_scale, return_data=True)
    out = _output_png(args, d)
    write_atomically(out, "PNG", lambda tmp: Image.fromarray(img).save(tmp, format="PNG"), suffix=".tmp.png")
    what = f"pixel nrmse {data['nrmse']:.4g}, mean rel. error {data['mean_rel']:.4g}" if "nrmse" in data else "no exact target"
    print(f"wrote {out}: {fac.parametrization} on {fac.mapper} {fac.texture_size}, {what}")
    return 0


def _check_common(args, lo: int, hi: int) -> None:
    if not lo <= args.size <= hi:
        raise HomofacError(f"--size must be in {lo} ... {hi}, got {args.size}")
    for name in ("exposure", "error_scale"):
        v = getattr(args, name)
        if v is not None and not (v > 0 and v < float("inf")):
            raise HomofacError(f"--{name.replace('_', '-')} must be a positive number, got {v}")


def _bake_scene(args, d: Path, lo: int, hi: int):
    """The bake in ``d``, its asset and environment (checked: one-line errors)."""
    _check_common(args, lo, hi)
    if not 4 <= args.resolution <= 256:
        raise HomofacError(f"--resolution must be in 4 ... 256, got {args.resolution}")
    bake = load(d)
    env = args.environment or (bake.info or {}).get("source")
    if not env:
        raise HomofacError(f"{d}: the bake records no source environment; pass --environment")
    if not args.environment and not Path(env).exists() and Path(env).stem in BUNDLED:
        env = Path(env).stem  # a bundled map recorded by another installation's path
    return bake, load_asset(args.asset), load_environment(env, args.resolution)


def _preview_bake(args, d: Path) -> int:
    if args.window:
        raise HomofacError("--window shows factorizations; a bake's interactive view is python -m homofac.view BAKE_DIR")
    bake, asset, env = _bake_scene(args, d, 8, 4096)
    out = _output_png(args, d)
    camera = gl.Camera(azimuth=args.azimuth, elevation=args.elevation)
    img, data = preview_bake(bake, env, asset=asset, size=args.size, camera=camera, exposure=args.exposure,
                             error_scale=args.error_scale, return_data=True)
    write_atomically(out, "PNG", lambda tmp: Image.fromarray(img).save(tmp, format="PNG"), suffix=".tmp.png")
    bands = "; ".join(f"{k}: {v['bake']:.3g} / {v['split_sum']:.3g}" for k, v in data["bands"].items())
    print(f"wrote {out}: bake {bake.plan.preset} ({bake.lookups} lookups) on {asset.name}; pixel nrmse, bake / "
          f"split-sum, by roughness band: {bands}")
    return 0


def _output_png(args, d: Path) -> Path:
    out = Path(args.output) if args.output else d / "preview.png"
    if out.is_dir():
        raise HomofacError(f"-o {out}: is a directory")
    if not out.parent.is_dir():
        raise HomofacError(f"-o {out}: directory {out.parent} does not exist")
    return out


# --------------------------------------------------------------------------------------------------
# python -m homofac.view


def view_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m homofac.view",
        description="Write a self-contained WebGL2 viewer (one HTML file, textures embedded) of a factorization: "
                    "the material on a sphere and a torus under an orbit camera, the exact lighting beside it, "
                    "per-term toggles, an error heat map and exposure.",
        epilog="exit status: 0 success, 2 bad input (one line on stderr), 1 unexpected failure.",
    )
    p.add_argument("out_dir", metavar="OUT_DIR", help="output directory written by python -m homofac.fit, or a bake "
                   "directory written by python -m homofac.bake (then shown on a textured glTF asset)")
    p.add_argument("--html", metavar="FILE.html", help="page to write (default: OUT_DIR/viewer.html)")
    _bake_arguments(p)
    p.add_argument("--size", type=int, default=256, help="pixels of each panel (default 256)")
    p.add_argument("--azimuth", type=float, default=30.0, help="reference camera azimuth in degrees (+z up)")
    p.add_argument("--elevation", type=float, default=20.0, help="reference camera elevation in degrees")
    p.add_argument("--exposure", type=float, help="initial linear scale before the sRGB curve (default: automatic)")
    p.add_argument("--error-scale", type=float, help="relative error at the top of the heat map's colour bar")
    p.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    return p


def view_main(argv: list[str] | None = None) -> int:
    args = view_parser().parse_args(argv)
    enable_compilation_cache()
    return run_one_line(lambda: _view(args), args.debug)


def _view(args) -> int:
    d = Path(args.out_dir)
    if not d.is_dir():
        raise HomofacError(f"{d}: no such directory" if not d.exists() else f"{d}: not a directory")
    bake = is_bake_dir(d)
    if not bake and not is_homofac_dir(d):
        raise HomofacError(f"{d} is not a homofac output directory (no valid {JSON_NAME})")
    _check_common(args, 16, 1024)
    out = Path(args.html) if args.html else d / "viewer.html"
    if out.is_dir():
        raise HomofacError(f"--html {out}: is a directory")
    if not out.parent.is_dir():
        raise HomofacError(f"--html {out}: directory {out.parent} does not exist")
    camera = gl.Camera(azimuth=args.azimuth, elevation=args.elevation)
    if bake:
        b, asset, env = _bake_scene(args, d, 16, 1024)
        write_bake_viewer(b, out, env, asset=asset, size=args.size, camera=camera, exposure=args.exposure,
                          error_scale=args.error_scale)
        print(f"wrote {out}: bake {b.plan.preset} on {asset.name}, {out.stat().st_size / 1e6:.1f} MB, beside the exact "
              "lighting and split-sum's")
        return 0
    fac = budgeted_load(d, args.size, "homofac.view")
    target = None
    try:
        target = target_from_config(fac, base=d)
    except HomofacError as e:
        print(f"homofac: warning: cannot rebuild the exact target ({e}); the page shows the factorization only",
              file=sys.stderr)
    write_viewer(fac, out, target, size=args.size, camera=camera, exposure=args.exposure, error_scale=args.error_scale)
    print(f"wrote {out}: {fac.parametrization} ({len(fac.model.terms)} term(s)), {out.stat().st_size / 1e6:.1f} MB, "
          f"{'with' if target is not None else 'without'} the exact lighting")
    return 0


__all__ = ["compilation_cache_dir", "enable_compilation_cache", "fit_main", "fit_parser", "preview_main",
           "preview_parser", "run_one_line", "view_main", "view_parser"]
