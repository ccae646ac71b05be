"""``python -m homofac.fit [CONFIG.yaml] [--out DIR]``: run a factorization from a YAML config.

With no config it runs the bundled default (``homofac/data/default.yaml``). Bad input exits with
status 2 and one line ``homofac: error: ...`` (a traceback only with ``--debug``); nothing partial is
ever written (the output directory is replaced only once the whole result exists).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

EPILOG = """\
config keys (DESIGN.md; unknown keys are errors):
  target:          kind (brdf | lighting), brdf {model, kd, ks, roughness, f0, exponent, file},
                   environment {file, resolution, boost {threshold, factor}, lights [...]} (lighting),
                   quantity (brdf | brdf_cos; brdf only), clamp (lighting values, optional)
  parametrization: IV | GSHD | PQP (brdf); N | R | NR | NRV | NRHD (lighting)
  mapper:          parabolic | dual_paraboloid | cube | octahedral | hemispherical | spherical
  texture_size:    S of the mapper (4 ... 1024)
  sampling:        {kind: texels | latlong | random, size, validation, seed, count, mapper}
  solver:          {method: lsmr | qmr | direct, tolerance, max_iterations, laplacian, epsilon}
  output:          {dir, png, samples, exr (float32 | half), alpha, prescale [w0 .. wT], preview}
relative paths are relative to the config file; --out is relative to the current directory.
exit status: 0 success, 2 bad input (one line on stderr), 1 unexpected failure.
"""


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m homofac.fit",
        description="Factor a BRDF or the lighting of a BRDF under an environment map into 2D textures.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("config", nargs="?", help="YAML config file (default: the bundled default.yaml)")
    p.add_argument("--out", "-o", metavar="DIR", help="output directory (overrides output.dir)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress display, only the summary line")
    p.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    p.add_argument("--print-config", action="store_true", help="print the resolved config as YAML and exit")
    p.add_argument("--no-preview", action="store_true", help="do not write preview.png (output.preview: false)")
    return p


def main(argv: list[str] | None = None) -> int:
    from ..cli import enable_compilation_cache, run_one_line

    args = _parser().parse_args(argv)
    enable_compilation_cache()
    return run_one_line(lambda: _run(args), args.debug, "homofac: interrupted; nothing was written")


def _run(args) -> int:
    import yaml

    from . import config as cfgmod

    path = Path(args.config) if args.config else cfgmod.default_config_path()
    cfg, base = cfgmod.load(path)
    if args.print_config:
        print(yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False), end="")
        return 0
    if args.out is None and not args.config:
        args.out = cfg.output.dir  # the bundled default writes below the current directory

    from rich.console import Console

    console = Console(stderr=True, quiet=args.quiet, log_path=False, soft_wrap=True)
    t0 = time.perf_counter()
    with console.status("starting") as status:

        def log(msg: str) -> None:
            status.update(msg)
            console.log(msg)

        fac, out = cfgmod.run(cfg, base, args.out, log=log, preview=False if args.no_preview else None)
    val = fac.metrics.get("validation", fac.metrics.get("train", {})).get("float", {})
    s = fac.solver
    print(
        f"wrote {out}: {fac.parametrization} on {fac.mapper} {fac.texture_size}, "
        f"validation nrmse {val.get('nrmse', float('nan')):.4g} avg_rel {val.get('avg_rel', float('nan')):.4g}, "
        f"{s['method']} {s['iterations']} iterations{'' if s['converged'] else ' (NOT converged)'}, "
        f"{time.perf_counter() - t0:.1f} s"
    )
    for w in fac.warnings:
        print(f"homofac: warning: {w}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
