"""Shared fixtures: float64 on demand (float32 stays the library default)."""

from __future__ import annotations

import os
import tempfile

import jax
import pytest

# Samples cached by the tests go to a private directory, never to the user's ~/.cache.
os.environ.setdefault("HOMOFAC_CACHE_DIR", tempfile.mkdtemp(prefix="homofac-test-cache-"))
# ... and so do the CLIs' compiled programs (JAX's persistent compilation cache).
os.environ.setdefault("HOMOFAC_JAX_CACHE", tempfile.mkdtemp(prefix="homofac-test-jax-"))


@pytest.fixture
def x64():
    """Enable float64 for one test (references and exactness tests need it), then restore float32."""
    jax.config.update("jax_enable_x64", True)
    try:
        yield
    finally:
        jax.config.update("jax_enable_x64", False)
