"""``python -m homofac.preview OUT_DIR [-o FILE.png] [--window]``: look at a factorization.

Renders the factorization in ``OUT_DIR`` (written by ``python -m homofac.fit``) on a sphere, a torus
or a mesh file headless through EGL, beside the exact lighting (rebuilt from the recorded config) and
an error heat map, and writes the picture as a PNG (default ``OUT_DIR/preview.png``). ``--window``
opens the interactive viewer instead (orbit camera; needs a display). Bad input exits with status 2
and one line ``homofac: error: ...`` (a traceback only with ``--debug``).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m homofac.preview",
        description="Render a factorization (GL, headless) beside the exact lighting and an error heat map.",
        epilog="exit status: 0 success, 2 bad input (one line on stderr), 1 unexpected failure.",
    )
    p.add_argument("out_dir", metavar="OUT_DIR", help="output directory written by python -m homofac.fit")
    p.add_argument("-o", "--output", metavar="FILE.png", help="picture to write (default: OUT_DIR/preview.png)")
    p.add_argument("--mesh", default="sphere", help="sphere (default), torus, or a mesh file (OBJ, PLY, ...)")
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


def main(argv: list[str] | None = None) -> int:
    from .cli import enable_compilation_cache, run_one_line

    args = _parser().parse_args(argv)
    enable_compilation_cache()
    return run_one_line(lambda: _run(args), args.debug)


def _run(args) -> int:
    from .errors import HomofacError
    from .io.output import JSON_NAME, is_homofac_dir

    d = Path(args.out_dir)
    if not d.is_dir():
        raise HomofacError(f"{d}: no such directory" if not d.exists() else f"{d}: not a directory")
    if not is_homofac_dir(d):
        raise HomofacError(f"{d} is not a homofac output directory (no valid {JSON_NAME})")
    if not 8 <= args.size <= 4096:
        raise HomofacError(f"--size must be in 8 ... 4096, got {args.size}")
    for name in ("exposure", "error_scale"):
        v = getattr(args, name)
        if v is not None and not (v > 0 and v < float("inf")):
            raise HomofacError(f"--{name.replace('_', '-')} must be a positive number, got {v}")

    from . import gl
    from .io.output import load

    fac = load(d, textures=args.textures)
    camera = gl.Camera(azimuth=args.azimuth, elevation=args.elevation)
    mesh = gl.load_mesh(args.mesh)
    if args.window:
        from .gl.window import require_display, show

        require_display()  # refuse before any work
        exposure = args.exposure
        if exposure is None:
            try:
                from .gl.picture import auto_exposure

                f = gl.render(fac, mesh, size=128, camera=camera)
                exposure = auto_exposure(f.value[f.mask])
            except HomofacError:
                exposure = 1.0
        show(fac, mesh=mesh, camera=camera, exposure=exposure)
        return 0

    target = None
    try:
        target = gl.target_from_config(fac, base=d)
    except HomofacError as e:
        print(f"homofac: warning: cannot rebuild the exact target ({e}); showing the factorization only",
              file=sys.stderr)
    img, data = gl.preview(fac, target, mesh=mesh, size=args.size, camera=camera, exposure=args.exposure,
                           error_scale=args.error_scale, return_data=True)
    out = Path(args.output) if args.output else d / "preview.png"
    if out.is_dir():
        raise HomofacError(f"-o {out}: is a directory")
    if not out.parent.is_dir():
        raise HomofacError(f"-o {out}: directory {out.parent} does not exist")
    _write_png(img, out)
    what = f"pixel nrmse {data['nrmse']:.4g}, mean rel. error {data['mean_rel']:.4g}" if "nrmse" in data else "no exact target"
    print(f"wrote {out}: {fac.parametrization} on {fac.mapper} {fac.texture_size}, {what}")
    return 0


def _write_png(img, out: Path) -> None:
    """Write atomically: a temporary file beside ``out``, renamed into place."""
    from PIL import Image

    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
    os.close(fd)
    try:
        Image.fromarray(img).save(tmp, format="PNG")
        os.replace(tmp, out)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


if __name__ == "__main__":
    sys.exit(main())
