"""On-disk cache of drawn samples, keyed by a hash of everything they depend on (issue 5, "skip work").

Sampling (evaluating the exact target on the training and validation pairs) dominates a lighting fit;
refitting the same target with another parametrization, texture size or solver needs the same samples.
:func:`key` hashes

* the target: its kind, quantity and every leaf of its function's pytree (BRDF parameters, environment
  directions, radiance, solid angles, corners, a MERL table), plus the tree structure with its static
  fields (model name, clamp, ...). ``Target.context`` (NRHD's dominant direction) is left out: it
  changes the system, not the samples;
* the resolved sampling settings, and for BRDF targets the parametrization (its texel iterator
  decides the pairs);
* the homofac version and :data:`FORMAT`,

so a change of any input is a different key (invalidation by construction; nothing is ever updated in
place). A target whose structure cannot be fingerprinted stably (a plain Python function, traced
values under ``jax.grad``) gets no key and is never cached.

Nothing read back is trusted. An entry ``<dir>/<key>.npz`` carries its own key, format and version, the
expected shapes, and a sha256 checksum of its arrays (:func:`store`); :func:`load` checks all of them
and that every value is finite, so a truncated file, an entry of another config copied under the
key, arrays of the wrong shape or dtype, or NaNs are a miss: the samples are drawn again and the bad
entry is replaced whole. Entries are written to a temporary file and renamed (a crash never leaves a
half-written entry), with the mode the umask allows.

The directory is ``$HOMOFAC_CACHE_DIR`` or ``~/.cache/homofac/samples``; delete it to clear the cache.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import tempfile
from pathlib import Path

import jax
import numpy as np

from .._version import __version__
from .samples import FIELDS, Samples

#: Bump when the sampling code changes what it produces for the same inputs (2: self-checking entries).
FORMAT = 2
#: Entries larger than this are not read (a lighting sample set of the thesis' size is ~15 MB).
MAX_ENTRY_BYTES = 2 << 30


def cache_dir() -> Path:
    """``$HOMOFAC_CACHE_DIR`` or ``~/.cache/homofac/samples``."""
    env = os.environ.get("HOMOFAC_CACHE_DIR")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "homofac" / "samples"


def _stable_structure(treedef) -> str | None:
    s = str(treedef)
    # object addresses (functions, lambdas, foreign objects) change between processes: no stable key
    if re.search(r"0x[0-9a-fA-F]{6,}", s) or "<function" in s or "<lambda" in s:
        return None
    return s


def key(target, sampling: dict, parametrization: str) -> str | None:
    """The cache key (hex sha256) of the samples of ``target`` under ``sampling``, or None (uncacheable)."""
    leaves, treedef = jax.tree_util.tree_flatten(target.fn)
    structure = _stable_structure(treedef)
    if structure is None:
        return None
    h = hashlib.sha256()
    head = {
        "format": FORMAT, "version": __version__, "kind": target.kind, "quantity": target.quantity,
        "sampling": {k: sampling[k] for k in sorted(sampling) if k != "cache"},
        "parametrization": parametrization if target.kind == "brdf" else None, "structure": structure,
    }
    h.update(json.dumps(head, sort_keys=True, default=str).encode())
    for leaf in leaves:
        if isinstance(leaf, jax.core.Tracer):
            return None
        if isinstance(leaf, (np.ndarray, jax.Array)) or np.isscalar(leaf):
            a = np.asarray(leaf)
            h.update(f"{a.dtype}{a.shape}".encode())
            h.update(np.ascontiguousarray(a).tobytes())
        else:
            return None
    return h.hexdigest()


def checksum(samples: Samples) -> str:
    """sha256 of the sample arrays (dtype, shape and bytes of each field, in order)."""
    h = hashlib.sha256()
    for name in FIELDS:
        a = np.ascontiguousarray(getattr(samples, name))
        h.update(f"{name}{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def check(samples: Samples, validation: int | None = None) -> str | None:
    """Why ``samples`` cannot be a sample set (None when they can): shapes, dtypes, finiteness.

    ``validation`` is the number of validation pairs the settings ask for (the lighting sampler may
    drop a few invalid ones, never add any).
    """
    for name in FIELDS:
        a = getattr(samples, name)
        if not isinstance(a, np.ndarray) or a.dtype != np.float32 or a.ndim != 2 or a.shape[1] != 3:
            return f"{name} is not an (N, 3) float32 array"
        if not np.all(np.isfinite(a)):
            return f"{name} has non-finite values"
    if not (len(samples.a) == len(samples.b) == len(samples.y)) or len(samples.a) == 0:
        return "training arrays of different lengths"
    if not (len(samples.val_a) == len(samples.val_b) == len(samples.val_y)):
        return "validation arrays of different lengths"
    if validation is not None and len(samples.val_a) > validation:
        return f"{len(samples.val_a)} validation pairs where at most {validation} were asked for"
    return None


def load(k: str, validation: int | None = None):
    """The cached :class:`~homofac.fit.samples.Samples` of key ``k``, or None (missing, or not a valid entry
    of this key: it is then drawn again and replaced)."""
    path = cache_dir() / f"{k}.npz"
    try:
        if path.stat().st_size > MAX_ENTRY_BYTES:
            return None
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            samples = Samples(*(np.asarray(z[f]) for f in FIELDS))
    except Exception:  # noqa: BLE001 - missing, truncated, not an npz, wrong members: a miss
        return None
    if not isinstance(meta, dict) or meta.get("key") != k or meta.get("format") != FORMAT:
        return None
    if meta.get("version") != __version__ or meta.get("checksum") != checksum(samples):
        return None
    if check(samples, validation) is not None:
        return None
    return samples


def store(k: str, samples) -> Path | None:
    """Write ``samples`` under key ``k`` atomically, with its key, format, version and checksum; returns the
    path, or None when the cache directory is not writable (caching is an optimisation: it never fails a
    run)."""
    d = cache_dir()
    tmp = None
    meta = json.dumps({"key": k, "format": FORMAT, "version": __version__, "checksum": checksum(samples),
                       "shapes": {f: list(getattr(samples, f).shape) for f in FIELDS}})
    try:
        d.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{k[:16]}.", suffix=".npz", dir=d)
        with os.fdopen(fd, "wb") as f:
            np.savez(f, meta=np.asarray(meta), **{name: getattr(samples, name) for name in FIELDS})
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(tmp, 0o666 & ~mask)
        os.replace(tmp, d / f"{k}.npz")
        return d / f"{k}.npz"
    except OSError:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        return None


__all__ = ["FORMAT", "cache_dir", "check", "checksum", "key", "load", "store"]
