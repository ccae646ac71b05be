"""The threads of numpy's and scipy's BLAS / LAPACK during homofac's small dense problems.

OpenBLAS (as numpy's and scipy's wheels ship it) splits every call over all cores. The bake's numpy linear
algebra is many small problems (J x J eigenproblems and J x G products with J <= 64, G = 1024:
:func:`homofac.bake.build.compress`, :func:`homofac.bake.build.layer_fit`), on which the extra thread only
waits: measured on this project's 2-core machine at load 13, a 64 x 64 ``eigh`` took 28 ms CPU against 0.4 ms on
one thread and a whole studio / balanced bake 31.2 -> 22.0 s CPU (docs/notes/bake.md, "Bake time,
twenty-second session"). XLA's own thread pool is not the BLAS's and is not touched.

:func:`blas_threads` is threadpoolctl's ``threadpool_limits`` on the BLAS libraries the process has loaded
(OpenBLAS, MKL, BLIS, Accelerate: whichever threadpoolctl finds), restoring their counts on exit.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from threadpoolctl import threadpool_info, threadpool_limits


@contextlib.contextmanager
def blas_threads(count: int = 1) -> Iterator[int]:
    """Run the block with every loaded BLAS on ``count`` threads; the previous counts are restored after it.
    Yields how many BLAS libraries it limited (0: none loaded, nothing changed)."""
    with threadpool_limits(limits=int(count), user_api="blas"):
        yield sum(1 for info in threadpool_info() if info["user_api"] == "blas")


__all__ = ["blas_threads"]
