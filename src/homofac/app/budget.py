"""Memory estimate of a run, and the refusal of configs that would not fit, before any work starts.

:func:`estimate` counts the arrays a run holds at its peak, from the config (and the environment
file's header) alone, no sampling:

* training pairs M (counted from the sampling grids, valid pairs only) and validation pairs V;
* samples: a, b, y float32 (36 bytes per pair) plus the flattened grouped arrays (another 36);
* the system: ELL columns int32 and weights float32 with K = 4 J entries per row (8 K bytes), the
  log right-hand side (12), the Laplacian rows;
* the solver's own memory class (``Solver.memory`` of the registry: LSMR's gathered operands, the
  dense normal matrix of ``direct``, scipy's float64 copies ...);
* the lighting computation: one lax.map step of at most 2^22 light terms per group, with about 16
  float32 temporaries each (the lobe form's per-light work), plus the light arrays;
* the environment image: reading it whole (its header's size x 12 bytes and the reader's
  temporaries), or a few strips when it is read downsampled (:mod:`homofac.light.sources`), and its
  resampling to the cube of lights (:data:`RESAMPLE_BYTES` per sub-point);
* a scene sampling (``kind: scene``): ``sampling.count`` pairs (or every pixel of its cameras), the mesh
  and the renders;
* a fixed 1 GB for the JAX/XLA runtime, compilation and compiled code (measured 0.4-0.9 GB);
* a material library (``target.materials``): per further material its training and validation
  values, its log right-hand side, its own solver state (the solves are vmapped) and its textures.

:func:`view_estimate` is the same count for ``homofac.view`` and ``homofac.preview`` of a saved
factorization (its textures, the exact target its recorded config rebuilds, the frames), from
factorization.json alone; :func:`check_view` refuses it over the limit before any texture is read.

It aims at the right order of magnitude and errs high (the tests check it against a measured peak).
:func:`check` refuses a config whose estimate exceeds the limit: ``limits.memory_gb``, or by default
half of what the process may use -- the smaller of the machine's RAM, ``ulimit -v`` (RLIMIT_AS) and
the cgroup's ``memory.max`` -- with the estimate in the message.
"""

from __future__ import annotations

import math
import os
import resource
from pathlib import Path

import numpy as np

from .. import baselines
from ..errors import HomofacError
from ..fit import als, scene, solvers
from ..fit.draw import default_mapper
from ..fit.options import MAX_SCENE_PIXELS
from ..fit.pipeline import grid_count, validation_count
from ..fit.plan import budget_of
from ..io.limits import image_info
from ..light import bundled
from ..light.lighting import STEP_TERMS
from ..light.resample import MAX_SUPERSAMPLE
from ..light.sources import MAX_SOURCE_PIXELS
from ..param import mappers
from ..param import parametrizations as pz
from .config import Config, resolve_path

GB = 1024**3
RUNTIME_BYTES = int(1.0 * GB)
#: Bytes per sub-point of resampling an environment map to its cube of lights (the sparse matrix, its
#: COO temporaries, the means): the forest at resolution 512 (2 x 2 sub-points a texel) measured 1.7 GB.
RESAMPLE_BYTES = 360


def physical_memory() -> int:
    """Total RAM in bytes (os.sysconf); 8 GB when it cannot be read."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 8 * GB


def _cgroup_limit() -> int | None:
    """The memory limit of this process's cgroup (v2 ``memory.max``, v1 ``memory.limit_in_bytes``)."""
    candidates = []
    try:
        for line in Path("/proc/self/cgroup").read_text().splitlines():
            parts = line.split(":", 2)
            if len(parts) == 3:
                rel = parts[2].lstrip("/")
                candidates += [Path("/sys/fs/cgroup") / rel / "memory.max",
                               Path("/sys/fs/cgroup/memory") / rel / "memory.limit_in_bytes"]
    except OSError:  # no /proc/self/cgroup (not Linux): only the fixed paths below
        pass
    candidates += [Path("/sys/fs/cgroup/memory.max"), Path("/sys/fs/cgroup/memory/memory.limit_in_bytes")]
    for p in candidates:
        try:
            text = p.read_text().strip()
        except OSError:
            continue
        if text and text != "max":
            try:
                value = int(text)
            except ValueError:
                continue
            if 0 < value < (1 << 60):
                return value
    return None


