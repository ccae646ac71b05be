"""homofac: homomorphic factorization of BRDFs and environment lighting into a few 2D textures.

Subpackages: :mod:`homofac.brdf` (BRDF models), :mod:`homofac.light` (environments and the lighting
computation), :mod:`homofac.param` (direction mappers and parametrizations), :mod:`homofac.fit`
(sampling, system, solvers, metrics, the CLI) and :mod:`homofac.io` (files); :mod:`homofac.gl` is the OpenGL preview
(moderngl is imported only when something is rendered).
"""

from __future__ import annotations

__version__ = "0.1.0"

from . import brdf, fit, gl, io, light, param, sphere  # noqa: E402
from .errors import HomofacError  # noqa: E402

__all__ = ["HomofacError", "brdf", "fit", "gl", "io", "light", "param", "sphere", "__version__"]
