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
values under ``jax.grad``) gets no key and is never cached. Entries are ``<dir>/<key>.npz``, written
to a temporary file and renamed, so a crash never leaves a half-written entry that a later run reads.

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

#: Bump when the sampling code changes what it produces for the same inputs.
FORMAT = 1


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


def load(k: str):
    """The cached :class:`~homofac.fit.samples.Samples` of key ``k``, or None (missing or unreadable)."""
    path = cache_dir() / f"{k}.npz"
    try:
        with np.load(path) as z:
            return Samples(*(np.asarray(z[f]) for f in FIELDS))
    except (OSError, KeyError, ValueError, EOFError):
        return None  # missing, or damaged: resample (and overwrite it whole)


def store(k: str, samples) -> Path | None:
    """Write ``samples`` under key ``k`` atomically; returns the path, or None when the cache directory is
    not writable (caching is an optimisation: it never fails a run)."""
    d = cache_dir()
    tmp = None
    try:
        d.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{k[:16]}.", suffix=".npz", dir=d)
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **{name: getattr(samples, name) for name in FIELDS})
        os.replace(tmp, d / f"{k}.npz")
        return d / f"{k}.npz"
    except OSError:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        return None


__all__ = ["FORMAT", "cache_dir", "key", "load", "store"]
