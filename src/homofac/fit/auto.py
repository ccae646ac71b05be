"""``target_error``: the cheapest parametrization and texture size whose validation error meets a target.

A user often knows the error they can accept, not which parametrization reaches it. :func:`choose`
fits candidates in order of cost and returns the first whose validation ``nrmse`` (float textures, the
pinned metric of docs/conventions.md) is at most ``target_error``:

* candidates: every parametrization registered for the target's kind on the chosen mapper, at texture
  sizes 8, 16, 32, 64 up to ``max_size``;
* cost: the texture memory a renderer pays, ``T x`` valid texels per texture, and then the number of
  factors J (texture lookups per pixel) -- so NR at 16 comes before NRV at 16, and N at 32 before NR
  at 32;
* all candidates share one set of samples (drawn once; with the sample cache also across runs), so the
  comparison is on the same validation pairs and the search costs one sampling plus small solves.

The choice is recorded on the result (``selection`` in factorization.json): the target, every candidate
tried with its error, and the reason. When none meets the target the best one tried is returned with
a warning that says so; the error promised is the validation error actually measured.
"""

from __future__ import annotations

from typing import Callable

from ..errors import HomofacError
from ..light import with_context
from ..param import parametrizations as pz
from .system import parametrization_layout

#: Texture sizes tried (each at most ``max_size``).
SIZES = (8, 16, 32, 64)


def candidates(kind: str, mapper: str, max_size: int, names: list[str] | None = None) -> list[dict]:
    """The (parametrization, size) pairs to try, cheapest first (see the module docstring)."""
    if names is None:
        names = list(pz.names(kind))
    out = []
    for name in names:
        p = pz.get(name, kind)
        for size in SIZES:
            if size > max_size:
                continue
            cost = parametrization_layout(p, mapper, size).n_unknowns
            out.append({"parametrization": name, "texture_size": size, "cost": cost, "lookups": p.J})
    return sorted(out, key=lambda c: (c["cost"], c["lookups"], c["parametrization"]))


def choose(
    target,
    target_error: float,
    fit: Callable,
    samples,
    *,
    mapper: str,
    max_size: int = 64,
    parametrizations: list[str] | None = None,
    log: Callable[[str], None] | None = None,
):
    """Fit candidates cheapest first; return the first result whose validation nrmse <= target_error.

    Args:
        target: the target to factor.
        target_error: the largest acceptable validation nrmse (float textures), > 0.
        fit: ``fit(target, parametrization, texture_size) -> Result`` on the shared ``samples``
            (:func:`homofac.fit.pipeline.factorize` passes its product fit).
        samples: the shared samples (their validation set must not be empty).
        mapper: the mapper of every candidate.
        max_size: the largest texture size tried.
        parametrizations: restrict the candidates (default: all of the target's kind).
        log: progress callback.
    """
    log = log or (lambda msg: None)
    cands = candidates(target.kind, mapper, max_size, parametrizations)
    if not cands:
        raise HomofacError(f"target_error: no candidate texture size up to {max_size} (the smallest tried is {SIZES[0]})")
    if len(samples.val_a) == 0:
        raise HomofacError("target_error needs validation samples (sampling.validation > 0)")
    tried, best = [], None
    for c in cands:
        log(f"target_error {target_error:g}: trying {c['parametrization']} at {c['texture_size']}")
        fac = fit(_target_for(target, c["parametrization"]), c["parametrization"], c["texture_size"])
        err = float(fac.metrics["validation"]["float"]["nrmse"])
        tried.append({**c, "validation_nrmse": err, "met": err <= target_error})
        if best is None or err < best[1]:
            best = (fac, err)
        if err <= target_error:
            reason = (f"{c['parametrization']} at {c['texture_size']} is the cheapest candidate "
                      f"({c['cost']} texels, {c['lookups']} lookups) with validation nrmse {err:.4g} <= {target_error:g}")
            log(reason)
            return _record(fac, target_error, tried, reason, met=True)
    fac, err = best
    reason = (f"no candidate up to size {max_size} meets target_error {target_error:g}; the best tried is "
              f"{fac.parametrization} at {fac.texture_size} with validation nrmse {err:.4g}")
    log("warning: " + reason)
    fac = fac.replace(warnings=tuple(fac.warnings) + (reason,))
    return _record(fac, target_error, tried, reason, met=False)


def _target_for(target, name: str):
    """The target with the context ``name``'s projections need (NRHD's dominant light direction)."""
    return with_context(target, name) if target.kind == "lighting" else target


def _record(fac, target_error, tried, reason, met):
    return fac.replace(selection={
        "target_error": float(target_error), "metric": "validation.float.nrmse", "met": met,
        "chosen": {"parametrization": fac.parametrization, "texture_size": fac.texture_size},
        "reason": reason, "tried": tried,
    })


__all__ = ["SIZES", "candidates", "choose"]