def process_limit() -> int:
    """What this process may use: the smallest of the RAM, ``ulimit -v`` (RLIMIT_AS) and the cgroup limit."""
    limits = [physical_memory()]
    try:
        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft not in (resource.RLIM_INFINITY, -1) and soft > 0:
            limits.append(int(soft))
    except (ValueError, OSError):  # no RLIMIT_AS on this platform: RAM and cgroup only
        pass
    cg = _cgroup_limit()
    if cg is not None:
        limits.append(cg)
    return min(limits)


def default_limit() -> int:
    """Half of what the process may use (:func:`process_limit`)."""
    return process_limit() // 2


def _grid_count(mapper: str, size: int, hemisphere: bool) -> int:
    """Valid directions of a texel grid without building it: area fraction of the mapper's valid texels."""
    m = mappers.get(mapper)
    s = min(int(size), 64)  # the fraction is the same at any size; count it on a small table
    frac = float(np.mean(mappers.valid_mask(m, s)))
    count = frac * np.prod(mappers.texture_shape(m, int(size)))
    if hemisphere and m.covers_sphere:
        count /= 2
    return int(count)


def environment_bytes(cfg: Config, base: Path) -> int:
    """Peak bytes of reading the environment image (whole, or in strips when it is big); 0 when unknown."""
    env = cfg.target.environment
    if cfg.target.kind != "lighting" or env is None:
        return 0
    path = Path(resolve_path(env.file, base))
    if not path.exists():
        try:
            path = bundled(env.file)
        except HomofacError:
            return 0
    if path.is_dir() or not path.is_file():
        return 0
    try:
        info = image_info(path)
    except HomofacError:
        return 0  # the loader reports the problem with its own message
    if info.pixels <= MAX_SOURCE_PIXELS:
        return int(info.whole_read_bytes)
    return 3 * (8 << 20) + 2 * 12 * MAX_SOURCE_PIXELS  # a few strips, the reduced image and its float64 sums


def supersample(cfg: Config, base: Path) -> int:
    """The sub-points per cube-texel side the environment's resampling uses (``homofac.light.resample``:
    at least as dense as the source pixels, 2 when the header cannot be read)."""
    env = cfg.target.environment
    r = env.resolution if env is not None else 32
    path = Path(resolve_path(env.file, base)) if env is not None else None
    try:
        if path is None or not path.is_file():
            path = bundled(env.file if env is not None else "forest")
        h = image_info(path).height
    except (HomofacError, OSError, TypeError):
        return 2
    return int(min(MAX_SUPERSAMPLE, max(2, math.ceil(2.0 * h / (math.pi * r)))))


def lighting_bytes(cfg: Config, base: Path = Path(".")) -> dict:
    """Bytes of the lighting target a config describes, by part: ``environment`` (reading the image),
    ``resample`` (the sparse resampling of the map to ``6 R^2`` light texels, :data:`RESAMPLE_BYTES` per
    sub-point: measured 1.7 GB for the forest at resolution 512), ``lighting`` (the light arrays and one
    chunk of the lighting sum). Empty for a BRDF target."""
    if cfg.target.kind != "lighting":
        return {}
    env = cfg.target.environment
    res = env.resolution if env else 32
    lights = 6 * res * res + len(env.lights if env else [])
    return {
        "environment": environment_bytes(cfg, base),
        "resample": 6 * res * res * supersample(cfg, base) ** 2 * RESAMPLE_BYTES,
        "lighting": STEP_TERMS * 16 * 4 + lights * 200,
    }


