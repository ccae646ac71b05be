"""Loading environments from files: lat-long EXR / HDR, cube maps (strips, six faces), bundled maps.

* lat-long maps (EXR or Radiance ``.hdr``, exactly 2:1), see :mod:`.latlong`;
* cube maps: an EXR with header ``envmap = cube`` (or any image exactly 6:1 or 1:6 without an
  ``envmap`` attribute) stored as a horizontal ``(S, 6S)`` strip in the pinned face order
  +X, -X, +Y, -Y, +Z, -Z, or as a vertical ``(6S, S)`` strip (same faces top to bottom); or a directory
  (or a list) of six face images named ``px nx py ny pz nz`` (``.exr`` or ``.hdr``). Each face image is
  oriented as its block of the pinned texture: row = v S - 0.5, column = u S - 0.5.
* a bare bundled name (``"forest"`` or ``"forest.exr"`` when no such file exists): one of
  :data:`BUNDLED`, 256x128 lat-long copies of CC0 maps (see ``homofac/data/hdri/LICENSE.txt``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import HomofacError
from ..io.exr import read_exr
from ..io.files import strip_rows
from ..io.hdr import read_hdr
from ..io.limits import image_info, iter_strips, read_downsampled
from ..options import validate
from .cubemap import FACE_NAMES
from .environment import Environment
from .latlong import downsample_strips
from .lights import cull_lights
from .options import EnvironmentOptions
from .resample import from_cube, from_latlong

#: Names of the bundled lat-long maps (256x128, CC0): ``load_environment("forest")``.
BUNDLED = ("city", "forest", "interior", "studio")
#: Source images up to this many pixels are read whole (100 MB as float32); bigger ones in strips.
MAX_SOURCE_PIXELS = 4096 * 2048


def bundled(name: str) -> Path:
    """Path of a bundled lat-long map (one of :data:`BUNDLED`)."""
    stem = name[:-4] if name.lower().endswith(".exr") else name
    if stem not in BUNDLED:
        raise HomofacError(f"{name}: not a bundled environment (bundled: {', '.join(BUNDLED)})")
    return Path(__file__).resolve().parents[1] / "data" / "hdri" / f"{stem}.exr"


def _read_image(path: Path) -> tuple[np.ndarray, str | None, dict]:
    """``(rgb, envmap kind from the header or None, read record)`` of an EXR or Radiance HDR file.

    Images of at most :data:`MAX_SOURCE_PIXELS` pixels are read whole; bigger ones (16K HDRIs) are
    box-averaged while they are read, strip by strip, by the smallest integer factor that brings them
    under it (solid-angle weighted for 2:1 lat-long maps, so the energy is kept exactly): the memory
    stays a few strips plus the result, whatever the file declares. The read record says what was done.
    """
    info = image_info(path)
    kind = info.envmap if info.kind == "exr" else None
    h, w = info.height, info.width
    if info.pixels <= MAX_SOURCE_PIXELS:
        rgb = read_exr(path) if info.kind == "exr" else read_hdr(path)
        return rgb, kind, {}
    f = next((f for f in range(2, min(h, w) + 1) if h % f == 0 and w % f == 0 and (h // f) * (w // f) <= MAX_SOURCE_PIXELS),
             None)
    if f is None:
        raise HomofacError(f"{path}: {w} x {h} pixels is above {MAX_SOURCE_PIXELS:,} and has no integer downsampling "
                           f"factor that divides both sides; resample it to a size such as {2 * 2048} x 2048")
    if kind != "cube" and w == 2 * h:
        rgb = downsample_strips(iter_strips(path, strip_rows(info, f)), h, w, f)
    else:
        rgb = read_downsampled(path, f)
    return rgb, kind, {"read_downsample": f, "file_shape": [h, w]}


def _face_files(directory: Path) -> list[Path]:
    found = []
    missing = []
    for n in FACE_NAMES:
        cands = sorted(p for p in directory.glob(f"{n}.*") if p.suffix.lower() in (".exr", ".hdr", ".pic"))
        if not cands:
            missing.append(n)
        else:
            found.append(cands[0])
    if missing:
        raise HomofacError(f"{directory}: cube map directory lacks face image(s) {' '.join(missing)} (.exr or .hdr)")
    return found


def load_environment(
    path: str | os.PathLike | Sequence[str | os.PathLike],
    resolution: int = 32,
    *,
    boost: dict | None = None,
    lights: Sequence[dict] = (),
) -> Environment:
    """Load an environment map and resample it to ``6 resolution^2`` cube-texel lights.

    ``path``: a lat-long EXR or ``.hdr`` (2:1), a cube-map EXR (header ``envmap = cube``, or a 6:1 / 1:6
    strip), a directory of six faces ``px nx py ny pz nz``, a list of six face files (that order), or a
    bare bundled name such as ``"forest"``. Negative pixels are clamped to 0; NaN/Inf pixels are set to
    0 with a warning (both counted in ``info``). ``boost`` is the thesis §5.7 highlight boost
    (``{"threshold": 0.9, "factor": 10}``, default off), ``lights`` extra directional/point lights.
    Raises :class:`HomofacError` (one line naming the file) on any bad input, and if the result has no
    power at all.
    """
    if isinstance(path, (list, tuple)):
        files = [Path(p) for p in path]
        label = f"cube faces [{', '.join(str(p) for p in files)}]"
        if len(files) != 6:
            raise HomofacError(f"{label}: a cube map needs six face files ({' '.join(FACE_NAMES)}), got {len(files)}")
        faces = [_read_image(p)[0] for p in files]
        return from_cube(faces, resolution, boost=boost, lights=lights, source=label)
    p = Path(os.fspath(path)).expanduser()
    label = str(p)
    if not p.exists():
        s = os.fspath(path)
        bare = os.sep not in s and "/" not in s
        stem = s[:-4] if s.lower().endswith(".exr") else s
        if bare and stem in BUNDLED:
            p = bundled(stem)
            label = str(p)
        else:
            raise HomofacError(f"{p}: no such file (bundled environments: {', '.join(BUNDLED)})")
    if p.is_dir():
        faces = [_read_image(f)[0] for f in _face_files(p)]
        return from_cube(faces, resolution, boost=boost, lights=lights, source=label)
    rgb, kind, read = _read_image(p)
    h, w = rgb.shape[:2]
    if kind == "cube" or (kind is None and (w == 6 * h or h == 6 * w)):
        return from_cube(rgb, resolution, boost=boost, lights=lights, source=label, extra_info=read)
    return from_latlong(rgb, resolution, boost=boost, lights=lights, source=label, extra_info=read)


def environment_from_options(options: EnvironmentOptions | dict, *, file: str | None = None) -> tuple[Environment, dict]:
    """The environment an :class:`EnvironmentOptions` describes, and its provenance record.

    ``file`` overrides ``options.file`` (the app passes the path resolved against the config file).
    With ``cull`` the weakest lights are dropped (:func:`~homofac.light.lights.cull_lights`) and the
    record gets ``culling`` (dropped, kept, dropped_power, total_power, tolerance).
    """
    opts = validate(EnvironmentOptions, options, "target.environment")
    env = load_environment(
        file or opts.file, opts.resolution,
        boost=opts.boost.model_dump() if opts.boost else None,
        lights=[lc.model_dump(exclude_none=True) for lc in opts.lights],
    )
    info = dict(env.info)
    if opts.cull:
        env, culling = cull_lights(env, opts.cull)
        info["culling"] = {"tolerance": opts.cull, **culling}
    return env, info


__all__ = ["BUNDLED", "bundled", "environment_from_options", "load_environment"]
