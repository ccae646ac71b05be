"""homofac.blas: the BLAS thread count is set inside the block and restored after it."""

import numpy as np
from threadpoolctl import threadpool_info

from homofac.blas import blas_threads


def _blas_threads() -> list[int]:
    return [info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"]


def test_blas_threads_sets_and_restores_every_loaded_blas():
    np.linalg.eigh(np.eye(4))  # numpy's LAPACK loaded
    before = _blas_threads()
    assert before, "numpy's wheel ships OpenBLAS: it should be found"
    with blas_threads(1) as n:
        assert n == len(before)
        assert _blas_threads() == [1] * len(before)
        m = np.random.default_rng(0).standard_normal((32, 32))
        vals = np.linalg.eigvalsh(m + m.T)
        assert np.all(np.diff(vals) >= 0)
    assert _blas_threads() == before
