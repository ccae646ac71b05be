"""The bound on compiled programs (homofac.fit.programs): XLA keeps each program's code in memory
mappings, the kernel allows a process 65530; above the bound the caches are cleared and the mappings
go back."""

from __future__ import annotations

import gc

import jax
import jax.numpy as jnp
import pytest

from homofac.fit import programs


@pytest.mark.skipif(programs.mappings() == 0, reason="no /proc/self/maps")
def test_compiled_programs_hold_mappings_and_the_bound_releases_them():
    gc.collect()  # programs of earlier tests in this worker freed now, not in the middle of the checks
    before = programs.mappings()
    for i in range(30):  # 30 distinct programs (each shape compiles anew)
        jax.jit(lambda x, i=i: (jnp.sin(x) * (i + 1)).sum())(jnp.ones((i + 2,))).block_until_ready()
    gc.collect()
    grown = programs.mappings()
    assert grown - before >= 30  # about three per program on XLA:CPU
    assert not programs.bound_compiled_programs(limit=grown + 1000)  # under the bound: nothing cleared
    assert programs.mappings() >= grown - 20  # allocator noise (a cleared cache frees 3 a program: > 90)
    assert programs.bound_compiled_programs(limit=before)  # over it: cleared
    assert programs.mappings() < grown - 30
