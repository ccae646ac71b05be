"""homofac.blas: the OpenBLAS thread count is set inside the block and restored after it."""

import numpy as np

from homofac.blas import _controls, blas_threads


def test_blas_threads_sets_and_restores_every_loaded_openblas():
    np.linalg.eigh(np.eye(4))  # numpy's LAPACK loaded
    controls = _controls()
    assert controls, "numpy's wheel ships OpenBLAS: it should be found"
    before = [get() for _, get in controls]
    with blas_threads(1) as n:
        assert n == len(controls)
        assert all(get() == 1 for _, get in controls)
        m = np.random.default_rng(0).standard_normal((32, 32))
        vals = np.linalg.eigvalsh(m + m.T)
        assert np.all(np.diff(vals) >= 0)
    assert [get() for _, get in controls] == before
