"""What a refit reuses of a fit (``Result.state``): the layout, the sample directions, the solver's work.

A fit fixes a *layout*: the parametrization (or sum structure, or baseline), the mappers and sizes
of the textures, and the training and validation directions. The log-space least-squares matrix of
a product (thesis eq. 37: data rows of bilinear weights, Laplacian rows) depends on the layout only;
a new environment or material changes the right-hand side alone. :class:`RefitState` holds the
layout and the directions (grouped by normal for lighting targets, so the lighting's per-normal fast
path applies) and a memo (``cache``) of what the first refit derives and every later one reuses: the
system's rows, the Cholesky factor of the normal equations, the previous solution (a warm start) and
the light transport of :mod:`homofac.fit.transport`.

:func:`from_fit` builds it at the end of :func:`homofac.fit.factorize`; :func:`from_options` rebuilds it
for a result read back from disk, from its recorded config (sampling is deterministic: the same seeds
give the same directions).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from .. import baselines
from ..errors import HomofacError
from ..param import parametrizations as pz
from . import sampling, scene
from .draw import draw_pairs
from .options import FitOptions, SamplingOptions
from .samples import Samples
from .structures import Structure


@dataclasses.dataclass(frozen=True)
class RefitState:
    """The layout and directions of a fit, and the memo of what refits derive from them.

    ``mode``: ``product`` (log-space product), ``sum`` (linear-space sum of products, ``structure``) or
    ``baseline`` (computed). ``train`` and ``validation`` are the direction pairs (``Pairs``), and for
    lighting targets ``groups`` / ``val_groups`` the same pairs grouped by normal. ``scene``: the image-space
    pixels of a ``sampling.kind: scene`` fit (:mod:`homofac.fit.scene`), for its scene metrics.
    """

    options: FitOptions
    kind: str
    mode: str
    parametrization: str
    mapper: str
    texture_size: int
    train: sampling.Pairs
    validation: sampling.Pairs
    groups: sampling.Grouped | None = None
    val_groups: sampling.Grouped | None = None
    structure: Structure | None = None
    scene: Any = None
    cache: dict = dataclasses.field(default_factory=dict, compare=False, repr=False)

    def samples(self, y, val_y) -> Samples:
        """The samples of this layout with new values."""
        return Samples(self.train.a, self.train.b, np.asarray(y, np.float32), self.validation.a,
                       self.validation.b, np.asarray(val_y, np.float32))


def _mode(opts: FitOptions) -> str:
    if opts.parametrization in baselines.BASELINES:
        return "baseline"
    return "sum" if opts.is_sum else "product"


def _structure(result) -> Structure | None:
    rec = (result.solver or {}).get("structure")
    if not isinstance(rec, dict):
        return None
    return Structure.of(rec)


def from_fit(opts: FitOptions, kind: str, samples: Samples, result, mapper: str, scene=None) -> RefitState:
    """The state of a fit that just ran (its options, samples and result)."""
    mode = _mode(opts)
    structure = _structure(result) if mode == "sum" else None
    if mode == "sum" and structure is None:
        raise HomofacError("refit state: the sum's structure is not recorded in the result")
    name = structure.parametrization if structure is not None else (
        opts.parametrization if mode == "baseline" else result.model.name)
    size = int(result.texture_size)
    train = sampling.Pairs(np.asarray(samples.a, np.float32), np.asarray(samples.b, np.float32))
    val = sampling.Pairs(np.asarray(samples.val_a, np.float32), np.asarray(samples.val_b, np.float32))
    groups = val_groups = None
    if kind == "lighting":
        groups, val_groups = sampling.regroup(train.a, train.b), sampling.regroup(val.a, val.b)
    return RefitState(opts, kind, mode, name, mapper, size, train, val, groups, val_groups, structure, scene)


def from_layout(opts: FitOptions, kind: str, samples: Samples, mapper: str, scene=None) -> RefitState:
    """The state of the layout ``opts`` describes (no fit yet: products, sums and baselines of fixed
    structure), on the directions of ``samples`` (``scene``: the scene of a scene sampling)."""
    mode = _mode(opts)
    structure = opts.structure() if mode == "sum" else None
    train = sampling.Pairs(np.asarray(samples.a, np.float32), np.asarray(samples.b, np.float32))
    val = sampling.Pairs(np.asarray(samples.val_a, np.float32), np.asarray(samples.val_b, np.float32))
    groups = val_groups = None
    if kind == "lighting":
        groups, val_groups = sampling.regroup(train.a, train.b), sampling.regroup(val.a, val.b)
    return RefitState(opts, kind, mode, opts.parametrization, mapper, int(opts.texture_size), train, val, groups,
                      val_groups, structure, scene)


def check_layout(opts: FitOptions, mode: str, result, mapper: str) -> None:
    """Refuse (one line) a saved model whose layout contradicts its recorded config: texture size and
    mapper, and a product's parametrization (a chooser's, ``target_error``, are limits, not checked). A
    refit follows the model and records the config, so an output's config would contradict its textures."""
    if opts.target_error is not None:
        return
    saved = (result.model.name if mode == "product" else None, result.mapper, int(result.texture_size))
    recorded = (opts.parametrization if mode == "product" else None, mapper, int(opts.texture_size))
    if saved != recorded:
        what = ", ".join(f"{k} {a!r} in the textures, {b!r} in the config" for k, a, b
                         in zip(("parametrization", "mapper", "texture_size"), saved, recorded) if a != b)
        raise HomofacError(f"refit: the saved factorization contradicts its recorded config ({what}); "
                           "its factorization.json was edited or is stale: fit it again")


def from_options(opts: FitOptions, kind: str, result, mapper: str, sampling_options: SamplingOptions) -> RefitState:
    """The state of a result read back from disk: its directions drawn again from ``sampling_options``
    (the resolved sampling of the recorded config) and its layout from the model."""
    mode = _mode(opts)
    structure = _structure(result) if mode == "sum" else None
    if mode == "sum" and structure is None:
        raise HomofacError("refit: the saved sum of products does not record its structure (solver.structure)")
    if mode == "product" and result.model.name not in pz.PARAMETRIZATIONS:
        raise HomofacError(f"refit: the saved model {result.model.name!r} is not a parametrization")
    name = structure.parametrization if structure is not None else (
        opts.parametrization if mode == "baseline" else result.model.name)
    check_layout(opts, mode, result, mapper)
    train, val, groups, vgroups = draw_pairs(kind, name, sampling_options, result.model.context)
    if len(train) == 0:
        raise HomofacError("refit: the recorded sampling produces no training pairs")
    if groups is not None:  # the pairs exactly as the fit had them (normal-major)
        groups, vgroups = sampling.regroup(train.a, train.b), sampling.regroup(val.a, val.b)
    sc = scene.load(sampling_options) if sampling_options.kind == "scene" else None
    return RefitState(opts, kind, mode, name, mapper, int(result.texture_size), train, val, groups, vgroups,
                      structure, sc)


__all__ = ["RefitState", "check_layout", "from_fit", "from_layout", "from_options"]
