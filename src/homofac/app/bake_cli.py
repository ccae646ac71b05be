"""``python -m homofac.bake ENVIRONMENT --out DIR``: one bake of an environment for every glTF material.

ENVIRONMENT is a lat-long EXR/HDR file, a cube map, or a bundled name (``forest``). The options of
:class:`homofac.bake.BakeOptions` are flags (``--preset fast``, ``--max-size 64``) and keys of a ``--config``
YAML file (flags win); both go through the same pydantic model, so both refuse the same values with the
same one-line error. The directory is written atomically (docs/format.md "The bake directory").
"""

from __future__ import annotations

import argparse
import sys
import time
import typing
from pathlib import Path

from ..bake import BakeOptions, bake
from ..errors import HomofacError
from ..options import validate
from ..output import check_output_dir, save_bake
from .cli import enable_compilation_cache, run_one_line
from .config import read_yaml


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m homofac.bake", description=__doc__.split("\n")[0])
    p.add_argument("environment", help="lat-long EXR/HDR file, cube map, or bundled name (city, forest, interior, studio)")
    p.add_argument("--out", required=True, help="output directory (written atomically)")
    p.add_argument("--config", help="YAML file with the bake options (keys as the flags, with underscores)")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    for name, field in BakeOptions.model_fields.items():
        if field.annotation in (bool, typing.Optional[bool]):  # an optional one (default: the preset's) as --x / --no-x
            p.add_argument(_flag(name), dest=name, default=None, help=field.description,
                           action=argparse.BooleanOptionalAction if field.default or field.annotation is not bool else "store_true")
            continue
        kind = typing.get_args(field.annotation)
        choices = kind if typing.get_origin(field.annotation) is typing.Literal else None
        number = int if "int" in str(field.annotation) else (float if "float" in str(field.annotation) else str)
        p.add_argument(_flag(name), dest=name, default=None, choices=choices, type=None if choices else number,
                       help=f"{field.description or name} (default: {field.default})")
    return p


def options(args) -> BakeOptions:
    """The validated options: the config file's keys, then the flags given."""
    data = {}
    if args.config:
        raw = read_yaml(Path(args.config))
        if raw is not None and not isinstance(raw, dict):
            raise HomofacError(f"{args.config}: a bake config is a mapping of option names to values")
        data.update(raw or {})
    data.update({k: getattr(args, k) for k in BakeOptions.model_fields if getattr(args, k) is not None})
    return validate(BakeOptions, data, "bake")


def _main(args) -> int:
    opts = options(args)
    check_output_dir(args.out)
    t0 = time.perf_counter()
    b = bake(args.environment, opts)
    out = save_bake(b, args.out)
    t = b.info["timings"]
    print(f"wrote {out}: {b.describe()}; bake {t['total_s']:.1f} s "
          f"(maps {t['maps_s']:.1f}, weights {t['weights_s']:.1f}, kernels {t['kernels_s']:.1f}, "
          f"diffuse {t['diffuse_s']:.1f}), {time.perf_counter() - t0:.1f} s in all")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    enable_compilation_cache()
    return run_one_line(lambda: _main(args), args.debug, "homofac: interrupted; nothing was written")


if __name__ == "__main__":
    sys.exit(main())