def estimate(cfg: Config, base: Path = Path(".")) -> dict:
    """Estimated peak bytes of the run a :class:`~homofac.app.config.Config` describes, by part."""
    kind = cfg.target.kind
    if cfg.parametrization in baselines.BASELINES:  # computed, not fitted: 3 textures, no system
        p, j, t = None, 3, 3
    else:
        p = pz.get(cfg.parametrization, kind) if cfg.target_error is None else None
        j = p.J if p else 4
        t = p.T if p else 4
    s = cfg.sampling
    smapper = s.mapper or default_mapper(kind)
    grid = s.kind == "grid" or (s.kind == "auto" and cfg.is_sum and kind == "lighting")
    if grid:
        m = grid_count(cfg)
    elif s.kind == "random":
        m = s.count or s.size**2 * (s.view_size or s.size) ** 2 // 4
    elif s.kind == "latlong":
        m = (s.size * 2 * s.size) * ((s.view_size or s.size) * 2 * (s.view_size or s.size)) // (8 if kind == "brdf" else 2)
    elif s.kind == "scene":
        m = s.count or scene_pixels(s)
    else:
        hemi = kind == "brdf"
        m = _grid_count(smapper, s.size, hemi) * _grid_count(smapper, s.view_size or s.size, hemi)
        m = m if hemi else m // 2
    v = validation_count(cfg)
    mapper = cfg.mapper or default_mapper(kind)
    n = t * int(np.prod(mappers.texture_shape(mappers.get(mapper), cfg.texture_size)))
    k = 4 * j
    parts = {
        "samples": (m + v) * 72,
        "system": m * (8 * k + 12) + n * 5 * 8,
        "solver": solvers.get(cfg.solver.method).memory(m, n, k),
        "runtime": RUNTIME_BYTES,
    }
    if cfg.is_sum:
        parts["system"], parts["solver"] = _sum_bytes(cfg, m, mapper, grid and kind == "lighting")
    parts.update(lighting_bytes(cfg, base))
    if s.kind == "scene":  # the mesh (at most MAX_FACES triangles), the renders, the covered pixels
        parts["scene"] = scene.MAX_FACES * 100 + scene.CHUNK * 200 + scene_pixels(s) * 150
    count = len(cfg.target.materials or ())
    if count > 1:  # a library: one layout, per material its values, right-hand side, solver state, textures
        parts["materials"] = (count - 1) * ((m + v) * 24 + m * 12 + parts["solver"] + n * 3 * 4 * 4)
    parts["total"] = sum(parts.values())
    parts["pairs"] = m
    parts["unknowns"] = n
    return parts


