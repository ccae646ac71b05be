"""homofac: homomorphic factorization of BRDFs and environment lighting into a few 2D textures."""

from __future__ import annotations

__version__ = "0.1.0"
