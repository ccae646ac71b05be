"""The lighting the validation pairs read: converged, so that the votes rank fits, not light texels.

Every vote of a fit (structure, lines, disc, polish; ``target_error``'s "the first that meets it") reads
the validation nrmse. Against the lighting at the fit's own light resolution r that figure carries the
lighting's own discretisation error: under small lamps (the bundled interior and studio) the values at
r = 32 are 9-10 % from converged, as large as the candidates' differences (docs/notes/validation.md).

:func:`decide` picks the validation light resolution R from the environment and the BRDF by doubling:
the validation lighting is evaluated at r, 2r, 4r, ... on the first :data:`DECISION_NORMALS` normals of
the validation pairs, and R is the first resolution whose next doubling changes the values by an nrmse
(pinned definition) below :data:`TOLERANCE`. A lighting error d moves a fit's nrmse e to
sqrt(e^2 + d^2) when the two are uncorrelated, so d < :data:`TOLERANCE` moves a fit of nrmse
:data:`FIT_NRMSE` by less than :data:`MOVE` (1 %). The doubling stops at
:data:`MAX_RESOLUTION`, and :data:`MAX_DOUBLINGS` above the fit's (the cost); the decision then says it
did not converge, and by how much.

The lighting at R (:func:`lighting_at`) refines only where the light is: the fit's light texels that
hold :data:`SHARE` of the power are replaced by the texels of the map at R inside them
(:func:`homofac.light.refine.mixture`), the dim rest stays at r. Measured on 4000 validation pairs
against the full map at 128: 0.0018 nrmse (metal / interior; 0.0514 at r = 32), 0.0022 (mirror /
studio; 0.174), 0.0009 (metal / forest; 0.029), 0.0006 (plastic / city; 0.004), with 9 % to 47 % of
the lights. How the finer map is made (its file reloaded, an analytic sky rebuilt, else its texels
split): :mod:`homofac.light.refine`.

The refined lighting is summed by a two-level light tree (:func:`light_sum`, :mod:`homofac.light.tree`):
every pair sums the fit's light texels (the refined ones aggregated) and replaces the
:data:`REFINED_LIGHTS` / (R/r)^2 cells of largest contribution by their fine texels, about 6x cheaper
than every light at R = 4r, within 0.2-0.3 % nrmse of the full sum (benchmarks/light_tree.md). Below
:data:`TREE_MIN_START` the fit's texels are too few to be a coarse level, and where the refined lighting
has few more lights than the tree evaluates (:data:`TREE_GAIN`) the full sum is cheaper: both use it.

The decision is a plan value (:class:`ValidationLight`, :func:`homofac.fit.plan.build_plan`): printed by
``--plan`` and recorded in factorization.json (``selection.validation_light``), the light sum with it. Its
values are computed as the validation values are (:mod:`homofac.fit.levels`: the grouped program at the fit's
own lights, light blocks at a refined level), and its pairs' values at R are kept, so the validation values
of the fit evaluate only the other normals.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..errors import HomofacError
from ..light import Lighting
from ..light.lighting import max_visible
from ..light.refine import at_resolution, bright_texels, mixture, route
from ..light.tree import light_tree
from ..target import Target
from . import cache, levels, sampling
from .draw import VALIDATION_VIEWS
from .metrics import metrics

#: The relative move of a fit's validation nrmse that one more doubling of the lights may cause (issue 41).
MOVE = 0.01
#: The fit nrmse :data:`MOVE` is stated for: the presets' fits reach 0.05-0.25 on the accuracy
#: benchmark (a fit of 0.05 moves by under 4 %).
FIT_NRMSE = 0.1
#: The largest change (nrmse) of the validation values per doubling: sqrt(e^2 + d^2) <= (1 + MOVE) e.
TOLERANCE = FIT_NRMSE * math.sqrt((1.0 + MOVE) ** 2 - 1.0)
#: The share of the power whose light texels are refined (the rest stays at the fit's resolution).
SHARE = 0.9
#: The finest validation light resolution (the accuracy benchmark's ground truth converges by 256).
MAX_RESOLUTION = 256
#: The most doublings above the fit's light resolution (64 x its lights at most: the cost of the
#: validation values grows with the lights; the fit's own 32 reaches :data:`MAX_RESOLUTION`).
MAX_DOUBLINGS = 3
#: Normals of the validation pairs the doubling is measured on (:data:`~homofac.fit.draw.VALIDATION_VIEWS`
#: views each).
DECISION_NORMALS = 256
#: Fine lights each pair sums of the two-level light tree (:func:`light_sum`): the refined cells are
#: ``REFINED_LIGHTS // (R / r)^2`` (R = 2r: 256 cells, 4r: 64, 8r: 16).
REFINED_LIGHTS = 1024
#: The smallest fit light resolution whose texels are the tree's coarse level (fewer: the full sum).
TREE_MIN_START = 16


#: The tree is used where the refined lighting has this many times the lights above a horizon that the tree
#: evaluates per view (its coarse cells and its refined cells' lights): below it the full sum is cheaper
#: (mirror / studio at 64, 6576 visible lights: 2.8 s CPU the full sum, 4.6 s the tree; benchmarks/light_tree.md).
TREE_GAIN = 2.0


def light_sum(start: int, resolution: int, visible: int) -> tuple[int, int] | None:
    """How the validation lighting at ``resolution`` R is summed when the fit's lights are at ``start`` r and
    the refined lighting has ``visible`` lights above a horizon (``info["max_visible"]``): ``(coarse face
    size, refined cells per pair)`` of the two-level light tree (the coarse cells are the fit's own texels,
    each refined one summed over its (R/r)^2 texels at R), or None for the full sum (R = r: nothing refined;
    r below :data:`TREE_MIN_START`: too few coarse cells to be exact; fewer than :data:`TREE_GAIN` x the
    tree's evaluations: the full sum is cheaper)."""
    start, resolution = int(start), int(resolution)
    if resolution <= start or start < TREE_MIN_START:
        return None
    refined = max(1, REFINED_LIGHTS // (resolution // start) ** 2)
    work = 3 * start * start + 6 * start + 2 * refined * (resolution // start) ** 2
    return (start, refined) if int(visible) > TREE_GAIN * work else None


@dataclasses.dataclass(frozen=True)
class ValidationLight:
    """The validation lighting a plan decided: ``resolution`` R (the fit's ``start`` where nothing finer
    exists or is needed), ``route`` (how the finer map is made, :data:`homofac.light.refine.ROUTES`),
    ``changes`` ((r, nrmse of the values at r against 2r) per doubling measured), ``converged`` (the last
    change is below ``tolerance``), ``lights`` (the lights of the validation lighting), ``light_sum``
    (:func:`light_sum`: the two-level light tree's coarse face size and refined cells, None: every light)."""

    resolution: int
    start: int
    route: str
    changes: tuple[tuple[int, float], ...]
    converged: bool
    tolerance: float
    lights: int
    light_sum: tuple[int, int] | None = None

    def record(self) -> dict[str, Any]:
        """Plain data (the plan's JSON and factorization.json's ``selection.validation_light``)."""
        return {"resolution": self.resolution, "start": self.start, "route": self.route,
                "changes": [{"resolution": r, "nrmse_to_double": c} for r, c in self.changes],
                "converged": self.converged, "tolerance": self.tolerance, "share": SHARE, "lights": self.lights,
                "light_sum": None if self.light_sum is None else {"coarse": self.light_sum[0], "refined": self.light_sum[1]}}

    def describe(self) -> str:
        """One line of the printed plan."""
        last = f"{self.changes[-1][1]:.4f}" if self.changes else "0"
        where = (f"the lights holding {SHARE:.0%} of the power at resolution {self.resolution}, the rest at "
                 f"{self.start}" if self.resolution != self.start else f"lights at resolution {self.start}")
        if self.light_sum is not None:
            where += (f", summed by a light tree (the {self.light_sum[1]} cells of face size {self.light_sum[0]} "
                      f"of largest contribution refined per pair)")
        if not self.changes:
            why = "advanced.validation_light" if self.route == "given" else f"at the limit, {MAX_RESOLUTION}"
            return f"{where} ({self.lights} lights; {why}, no doubling measured)"
        verdict = (f"one more doubling moves the values by {last} nrmse < {self.tolerance:.4f} (a fit of nrmse "
                   f"{FIT_NRMSE:g} by < {MOVE:.0%})" if self.converged else
                   f"not converged: one more doubling moves the values by {last} nrmse (the limit: {MAX_DOUBLINGS} "
                   f"doublings, resolution {MAX_RESOLUTION})")
        return f"{where} ({self.lights} lights, {self.route}); {verdict}"


def environment(target: Target):
    """The environment of a lighting target with cube texels to refine, else None."""
    env = getattr(target.fn, "env", None) if target.kind == "lighting" else None
    if env is None or not isinstance(target.fn, Lighting) or not env.info.get("resolution"):
        return None
    return env if env.num_lights >= 6 * int(env.info["resolution"]) ** 2 else None


_RULE = object()


def lighting_at(target: Target, resolution: int, summed=_RULE) -> Target:
    """``target`` with its lights refined to ``resolution`` where :data:`SHARE` of the power is (module
    docstring), summed as ``summed`` says (a plan's ``ValidationLight.light_sum``: a light tree's
    ``(coarse, refined)`` or None for every light; not given: :func:`light_sum`); ``target`` itself at its
    own resolution or without an environment to refine."""
    env = environment(target)
    if env is None or int(resolution) == int(env.info["resolution"]):
        return target
    fine = mixture(env, at_resolution(env, int(resolution)), bright_texels(env, SHARE))
    how = light_sum(int(env.info["resolution"]), int(resolution), max_visible(fine)) if summed is _RULE else summed
    tree = None if how is None else light_tree(fine, *how)
    return Target(target.kind, dataclasses.replace(target.fn, env=fine, tree=tree), target.quantity, dict(target.context))


def given(target: Target, resolution: int) -> ValidationLight:
    """The validation lighting at ``resolution`` as given (``advanced.validation_light``): a multiple of the
    fit's light resolution by a power of 2 (refused in one line otherwise); nothing measured."""
    env = environment(target)
    start = int(env.info["resolution"])
    f = int(resolution) // start
    if int(resolution) % start or f & (f - 1):
        raise HomofacError(f"advanced.validation_light must be the light resolution {start} times a power of 2 "
                           f"(the validation refines the fit's light texels), got {resolution}")
    fine = lighting_at(target, int(resolution), None).fn.env
    return ValidationLight(resolution=int(resolution), start=start, route="given", changes=(), converged=False,
                           tolerance=TOLERANCE, lights=int(fine.num_lights),
                           light_sum=light_sum(start, int(resolution), max_visible(fine)))


def decision_pairs(count: int, seed: int) -> sampling.Grouped:
    """The validation pairs the doubling is measured on: the first :data:`DECISION_NORMALS` normals of the
    ``count`` validation pairs of ``seed`` (:func:`homofac.fit.draw.draw_pairs` draws them the same way)."""
    g = sampling.grouped_random(count, seed, views=VALIDATION_VIEWS)
    k = min(DECISION_NORMALS, len(g.normals))
    return sampling.Grouped(g.normals[:k], g.views[:k], g.mask[:k])


#: Decisions of this process by the hash of the target's arrays, the pair count and the seed (a plan
#: built again for the same target, as ``--plan`` then the fit, or a test module, decides once).
_DECIDED: dict[str, ValidationLight] = {}


def decide(target: Target, count: int, seed: int, log=None) -> ValidationLight | None:
    """The validation light resolution of ``target`` (module docstring): doubling from the fit's own
    until one more doubling changes the values on :func:`decision_pairs` by less than :data:`TOLERANCE`,
    at most :data:`MAX_RESOLUTION` and :data:`MAX_DOUBLINGS` doublings. None for a target without cube
    texels (nothing to refine)."""
    log = log or (lambda msg: None)
    env = environment(target)
    if env is None or count <= 0:
        return None
    k = cache.key(target, {"validation_light": [int(count), int(seed), TOLERANCE,
                                                SHARE, MAX_RESOLUTION, MAX_DOUBLINGS, route(env),
                                                REFINED_LIGHTS, TREE_MIN_START, TREE_GAIN]}, "")
    if k is not None and k in _DECIDED:
        return _DECIDED[k]
    found = _decide(target, env, count, seed, log)
    if k is not None:
        _DECIDED[k] = found
    return found


def _decide(target: Target, env, count: int, seed: int, log) -> ValidationLight:
    start = int(env.info["resolution"])
    how = route(env)
    pairs = decision_pairs(count, seed)
    r, changes = start, []
    y = y0 = levels.evaluate(target, pairs, refined=False)
    summed = False  # y is the sum over every light (not a light tree's)
    limit = min(MAX_RESOLUTION, start << MAX_DOUBLINGS)
    while 2 * r <= limit:
        # every light: the fit's program on the refined texels' difference where few blocks hold it (no
        # program of the level's own), else the level's lighting as the validation values read it
        y2 = levels.refined(target, lighting_at(target, 2 * r, None), pairs, y0)
        summed2 = y2 is not None
        if not summed2:
            y2 = levels.evaluate(lighting_at(target, 2 * r), pairs, refined=True)
        change = float(metrics(y, y2)["nrmse"])
        changes.append((r, change))
        log(f"validation lighting: resolution {r} -> {2 * r} changes the values by {change:.4f} nrmse")
        if change < TOLERANCE:
            break
        r, y, summed = 2 * r, y2, summed2
    converged = bool(changes) and changes[-1][1] < TOLERANCE
    at = lighting_at(target, r)
    if r == start or not (summed and at.fn.tree is not None):  # the values as the validation values read them:
        levels.remember(at, pairs, r != start, y)  # those at r reuse these pairs' (levels.values)
    fine = at.fn.env
    return ValidationLight(resolution=r, start=start, route=how, changes=tuple(changes), converged=converged,
                           tolerance=TOLERANCE, lights=int(fine.num_lights), light_sum=light_sum(start, r, max_visible(fine)))


__all__ = ["DECISION_NORMALS", "FIT_NRMSE", "MAX_DOUBLINGS", "MAX_RESOLUTION", "MOVE", "REFINED_LIGHTS", "SHARE", "TOLERANCE",
           "TREE_GAIN", "TREE_MIN_START", "ValidationLight", "decide", "decision_pairs", "environment", "given", "light_sum", "lighting_at"]
