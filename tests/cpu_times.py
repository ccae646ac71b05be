"""Per-test CPU time, for measuring the suite on a shared machine (docs/notes/suite.md).

Wall-clock durations (``--durations``) grow with the machine's load; a process's CPU time (all its
threads: XLA compiles and runs on several) does much less. As a pytest plugin it appends one line per
test phase, ``nodeid, phase, cpu s, wall s, XLA compiles, compile s, children's cpu s``, to ``$HOMOFAC_CPU_TIMES/<xdist worker>.tsv``::

    PYTHONPATH=src:tests HOMOFAC_CPU_TIMES=/tmp/cpu python -m pytest -p cpu_times -n 2 --dist loadfile -m "not slow"
    python tests/cpu_times.py /tmp/cpu        # totals per worker and per file, the slowest phases
    python tests/cpu_times.py /tmp/cpu --costs "not slow" tests/unit_costs.json   # the scheduler's costs (conftest.py)

CPU time of subprocesses is a column of its own, for those the test waited for (a CLI run, a compiler); the GL
device process and Chromium, reaped when the worker ends, are in no test's.
"""

from __future__ import annotations

import collections
import glob
import json
import os
import sys
import time

import pytest
from jax import monitoring

_OUT = os.environ.get("HOMOFAC_CPU_TIMES", "")
#: XLA backend compiles of this process so far: their number and their seconds (JAX's compile event).
_COMPILES = [0, 0.0]


def _count_compile(event: str, seconds: float, **_) -> None:
    if event == "/jax/core/compile/backend_compile_duration":
        _COMPILES[0] += 1
        _COMPILES[1] += seconds


if _OUT:
    monitoring.register_event_duration_secs_listener(_count_compile)


def _children() -> float:
    """CPU seconds of this process's reaped subprocesses (a CLI run; not the GL device process, reaped at exit)."""
    t = os.times()
    return t.children_user + t.children_system


def _timed(phase: str):
    @pytest.hookimpl(hookwrapper=True)
    def hook(item):
        cpu, wall, (compiles, compile_s), children = time.process_time(), time.perf_counter(), _COMPILES, _children()
        yield
        if _OUT:
            os.makedirs(_OUT, exist_ok=True)
            worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
            with open(os.path.join(_OUT, f"{worker}.tsv"), "a") as f:
                f.write(f"{item.nodeid}\t{phase}\t{time.process_time() - cpu:.3f}\t{time.perf_counter() - wall:.3f}"
                        f"\t{_COMPILES[0] - compiles}\t{_COMPILES[1] - compile_s:.3f}\t{_children() - children:.3f}\n")
    return hook


pytest_runtest_setup = _timed("setup")
pytest_runtest_call = _timed("call")
pytest_runtest_teardown = _timed("teardown")


def report(directory: str, files: int = 40, phases: int = 40) -> None:
    """Print the totals of a directory of these records: per worker, per file (with its XLA compiles and their
    seconds, when recorded), the slowest phases."""
    rows = []
    for path in glob.glob(os.path.join(directory, "*.tsv")):
        for line in open(path):
            nodeid, phase, cpu, wall, *more = line.rstrip("\n").split("\t")
            n, secs, sub = int(more[0]) if more else 0, float(more[1]) if more else 0.0, float(more[2]) if more[2:] else 0.0
            rows.append((nodeid, phase, float(cpu), float(wall), os.path.basename(path)[:-4], n, secs, sub))
    print(f"{len({r[0] for r in rows})} tests: {sum(r[2] for r in rows):.0f} s CPU, {sum(r[3] for r in rows):.0f} s wall summed, "
          f"{sum(r[5] for r in rows)} XLA compiles ({sum(r[6] for r in rows):.0f} s), subprocesses {sum(r[7] for r in rows):.0f} s CPU")
    cpu, wall = collections.Counter(), collections.Counter()
    for r in rows:
        cpu[r[4]] += r[2]
        wall[r[4]] += r[3]
    print("per worker (CPU s / wall s):", ", ".join(f"{w} {cpu[w]:.0f} / {wall[w]:.0f}" for w in sorted(cpu)))
    cpu, wall, count, secs, sub = (collections.Counter() for _ in range(5))
    for r in rows:
        name = r[0].split("::")[0]
        cpu[name] += r[2]
        wall[name] += r[3]
        count[name] += r[5]
        secs[name] += r[6]
        sub[name] += r[7]
    print("\nCPU s   wall s  compiles (s)   subproc s  file")
    for name, c in cpu.most_common(files):
        print(f"{c:6.1f} {wall[name]:7.1f}  {count[name]:5d} {secs[name]:6.1f}  {sub[name]:7.1f}  {name}")
    print("\nCPU s   wall s  compiles  subproc s  phase")
    for r in sorted(rows, key=lambda r: -r[2] - r[7])[:phases]:
        print(f"{r[2]:6.1f} {r[3]:7.1f}  {r[5]:5d}  {r[7]:7.1f}  {r[1]:8s} {r[0]}")


def costs(directory: str) -> dict[str, float]:
    """CPU seconds per test file of a directory of these records: in the worker plus the subprocesses waited for
    (what tests/unit_costs.json holds for the scheduler in tests/conftest.py)."""
    out: collections.Counter = collections.Counter()
    for path in glob.glob(os.path.join(directory, "*.tsv")):
        for line in open(path):
            nodeid, _phase, cpu, _wall, *more = line.rstrip("\n").split("\t")
            out[nodeid.split("::")[0]] += float(cpu) + (float(more[2]) if more[2:] else 0.0)
    return {name: round(c, 1) for name, c in sorted(out.items(), key=lambda kv: -kv[1])}


if __name__ == "__main__":
    if sys.argv[2:3] == ["--costs"]:  # DIR --costs MARKEXPR FILE: the run's costs into FILE's entry for MARKEXPR
        markexpr, target = sys.argv[3], sys.argv[4]
        table = json.load(open(target)) if os.path.exists(target) else {}
        table[markexpr] = costs(sys.argv[1])
        with open(target, "w") as f:
            f.write(json.dumps(table, indent=1) + "\n")
    else:
        report(sys.argv[1], *(int(a) for a in sys.argv[2:]))
