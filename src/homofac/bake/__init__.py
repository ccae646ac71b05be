"""homofac.bake: one bake per environment for every glTF 2.0 metallic-roughness material (layer L7).

``hf.bake(environment, preset=...)`` -> :class:`Bake` with ``evaluate(n, v, base_color, metallic,
roughness)``, ``lookups`` and ``save(dir)``; the structure of a preset is :func:`plan` (a printable record).
See :mod:`.build` for how the textures are computed and :mod:`.model` for how they are read.
"""

from __future__ import annotations

import sys
import types

from .build import bake, fibonacci, layer_size, source_size
from .model import Bake, register_writer
from .options import BakeOptions
from .plan import PRESETS, BakePlan, plan

__all__ = ["Bake", "BakeOptions", "BakePlan", "PRESETS", "bake", "fibonacci", "layer_size", "plan", "register_writer",
           "source_size"]


class _Callable(types.ModuleType):
    """``hf.bake(environment, ...)`` calls :func:`bake` while ``hf.bake.Bake`` etc. stay reachable (pinned API)."""

    def __call__(self, environment, options=None, **kwargs):
        return bake(environment, options, **kwargs)


sys.modules[__name__].__class__ = _Callable
