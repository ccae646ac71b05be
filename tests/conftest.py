"""Shared fixtures and the test environment: private caches, float64 on demand.

The suite is hermetic: no test reads a path outside the repository (bundled data, tests/data, or
files the tests generate). JAX's persistent compilation cache is off for the tests and for the CLIs they
start (``HOMOFAC_JAX_CACHE=0``): with it on, two CI runs of the slow suite crashed with a segfault inside
JAX's cache read (``backend.deserialize_executable``, jax 0.10.2 on CPU) while the two xdist workers and
their CLI subprocesses shared one cache directory. Every entry of that cache deserialized cleanly in a
process of its own, so the crash is not one bad entry; a suite that can crash in a dependency's
optimisation is worse than one that compiles. ``HOMOFAC_TEST_JAX_CACHE=<dir>`` turns it back on for a
local run.

Each compiled XLA program keeps about three memory mappings of its code for as long as JAX caches it,
and Linux allows a process 65530 (``vm.max_map_count``): an xdist worker that compiles some twenty
thousand programs (the slow suite does) crashes in its next compile, with a segfault inside
``backend_compile_and_load`` when the mapping fails. So after any test that leaves the worker above
half that, JAX's caches are cleared (:func:`homofac.fit.programs.bound_compiled_programs`, which the
fitting entry points also call).

Most of the suite's CPU is XLA compiling small programs that then run for milliseconds, so the tests (and
the CLIs they start, through the environment) compile with XLA's cheaper settings: the CPU backend's classic
emitters instead of its MLIR fusion emitters (``--xla_cpu_use_fusion_emitters=false``, every test), each
program's LLVM module compiled whole instead of split for parallel codegen (``--xla_cpu_parallel_codegen_split_count=1``,
every test: the two workers already fill the two cores, so the split's parts only add work), and
most optimizations off (``jax_disable_most_optimizations``: LLVM at -O0, no expensive passes) for the fast
tests but those marked ``xla_optimized`` (their programs run long enough that -O0 costs more than it saves)
and the slow ones (the true default config and the other long runs); the fixtures that make bakes turn the
optimizations back on around the bake (``helpers.optimized_xla``: a bake's prefilter programs run long).
Measured in docs/notes/suite.md; the programs compute the same values to float32 rounding. ``HOMOFAC_TEST_XLA_OPT=1`` keeps XLA's defaults.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import jax
import pytest
from jax import monitoring
from _pytest.pathlib import import_path
from xdist.scheduler import LoadFileScheduling

import homofac as hf
from helpers import BAKE_SIZES, FOREST_BAKES, optimized_xla
from homofac.fit.programs import bound_compiled_programs

# Samples cached by the tests go to a private directory, never to the user's ~/.cache.
os.environ.setdefault("HOMOFAC_CACHE_DIR", tempfile.mkdtemp(prefix="homofac-test-cache-"))
# No persistent compilation cache, in this process or in the CLIs the tests start (see the docstring),
# unless HOMOFAC_TEST_JAX_CACHE names a directory for it.
_JAX_CACHE = os.environ.get("HOMOFAC_TEST_JAX_CACHE")
os.environ["HOMOFAC_JAX_CACHE"] = _JAX_CACHE or "0"
os.environ.pop("JAX_COMPILATION_CACHE_DIR", None)
if _JAX_CACHE:
    Path(_JAX_CACHE).mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", _JAX_CACHE)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
# Cheap compiles (see the docstring). XLA reads XLA_FLAGS when the backend starts, after this file.
_CHEAP = os.environ.get("HOMOFAC_TEST_XLA_OPT", "0") != "1"
if _CHEAP:
    os.environ["XLA_FLAGS"] = (f"{os.environ.get('XLA_FLAGS', '')} --xla_cpu_use_fusion_emitters=false"
                               " --xla_cpu_parallel_codegen_split_count=1").strip()


#: The test files that read the session's bakes (:func:`forest_bakes`, :func:`uniform_bake`): xdist runs them as one work unit, on one worker.
SHARED_BAKE_FILES = ("test_bake.py", "test_bake_harmonic.py", "test_bake_layout.py", "test_bake_mixed.py",
                     "test_bake_shared.py", "test_bake_sources.py")


#: Measured CPU seconds of each test file (in the worker plus the subprocesses it waits for) under a ``-m``
#: selection, from which the scheduler hands out the costliest work unit first: ``{"not slow": {"tests/test_x.py":
#: seconds, ...}}``, written by ``python tests/cpu_times.py DIR --costs`` from a run of that selection.
UNIT_COSTS_FILE = Path(__file__).with_name("unit_costs.json")


def unit_costs(markexpr: str, path: Path = UNIT_COSTS_FILE) -> dict[str, float]:
    """The test files' measured CPU seconds under the selection ``-m markexpr``, by node id (empty: not measured)."""
    return json.loads(path.read_text()).get(markexpr, {}) if path.exists() else {}


