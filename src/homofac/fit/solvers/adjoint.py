"""A matrix-free linear operator whose transpose is given, not derived.

``lx.FunctionLinearOperator.transpose`` derives ``A^T`` with ``jax.linear_transpose``; for the gathers
of the ELL rows that is a scatter-add of every entry, which XLA's CPU backend runs far slower than the
gathers of :func:`homofac.fit.system.apply_transpose` (see :mod:`homofac.fit.system`).
:class:`AdjointOperator` is a ``FunctionLinearOperator`` (every lineax rule for it applies) that carries
the transposed function and returns it from ``transpose``; ``conj`` leaves it as it is (real operators).
"""

from __future__ import annotations

from typing import Callable

import equinox as eqx
import jax
import lineax as lx


class AdjointOperator(lx.FunctionLinearOperator):
    """``fn`` (x -> A x) with its given transpose ``adjoint`` (y -> A^T y); real dtypes only."""

    adjoint: Callable

    def __init__(self, fn: Callable, adjoint: Callable, input_structure: jax.ShapeDtypeStruct,
                 output_structure: jax.ShapeDtypeStruct):
        super().__init__(fn, input_structure)
        self.adjoint = eqx.filter_closure_convert(adjoint, output_structure)

    def transpose(self):
        return AdjointOperator(self.adjoint, self.fn, self.out_structure(), self.in_structure())


@lx.conj.register(AdjointOperator)
def _conj(operator: AdjointOperator) -> AdjointOperator:
    return operator


__all__ = ["AdjointOperator"]
