"""Shared fixtures and the test environment: private caches, float64 on demand.

The suite is hermetic: no test reads a path outside the repository (bundled data, tests/data, or
files the tests generate). JAX's persistent compilation cache for the tests lives in the repository's
``.cache/jax-tests`` (ignored by git): the second run of the suite skips most XLA compilation.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import jax
import pytest

ROOT = Path(__file__).resolve().parents[1]

# Samples cached by the tests go to a private directory, never to the user's ~/.cache.
os.environ.setdefault("HOMOFAC_CACHE_DIR", tempfile.mkdtemp(prefix="homofac-test-cache-"))
# The CLIs' compiled programs (subprocesses, and in-process CLI calls) share the tests' cache.
_JAX_CACHE = ROOT / ".cache" / "jax-tests"
os.environ.setdefault("HOMOFAC_JAX_CACHE", str(_JAX_CACHE))
try:
    _JAX_CACHE.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(_JAX_CACHE))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
except OSError:  # a read-only checkout: compile as usual
    pass


def _float64():
    jax.config.update("jax_enable_x64", True)
    try:
        yield
    finally:
        jax.config.update("jax_enable_x64", False)


@pytest.fixture
def x64():
    """Enable float64 for one test (references and exactness tests need it), then restore float32."""
    yield from _float64()


@pytest.fixture(scope="module")
def x64_module():
    """float64 for a whole module's fits and gradients (module-scoped fixtures built in it), restored afterwards."""
    yield from _float64()
