"""The pinned output directory: factorization.json, ``<name>.exr`` textures, optional samples.npz.

Writing is atomic (DESIGN.md): everything goes into a temporary sibling directory that is renamed
into place only after every file was written. A directory homofac did not write is never replaced;
a previous homofac result is replaced whole, after the new one is complete.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import uuid
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..errors import HomofacError

FORMAT = "homofac.factorization"
SCHEMA_VERSION = 1
JSON_NAME = "factorization.json"


def _jsonable(v: Any) -> Any:
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, Path):
        return str(v)
    if hasattr(v, "shape") and hasattr(v, "dtype"):
        a = np.asarray(v)
        return a.item() if a.ndim == 0 else a.tolist()
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating,)):
        return float(v)
    return v


def is_homofac_dir(path: Path) -> bool:
    """True when ``path`` holds a factorization.json written by homofac."""
    f = Path(path) / JSON_NAME
    try:
        return json.loads(f.read_text()).get("format") == FORMAT
    except (OSError, ValueError, AttributeError):
        return False


def check_output_dir(out_dir) -> Path:
    """Refuse output paths that are files or foreign non-empty directories (before any work)."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise HomofacError(f"output path {out} exists and is not a directory")
    if out.is_dir() and any(out.iterdir()) and not is_homofac_dir(out):
        raise HomofacError(f"output directory {out} is not empty and was not written by homofac; refusing to overwrite it")
    parent = out.parent
    if parent.exists() and not parent.is_dir():
        raise HomofacError(f"output path {out}: parent {parent} is not a directory")
    return out


def document(fac) -> dict:
    """The factorization.json document of a :class:`~homofac.fit.factorization.Factorization`."""
    from ..param import parametrizations as pz

    p = pz.get(fac.parametrization)
    textures = [
        {
            "name": name,
            "file": f"{name}.exr",
            "mapper": fac.mapper,
            "size": fac.texture_size,
            "shape": list(np.asarray(fac.textures[k]).shape[:2]),
            "factors": list(p.uses(k)),
        }
        for k, name in enumerate(p.textures)
    ]
    return _jsonable(
        {
            "format": FORMAT,
            "schema_version": SCHEMA_VERSION,
            "homofac_version": __version__,
            "kind": fac.kind,
            "target": {"kind": fac.kind, "quantity": fac.quantity, **fac.target_info},
            "parametrization": fac.parametrization,
            "mapper": fac.mapper,
            "texture_size": fac.texture_size,
            "textures": textures,
            "factors": [{"projection": f.projection, "texture": p.textures[f.texture]} for f in p.factors],
            "correction": fac.correction,
            "context": fac.context,
            "metrics": fac.metrics,
            "solver": fac.solver,
            "timings": fac.timings,
            "counts": fac.counts,
            "warnings": list(fac.warnings),
            "config": fac.config,
        }
    )


def save(fac, out_dir, *, samples=None, extra_files: dict | None = None) -> Path:
    """Write the output directory atomically; returns its path.

    Args:
        fac: the factorization.
        out_dir: target directory (created; a previous homofac result there is replaced whole).
        samples: optional :class:`~homofac.fit.pipeline.Samples` written as samples.npz.
        extra_files: ``{file name: callable(path)}`` writers of further files (e.g. a preview).
    """
    from .exr import write_exr

    out = check_output_dir(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    try:
        doc = document(fac)
        for k, t in enumerate(doc["textures"]):
            write_exr(tmp / t["file"], np.asarray(fac.textures[k], np.float32))
        if samples is not None:
            np.savez(
                tmp / "samples.npz",
                **{k: np.asarray(v, np.float32) for k, v in samples._asdict().items()},
            )
        for name, writer in (extra_files or {}).items():
            writer(tmp / name)
        (tmp / JSON_NAME).write_text(json.dumps(doc, indent=2, allow_nan=True))
        _swap_into_place(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def _swap_into_place(tmp: Path, out: Path) -> None:
    if out.exists():
        old = out.parent / f".{out.name}.old-{uuid.uuid4().hex[:8]}"
        os.replace(out, old)
        try:
            os.replace(tmp, out)
        except BaseException:
            os.replace(old, out)
            raise
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, out)


def load(out_dir):
    """Read an output directory back into a :class:`~homofac.fit.factorization.Factorization`."""
    import jax.numpy as jnp

    from ..fit.factorization import Factorization
    from .exr import read_exr

    d = Path(out_dir)
    try:
        doc = json.loads((d / JSON_NAME).read_text())
    except OSError as e:
        raise HomofacError(f"{d}: cannot read {JSON_NAME} ({e.strerror or e})") from None
    except ValueError as e:
        raise HomofacError(f"{d / JSON_NAME}: not valid JSON ({e})") from None
    if doc.get("format") != FORMAT:
        raise HomofacError(f"{d / JSON_NAME}: not a homofac factorization")
    textures = tuple(jnp.asarray(read_exr(d / t["file"])) for t in doc["textures"])
    ctx = {k: jnp.asarray(v, jnp.float32) for k, v in (doc.get("context") or {}).items()}
    return Factorization(
        kind=doc["kind"], parametrization=doc["parametrization"], mapper=doc["mapper"],
        texture_size=int(doc["texture_size"]), textures=textures, correction=jnp.asarray(doc["correction"], jnp.float32),
        context=ctx, quantity=doc["target"].get("quantity", "brdf"), metrics=doc.get("metrics", {}),
        solver=doc.get("solver", {}), timings=doc.get("timings", {}), counts=doc.get("counts", {}),
        config=doc.get("config", {}), target_info={k: v for k, v in doc["target"].items() if k not in ("kind", "quantity")},
        warnings=tuple(doc.get("warnings", ())),
    )
