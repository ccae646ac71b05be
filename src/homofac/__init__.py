"""homofac: a few textures whose product, or short sum of products, reproduces a material in real time.

Layers, each importing only those below it (docs/architecture.md): :mod:`homofac.errors`, :mod:`homofac.sphere`
and :mod:`homofac.options`; :mod:`homofac.io` (image formats); :mod:`homofac.brdf` and :mod:`homofac.param`
(records: BRDF models, mappers, projections, parametrizations); :mod:`homofac.target` and
:mod:`homofac.factorization` (the schema-2 model); :mod:`homofac.light` and :mod:`homofac.shader`;
:mod:`homofac.baselines`; :mod:`homofac.fit`; :mod:`homofac.bake`; :mod:`homofac.output` and :mod:`homofac.gl`; :mod:`homofac.app`.
"""

from __future__ import annotations

from ._version import __version__
from . import app, bake, brdf, factorization, fit, gl, io, light, output, param, shader, sphere, target
from .errors import HomofacError
from .factorization import Factorization
from .output import load, save

__all__ = ["Factorization", "HomofacError", "app", "bake", "brdf", "factorization", "fit", "gl", "io", "light", "load",
           "output", "param", "save", "shader", "sphere", "target", "__version__"]
