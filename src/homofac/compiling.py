"""XLA compiler options of the library's programs: one rule, by what a program is.

XLA CPU has two code generators for fused element-wise work: its MLIR *fusion emitters* (the default) and
its older *loop emitters* (``xla_cpu_use_fusion_emitters: false``). The loop emitters compile a program in
about 0.5-0.7x the CPU and run it 0-55 % slower (the more arithmetic per element, the slower). A program
compiled for a few calls is compile-bound, so it takes the loop emitters; a program whose runs outweigh its
compile (many calls, or few wide ones) keeps the fusion emitters. Each program names its kind where it is
compiled (:func:`jit`, ``@jit(kind="lookup")``); the kinds, their options and the evidence are this table. A
program with no kind compiles with XLA's defaults (the fusion emitters): it is not measured. XLA takes the
options of a whole program only: a program called inside another's trace (an outer ``jax.jit``, ``grad``,
``vmap``) is part of the outer program and runs without its own.

The evidence (benchmarks/emitter_profile.py, every program's compile and run CPU on both emitters, gold /
forest ``fast`` and ``balanced`` and the forest bake; docs/notes/speed.md, "Compilation, twenty-first
session"), CPU s net of the loop emitters against the fusion emitters, ``fast`` / ``balanced``:

- ``lighting rows`` (the grouped lighting on rows of at most 8 views: a plan's decision, the validation
  values; 14 calls): -0.6 / -1.2. ``lighting grid`` (the training grid's rows of 64 views, 14-26 calls
  of 3x the work): +1.2 / +2.4, fusion emitters.
- ``lookup`` (factor lookups, footprints, the quantized evaluation, texture normalization): -1.2 / -3.0.
- ``texture`` (tables computed once: the E texture, the split sum's DFG table; the bake's kernels): -0.8 /
  -0.8; the bake (``balanced``, forest) -1.1 (its DFG 26 calls, -0.5; its lobes 17 calls, -0.1).
- ``polish`` (the Levenberg-Marquardt program: one call): ``balanced`` -1.3.
- ``filter`` (the bake's prefilter of the environment, the maps: 9 tiled calls, 108 others): +4.2 in the
  bake (its runs 1.8-2x slower), fusion emitters.
- not given a kind: the ALS sweep (``fast`` -1.4, ``balanced`` -1.1: its compile 0.6-0.7x, each of its runs
  15 % slower; ``balanced`` runs 24 calls per compile and ``best`` more, so where it turns is not measured).
"""

from __future__ import annotations

import functools
from typing import Callable

import equinox as eqx
import jax

#: XLA CPU's loop emitters: about half the compile CPU, a slower run.
LOOP_EMITTERS = {"xla_cpu_use_fusion_emitters": False}
#: XLA's defaults (the fusion emitters).
FUSION_EMITTERS: dict = {}

#: What a program is -> its XLA compiler options (module docstring: the evidence per kind).
PROGRAM_KINDS: dict[str, dict] = {
    "lighting rows": LOOP_EMITTERS,
    "lighting grid": FUSION_EMITTERS,
    "lookup": LOOP_EMITTERS,
    "texture": LOOP_EMITTERS,
    "polish": LOOP_EMITTERS,
    "filter": FUSION_EMITTERS,
}


def compiler_options(kind: str) -> dict:
    """The XLA compiler options of a program of ``kind`` (a key of :data:`PROGRAM_KINDS`), for the
    ``compiler_options`` argument of ``jax.jit`` / ``eqx.filter_jit``."""
    return dict(PROGRAM_KINDS[kind])


def jit(fun: Callable | None = None, *, kind: str, filter: bool = False, **jit_kwargs):
    """``jax.jit(fun, **jit_kwargs)`` (``eqx.filter_jit`` with ``filter``) compiled with the options of its
    ``kind`` (:func:`compiler_options`) where it is called outside any JAX trace; called with a traced
    argument (inside an outer ``jax.jit``, ``grad``, ``vmap``: JAX refuses a nested program's own options) it
    is the plain jit. Usable as ``@jit(kind=...)`` or ``jit(fun, kind=...)``; ``.lower`` is the compiled
    program's, ``.clear_cache`` drops both programs' executables."""
    if fun is None:
        return functools.partial(jit, kind=kind, filter=filter, **jit_kwargs)
    make = eqx.filter_jit if filter else jax.jit
    options = compiler_options(kind)
    own = make(fun, compiler_options=options, **jit_kwargs) if options else make(fun, **jit_kwargs)
    plain = make(fun, **jit_kwargs)

    @functools.wraps(fun)
    def call(*args, **kwargs):
        traced = any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves((args, kwargs)))
        return (plain if traced else own)(*args, **kwargs)

    def clear_cache() -> None:
        """Drop both programs' compiled executables (``jax.jit``'s ``clear_cache``)."""
        for f in {id(own): own, id(plain): plain}.values():
            getattr(f, "clear_cache", lambda: None)()

    call.lower = own.lower
    call.clear_cache = clear_cache
    return call


__all__ = ["FUSION_EMITTERS", "LOOP_EMITTERS", "PROGRAM_KINDS", "compiler_options", "jit"]
