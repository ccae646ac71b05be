"""Per-test CPU time, for measuring the suite on a shared machine (docs/notes/suite.md).

Wall-clock durations (``--durations``) grow with the machine's load; a process's CPU time (all its
threads: XLA compiles and runs on several) does much less. As a pytest plugin it appends one line per
test phase, ``nodeid, phase, cpu s, wall s``, to ``$HOMOFAC_CPU_TIMES/<xdist worker>.tsv``::

    PYTHONPATH=src:tests HOMOFAC_CPU_TIMES=/tmp/cpu python -m pytest -p cpu_times -n 2 --dist loadfile -m "not slow"
    python tests/cpu_times.py /tmp/cpu        # totals per worker and per file, the slowest phases

CPU time of subprocesses (the CLI tests, the GL server, Chromium) is not counted.
"""

from __future__ import annotations

import collections
import glob
import os
import sys
import time

import pytest

_OUT = os.environ.get("HOMOFAC_CPU_TIMES", "")


def _timed(phase: str):
    @pytest.hookimpl(hookwrapper=True)
    def hook(item):
        cpu, wall = time.process_time(), time.perf_counter()
        yield
        if _OUT:
            os.makedirs(_OUT, exist_ok=True)
            worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
            with open(os.path.join(_OUT, f"{worker}.tsv"), "a") as f:
                f.write(f"{item.nodeid}\t{phase}\t{time.process_time() - cpu:.3f}\t{time.perf_counter() - wall:.3f}\n")
    return hook


pytest_runtest_setup = _timed("setup")
pytest_runtest_call = _timed("call")
pytest_runtest_teardown = _timed("teardown")


def report(directory: str, files: int = 40, phases: int = 40) -> None:
    """Print the totals of a directory of these records: per worker, per file, the slowest phases."""
    rows = []
    for path in glob.glob(os.path.join(directory, "*.tsv")):
        for line in open(path):
            nodeid, phase, cpu, wall = line.rstrip("\n").split("\t")
            rows.append((nodeid, phase, float(cpu), float(wall), os.path.basename(path)[:-4]))
    print(f"{len({r[0] for r in rows})} tests: {sum(r[2] for r in rows):.0f} s CPU, {sum(r[3] for r in rows):.0f} s wall summed")
    cpu, wall = collections.Counter(), collections.Counter()
    for r in rows:
        cpu[r[4]] += r[2]
        wall[r[4]] += r[3]
    print("per worker (CPU s / wall s):", ", ".join(f"{w} {cpu[w]:.0f} / {wall[w]:.0f}" for w in sorted(cpu)))
    cpu, wall = collections.Counter(), collections.Counter()
    for r in rows:
        cpu[r[0].split("::")[0]] += r[2]
        wall[r[0].split("::")[0]] += r[3]
    print("\nCPU s   wall s  file")
    for name, c in cpu.most_common(files):
        print(f"{c:6.1f} {wall[name]:7.1f}  {name}")
    print("\nCPU s   wall s  phase")
    for r in sorted(rows, key=lambda r: -r[2])[:phases]:
        print(f"{r[2]:6.1f} {r[3]:7.1f}  {r[1]:8s} {r[0]}")


if __name__ == "__main__":
    report(sys.argv[1], *(int(a) for a in sys.argv[2:]))