def _sum_bytes(cfg: Config, m: int, mapper: str, als_path: bool) -> tuple[int, int]:
    """(data, solver) bytes of a linear-space sum (homofac.fit.sums): the largest structure it may fit within
    the lookup budget (``max_lookups`` or the preset's, :func:`homofac.fit.plan.budget_of`). A chooser's kept
    structure is polished off the grid (Levenberg-Marquardt on the grid and polish pairs), so its bytes are the
    larger of the ALS fit's and the polish's."""
    lookups = budget_of(cfg)
    terms = cfg.terms if lookups is None else max(1, lookups // 2)
    factors = terms * (4 if cfg.nv_factor or lookups is not None else 3) + 2
    texels = int(np.prod(mappers.texture_shape(mappers.get(mapper), cfg.texture_size)))
    n = factors * texels

    def lm(pairs: int) -> tuple[int, int]:
        data = pairs * factors * 32 + pairs * 12  # ELL footprints of every factor, the targets
        solver = 12 * (pairs * 3 + n * 3 * 5) * 4 + 3 * factors * pairs * 12  # LSMR vectors, JVP / VJP temporaries
        return data, solver

    if not als_path:
        return lm(m)
    # per-sample factor values and the chunked normal equations (homofac.fit.als)
    data = m * (16 + 12 + 12) + 6 * terms * m * 12
    solver = 2 * als.CHUNK_BYTES + texels * 3 * terms * terms * 4 * 4 + (32 * terms) ** 2 * 3 * 8
    if lookups is None:
        return data, solver
    polish = lm(2 * m)  # the polish reads the grid pairs and about as many texel pairs again
    return (data, solver) if data + solver >= sum(polish) else polish


def scene_pixels(s) -> int:
    """Pixels of a scene sampling's cameras (its own, else its bundled scene's; the most allowed when
    neither is known): the covered pixels cannot exceed them."""
    cams = s.cameras
    if not cams:
        try:
            cams = scene.resolve_cameras(s)
        except (HomofacError, OSError, ValueError):
            return MAX_SCENE_PIXELS
    return int(sum(c.width * c.height for c in cams))


def texture_bytes(doc: dict) -> int:
    """Bytes of loading the textures a factorization.json declares: per texel the float32 RGB result
    and the reader's temporaries (28 bytes), the 8-bit RGBA copy when PNG files are listed (20 more)."""
    total = 0
    for t in doc.get("textures") or [] if isinstance(doc.get("textures"), list) else []:
        if not isinstance(t, dict):
            continue
        try:
            mapper = t.get("mapper") or doc.get("mapper")
            size = int(t.get("size") or doc.get("texture_size"))
            texels = int(np.prod(mappers.texture_shape(mappers.get(mapper), min(size, 1 << 16))))
        except (HomofacError, TypeError, ValueError, KeyError):
            continue  # the loader refuses it with its own message
        total += texels * (28 + (20 if t.get("png") else 0))
    return total


#: Pixels of the viewer's and the preview's frames per requested ``--size`` squared (sphere and torus).
VIEW_FRAMES = 2
#: Bytes per light of computing the exact image of a view (the lighting sum's per-light arrays beyond the
#: fit's: measured 1.45 GB peak for ``homofac.view`` at resolution 256, 393 216 lights, against 0.7 GB
#: for loading that environment alone).
VIEW_LIGHT_BYTES = 2000


def view_estimate(doc: dict, cfg: Config | None, size: int, base: Path = Path(".")) -> dict:
    """Estimated peak bytes of ``homofac.view`` / ``homofac.preview`` of a saved factorization, by part:
    the runtime, its textures (:func:`texture_bytes`), the exact target rebuilt from its recorded config
    ``cfg`` (:func:`lighting_bytes` and the per-light work of its exact image) and the frames."""
    parts = {"runtime": RUNTIME_BYTES, "textures": texture_bytes(doc),
             "frames": VIEW_FRAMES * int(size) ** 2 * 200}
    if cfg is not None and cfg.target.kind == "lighting":
        parts.update(lighting_bytes(cfg, base))
        res = cfg.target.environment.resolution if cfg.target.environment else 32
        parts["exact"] = 6 * res * res * VIEW_LIGHT_BYTES
    parts["total"] = sum(parts.values())
    return parts


def check_view(doc: dict, cfg: Config | None, size: int, base: Path = Path("."), limit_bytes: int | None = None,
               what: str = "homofac.view") -> dict:
    """Refuse (HomofacError, one line) a view or preview whose estimate exceeds the limit (as :func:`check`)."""
    est = view_estimate(doc, cfg, size, base)
    limit = limit_bytes if limit_bytes is not None else default_limit()
    if est["total"] > limit:
        res = cfg.target.environment.resolution if cfg is not None and cfg.target.environment else None
        env = f", environment resolution {res}" if res and cfg.target.kind == "lighting" else ""
        raise HomofacError(
            f"{what}: estimated memory {est['total'] / GB:.1f} GB (textures {est['textures'] / GB:.2f} GB{env}) exceeds "
            f"the limit {limit / GB:.1f} GB (half of what this process may use: RAM, ulimit -v, cgroup); "
            f"use a smaller --size, or refit at a lower target.environment.resolution"
        )
    return est


def check(cfg: Config, base: Path = Path("."), limit_bytes: int | None = None) -> dict:
    """Refuse (HomofacError, one line) when the estimate exceeds the limit; returns the estimate."""
    est = estimate(cfg, base)
    limit = limit_bytes if limit_bytes is not None else default_limit()
    if est["total"] > limit:
        env = f", environment image {est.get('environment', 0) / GB:.1f} GB" if est.get("environment") else ""
        raise HomofacError(
            f"estimated memory {est['total'] / GB:.1f} GB ({est['pairs']:,} training pairs, {est['unknowns']:,} "
            f"unknowns{env}) exceeds the limit {limit / GB:.1f} GB (limits.memory_gb, or half of what this process "
            "may use: RAM, ulimit -v, cgroup); reduce sampling.size, texture_size or target.environment.resolution, "
            "or raise the limit"
        )
    return est


__all__ = ["GB", "check", "check_view", "default_limit", "environment_bytes", "estimate", "lighting_bytes",
           "physical_memory", "process_limit", "scene_pixels", "supersample", "texture_bytes", "view_estimate"]
