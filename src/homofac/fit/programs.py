"""Compiled programs: keep a long session below the kernel's limit on memory mappings.

XLA keeps the machine code of every program it compiled for as long as JAX caches it, in about three
memory mappings each, and Linux allows a process ``vm.max_map_count`` of them (65530 by default). A
fit compiles some 150-550 programs for each new configuration (sizes, structure, sampling), so a
session that tries a few dozen configurations (a sweep in a notebook, a test suite: the slow suite's
workers reached 31000 mappings in 60 tests) would crash inside XLA's next compile, a segfault in
``backend_compile_and_load`` when a mapping fails. The fitting entry points (``factorize``,
``factorize_many``, ``refit``) call :func:`bound_compiled_programs` first: above :data:`MAX_MAPPINGS`
it clears JAX's compilation caches (every program, the caller's too, compiles again when next used).

They also call :func:`enable_compilation_cache`: JAX's persistent compilation cache, so that a second
run of a configuration (or of any with the same program shapes) skips most of its compilation (a fit's
first run spends about a third of its time compiling; docs/notes/speed.md).
"""

from __future__ import annotations

import gc
import os
from pathlib import Path

import jax

#: Above this many mappings of the process (half the kernel's default limit), the caches are cleared.
MAX_MAPPINGS = 32768


def mappings() -> int:
    """The number of memory mappings of this process (``/proc/self/maps``; 0 where there is none)."""
    try:
        with open("/proc/self/maps", "rb") as f:
            return sum(1 for _ in f)
    except OSError:
        return 0


def bound_compiled_programs(limit: int = MAX_MAPPINGS) -> bool:
    """Clear JAX's caches (and collect the programs they held) when the process has more than ``limit``
    mappings; True when it did."""
    if mappings() <= limit:
        return False
    jax.clear_caches()
    gc.collect()
    return True


def compilation_cache_dir() -> Path | None:
    """``$HOMOFAC_JAX_CACHE`` (``0`` turns the cache off) or ``~/.cache/homofac/jax``; None when off or
    when the user configured JAX's own cache (``JAX_COMPILATION_CACHE_DIR`` or ``jax_compilation_cache_dir``:
    then JAX uses that)."""
    value = os.environ.get("HOMOFAC_JAX_CACHE")
    if value == "0" or os.environ.get("JAX_COMPILATION_CACHE_DIR") or jax.config.jax_compilation_cache_dir:
        return None
    return Path(value).expanduser() if value else Path.home() / ".cache" / "homofac" / "jax"


def enable_compilation_cache() -> Path | None:
    """Point JAX's persistent compilation cache at :func:`compilation_cache_dir`, for every program (a
    run's programs each compile in well under 0.2 s, so a time threshold would keep none); the
    directory, or None where it is off or JAX's own is configured. Programs compiled before (loading
    an environment compiles a few) do not stop it: JAX's check of the cache is reset. Never fails a run."""
    path = compilation_cache_dir()
    if path is None:
        return None
    try:
        path.mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", str(path))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        from jax._src import compilation_cache  # noqa: PLC0415 - JAX decides once whether its cache is used

        compilation_cache.reset_cache()
        return path
    except Exception:  # noqa: BLE001 - a cache is an optimisation
        return None


__all__ = ["MAX_MAPPINGS", "bound_compiled_programs", "compilation_cache_dir", "enable_compilation_cache", "mappings"]
