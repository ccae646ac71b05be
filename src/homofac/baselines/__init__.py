"""homofac.baselines: what engines already do, computed (not fitted) into the same schema-2 model.

==================  ==========================================================================================
``split_sum``       :mod:`.split_sum`: Karis 2013 / Filament: kd/pi E(n) + P(r) W(n.v), W = F0 A + B (3 lookups)
``kautz_mccool``    :mod:`.kautz_mccool`: Kautz & McCool 2000 radially symmetric prefiltered lobes (2D or sliced)
==================  ==========================================================================================

and :mod:`.svd`, Mahajan et al. 2008's in-out analysis (how many product terms a target needs). A
baseline is chosen like a parametrization (``parametrization: split_sum``; ``hf.fit.factorize(target,
"split_sum")``); its options are the config's ``baseline`` section.
"""

from __future__ import annotations

from typing import Any

from ..errors import HomofacError
from ..options import validate
from . import kautz_mccool, split_sum, svd
from .base import Baseline
from .svd import SVDAnalysis, analyse

#: The registered baselines by name.
BASELINES: dict[str, Baseline] = {b.BASELINE.name: b.BASELINE for b in (split_sum, kautz_mccool)}


def get(name: str) -> Baseline:
    if name not in BASELINES:
        raise HomofacError(f"unknown baseline {name!r}; known: {', '.join(BASELINES)}")
    return BASELINES[name]


def build(name: str, target, mapper: str, texture_size: int, options: Any = None):
    """The model of baseline ``name`` for ``target`` (options validated by the baseline's option model)."""
    b = get(name)
    return b.build(target, mapper, texture_size, validate(b.options, options, "baseline"))


__all__ = ["BASELINES", "Baseline", "SVDAnalysis", "analyse", "build", "get", "kautz_mccool", "split_sum", "svd"]
