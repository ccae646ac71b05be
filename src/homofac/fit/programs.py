"""Compiled programs: keep a long session below the kernel's limit on memory mappings.

XLA keeps the machine code of every program it compiled for as long as JAX caches it, in about three
memory mappings each, and Linux allows a process ``vm.max_map_count`` of them (65530 by default). A
fit compiles some 150-550 programs for each new configuration (sizes, structure, sampling), so a
session that tries a few dozen configurations (a sweep in a notebook, a test suite: the slow suite's
workers reached 31000 mappings in 60 tests) would crash inside XLA's next compile, a segfault in
``backend_compile_and_load`` when a mapping fails. The fitting entry points (``factorize``,
``factorize_many``, ``refit``) call :func:`bound_compiled_programs` first: above :data:`MAX_MAPPINGS`
it clears JAX's compilation caches (every program, the caller's too, compiles again when next used).
"""

from __future__ import annotations

import gc

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


__all__ = ["MAX_MAPPINGS", "bound_compiled_programs", "mappings"]
