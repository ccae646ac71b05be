"""Material libraries from a config: ``target.materials`` fitted on one layout (issue 15).

:func:`run_library` builds one target per material (the config's environment, the material's BRDF),
factors them all with :func:`homofac.fit.factorize_many` (one set of sample directions, one system
matrix, the right-hand sides solved together) and writes ``output.dir/<name>/`` per material -- each a
normal pinned output directory, recording the one-material config a single run of it would have --
and ``output.dir/index.json`` (:data:`homofac.output.LIBRARY_FORMAT`: the materials, their directories,
BRDFs and validation metrics, the shared layout, timings). The whole library is written into a
temporary directory and swapped into place under the output lock
(:func:`homofac.output.save_library`): never half written.
"""

from __future__ import annotations

import time
from pathlib import Path

from ..errors import HomofacError
from ..fit import factorize_many
from ..output import INDEX_NAME, OutputLock, check_output_dir, save_library
from . import budget
from .config import Config
from .run import build_target, encoding_of, keeps_samples, output_path, write_result


def library_index(cfg: Config, names: list[str], results, infos: list[dict], timings: dict) -> dict:
    """The index.json document of a library (without ``format`` / ``version``, which the writer adds)."""
    first = results[0]
    env = (infos[0] or {}).get("environment")
    mats = []
    for name, m, fac in zip(names, cfg.target.materials, results):
        mats.append({"name": name, "dir": name, "brdf": m.brdf.model_dump(mode="json"),
                     "metrics": {"validation": fac.metrics.get("validation", {}), "train": fac.metrics.get("train", {})},
                     "lookups": fac.model.lookups, "solver": {k: fac.solver.get(k) for k in ("method", "iterations",
                                                                                            "converged")},
                     "warnings": list(fac.warnings)})
    layout = {"kind": cfg.target.kind, "parametrization": first.parametrization, "mapper": first.mapper,
              "texture_size": first.texture_size, "sampling": cfg.sampling.model_dump(mode="json"),
              "train_pairs": first.counts.get("train"), "validation_pairs": first.counts.get("validation")}
    return {"materials": mats, "layout": layout, **({"environment": env} if env else {}), "timings": timings,
            "config": cfg.model_dump(mode="json")}


def run_library(cfg: Config, base: Path = Path("."), out_dir: str | None = None, log=None,
                preview: bool | None = None, shaders: list[str] | None = None):
    """Fit and write the material library a config describes; returns (results in the config's order,
    path, index). ``out_dir``, ``preview`` and ``shaders`` as in :func:`homofac.app.run.run`.
    Everything is refused before any work that a single run refuses (output path, memory estimate
    counting every material, prescale weights)."""
    if not cfg.is_library:
        raise HomofacError("config: target.materials is not given; a single material runs with homofac.app.run.run")
    out = output_path(cfg, base, out_dir)
    check_output_dir(out)
    members = cfg.material_configs()
    names = [n for n, _ in members]
    with OutputLock(out):
        lim = cfg.limits.memory_gb
        budget.check(cfg, base, int(lim * budget.GB) if lim is not None else None)
        encoding_of(cfg)
        t0 = time.perf_counter()
        built = [build_target(c, base) for _, c in members]
        targets, infos = [t for t, _ in built], [i for _, i in built]
        log = log or (lambda msg: None)
        log(f"fitting {len(targets)} materials on one layout")
        results = factorize_many(targets, **cfg.fit_options(), configs=[c.model_dump(mode="json") for _, c in members],
                                 target_infos=infos, log=log, keep_samples=keeps_samples(cfg))
        fit_s = time.perf_counter() - t0
        written: list = []
        index: dict = {}

        def write(tmp: Path) -> dict:
            for (name, c), fac, t in zip(members, results, targets):
                log(f"writing {name}")
                written.append(write_result(fac, t, c, tmp / name, log=log, preview=preview, shaders=shaders))
            index.update(library_index(cfg, names, written, infos,
                                       {"fit_s": fit_s, "per_material_s": fit_s / len(written),
                                        "total_s": time.perf_counter() - t0}))
            return index

        save_library(out, write)
    return written, out, index


__all__ = ["INDEX_NAME", "library_index", "run_library"]
