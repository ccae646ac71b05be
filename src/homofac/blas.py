"""The threads of numpy's and scipy's BLAS / LAPACK (OpenBLAS, as their wheels ship it).

OpenBLAS splits every call over all cores. The bake's numpy linear algebra is many small problems (J x J
eigenproblems and J x G products with J <= 64, G = 1024: :func:`homofac.bake.build.compress`,
:func:`homofac.bake.build.layer_fit`), on which the extra thread only waits: measured on this project's 2-core
machine at load 13, a 64 x 64 ``eigh`` took 28 ms CPU against 0.4 ms on one thread, ``compress`` 0.2-0.9 s
against 0.02 s, and a whole studio / balanced bake 31.2 -> 22.0 s CPU (docs/notes/bake.md, "Bake time,
twenty-second session"). XLA's own thread pool is not OpenBLAS's and is not touched.

:func:`blas_threads` sets the thread count of every OpenBLAS the process has loaded (found by its path in
``/proc/self/maps``, or in numpy's and scipy's wheel folders), restoring it on exit; a BLAS it cannot find (MKL,
Accelerate) is left as it is.
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import os
from collections.abc import Iterator

import numpy

#: (set, get) symbol pairs of OpenBLAS builds: scipy-openblas (numpy and scipy wheels, 64- and 32-bit
#: integers) and a plain OpenBLAS.
_SYMBOLS = (("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
            ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
            ("openblas_set_num_threads64_", "openblas_get_num_threads64_"),
            ("openblas_set_num_threads", "openblas_get_num_threads"))


def _paths() -> list[str]:
    """The OpenBLAS libraries loaded in this process (Linux: ``/proc/self/maps``), else those of the numpy and
    scipy wheels' library folders."""
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as f:
            found = {line.split(None, 5)[-1].strip() for line in f if "openblas" in line.lower()}
        return sorted(p for p in found if os.path.isfile(p))
    except OSError:
        site = os.path.dirname(os.path.dirname(numpy.__file__))
        return sorted(p for d in ("numpy.libs", "numpy/.dylibs", "scipy.libs", "scipy/.dylibs")
                      for p in glob.glob(os.path.join(site, d, "*openblas*")))


def _controls() -> list[tuple[ctypes._CFuncPtr, ctypes._CFuncPtr]]:
    """(set, get) thread-count functions of each loaded OpenBLAS."""
    out = []
    for path in _paths():
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for set_name, get_name in _SYMBOLS:
            if hasattr(lib, set_name) and hasattr(lib, get_name):
                setter, getter = getattr(lib, set_name), getattr(lib, get_name)
                setter.argtypes, setter.restype, getter.argtypes, getter.restype = [ctypes.c_int], None, [], ctypes.c_int
                out.append((setter, getter))
                break
    return out


@contextlib.contextmanager
def blas_threads(count: int = 1) -> Iterator[int]:
    """Run the block with OpenBLAS on ``count`` threads (every OpenBLAS loaded when it starts); the previous
    counts are restored after it. Yields how many libraries it set (0: none found, nothing changed)."""
    controls = _controls()
    before = [get() for _, get in controls]
    for setter, _ in controls:
        setter(int(count))
    try:
        yield len(controls)
    finally:
        for (setter, _), n in zip(controls, before):
            setter(int(n))


__all__ = ["blas_threads"]