class _LoadFileSharingBakes(LoadFileScheduling):
    """``--dist loadfile``, but the files of :data:`SHARED_BAKE_FILES` are one work unit (each file its own else),
    and, when the run's ``-m`` selection was measured (:data:`UNIT_COSTS_FILE`), a worker that asks for work gets
    the costliest unit left (a file not measured counts as the median file): longest processing time first, so
    the units left at the end are short and both workers finish at about the same time. An unmeasured selection
    keeps xdist's order (most tests first)."""

    def __init__(self, config, log=None):
        super().__init__(config, log)
        self.costs = unit_costs(config.getoption("markexpr") or "")
        known = sorted(self.costs.values())
        self.unknown_cost = known[len(known) // 2] if known else 0.0

    def _split_scope(self, nodeid: str) -> str:
        path = super()._split_scope(nodeid)
        return "shared bakes" if Path(path).name in SHARED_BAKE_FILES else path

    def unit_cost(self, scope: str) -> float:
        """The measured CPU seconds of the work unit ``scope`` (a file's node id, or ``shared bakes``: its files')."""
        if scope == "shared bakes":
            return sum(c for f, c in self.costs.items() if Path(f).name in SHARED_BAKE_FILES)
        return self.costs.get(scope, self.unknown_cost)

    def _assign_work_unit(self, node) -> None:
        """Send ``node`` the costliest unit left (xdist's own sends the first in its queue)."""
        if self.costs:
            self.workqueue.move_to_end(max(self.workqueue, key=self.unit_cost), last=False)
        super()._assign_work_unit(node)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadfile`` keeps the files that share the session's bakes on one worker, so each bake is made
    once a run; other modes are xdist's own."""
    return _LoadFileSharingBakes(config, log) if config.getvalue("dist") == "loadfile" else None


def collected_files(config) -> list[Path]:
    """The test files the run's path arguments name (a directory: its ``test_*.py``, at any depth), in path order."""
    paths = [Path(config.invocation_params.dir, a.split("::")[0]) for a in config.args]
    return sorted({f.resolve() for p in paths for f in (p.rglob("test_*.py") if p.is_dir() else [p])})


def pytest_collection(session):
    """Every xdist worker imports every test module (its collection), and in a fresh clone (no ``.pyc`` yet) each
    compiles them and what they import (assertion rewriting included) from source: about 8 CPU s a worker that the
    other worker also pays (docs/notes/suite.md). So the odd-numbered workers import the test modules last to first
    before their collection: the two workers compile from opposite ends and read the other's ``.pyc`` past the
    middle. Same modules, same import function as the collection's (which then finds them imported); a module that
    fails here is left to the collection to report."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if not worker.startswith("gw") or int(worker[2:]) % 2 == 0:
        return
    config = session.config
    for path in reversed(collected_files(config)):
        try:
            import_path(path, mode=config.getoption("importmode"), root=config.rootpath,
                        consider_namespace_packages=config.getini("consider_namespace_packages"))
        except (Exception, pytest.skip.Exception):
            pass


def pytest_configure(config):
    config.addinivalue_line("markers", "xla_optimized: compile with XLA's optimizations on (tests/conftest.py)")


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """Before a test's fixtures: its programs (and those of the CLIs it starts) compile with most XLA
    optimizations off, unless it is slow or marked ``xla_optimized`` (see the module docstring)."""
    cheap = _CHEAP and item.get_closest_marker("slow") is None and item.get_closest_marker("xla_optimized") is None
    jax.config.update("jax_disable_most_optimizations", cheap)
    os.environ["JAX_DISABLE_MOST_OPTIMIZATIONS"] = "1" if cheap else "0"


def _float64():
    jax.config.update("jax_enable_x64", True)
    try:
        yield
    finally:
        jax.config.update("jax_enable_x64", False)


@pytest.fixture
def x64():
    """Enable float64 for one test (references and exactness tests need it), then restore float32."""
    yield from _float64()


@pytest.fixture(scope="module")
def x64_module():
    """float64 for a whole module's fits and gradients (module-scoped fixtures built in it), restored afterwards."""
    yield from _float64()


#: XLA backend compiles of this process since the last check of its mappings (JAX's compile event).
_COMPILES_SINCE_CHECK = [0]


def _count_compile(event: str, seconds: float, **_) -> None:
    if event == "/jax/core/compile/backend_compile_duration":
        _COMPILES_SINCE_CHECK[0] += 1


monitoring.register_event_duration_secs_listener(_count_compile)


@pytest.fixture(autouse=True)
def _bounded_mappings():
    """Keep the worker's memory mappings below the kernel's limit (see the module docstring), checked after the
    tests that compiled a program: the programs are what holds the mappings, and reading ``/proc/self/maps``
    (some 10 000 lines) after each of the three quarters of the tests that compile nothing cost ~5 ms each."""
    yield
    if _COMPILES_SINCE_CHECK[0]:
        _COMPILES_SINCE_CHECK[0] = 0
        bound_compiled_programs()


@pytest.fixture(scope="session")
def forest_bakes():
    """``forest_bakes(layout)``: the forest bake of ``helpers.FOREST_BAKES[layout]`` at ``helpers.BAKE_SIZES``,
    made on first use and kept for the session (the files that read them share a worker:
    :func:`pytest_xdist_make_scheduler`)."""
    made = {}

    def get(layout: str):
        if layout not in made:
            with optimized_xla():  # its prefilter runs long: helpers.optimized_xla
                made[layout] = hf.bake("forest", **FOREST_BAKES[layout], **BAKE_SIZES)
        return made[layout]

    return get


@pytest.fixture(scope="session")
def uniform_bake():
    """``fast`` under constant radiance 1 (light resolution 8), three layers at ``helpers.BAKE_SIZES``: the white
    furnace of test_bake and the map without a source of test_bake_sources."""
    with optimized_xla():
        return hf.bake(hf.light.uniform(1.0, 8), preset="fast", layers=3, **BAKE_SIZES)
