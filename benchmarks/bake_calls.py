"""Where a bake's CPU goes, by compiled program: each call of the bake's jitted filters and kernels timed (CPU
and wall, blocking on its result), grouped by program (argument shapes and static values), over a cold bake
(every program compiles: the persistent cache off) and then the same bake again in the same process (warm:
compiled); cold - warm is about the compilation (docs/notes/bake.md, "Bake time, nineteenth session").

    HOMOFAC_JAX_CACHE=0 PYTHONPATH=src python benchmarks/bake_calls.py city best

Prints each run's bake CPU and wall, the stages' CPU (``info.timings``) and the programs by CPU seconds. The
seconds move with the machine's load (say it beside them); compare CPU.
"""
from __future__ import annotations

import collections
import os
import sys
import time

os.environ.setdefault("HOMOFAC_JAX_CACHE", "0")

import jax  # noqa: E402

import homofac as hf  # noqa: E402
from homofac.bake import filter as fl  # noqa: E402
from homofac.bake import kernels as kn  # noqa: E402

#: The programs timed: (module, name) of the jitted functions the bake calls through its module's globals.
PROGRAMS = ((fl, "_filter"), (fl, "_filter_tiles"), (kn, "_lobes"), (kn, "_diffuse"))


def timed(calls: list, mod, name: str) -> None:
    """Replace ``mod.name`` by a wrapper appending (name, argument shapes, CPU s, wall s) to ``calls``."""
    fn = getattr(mod, name)

    def wrapper(*args, **kwargs):
        cpu, wall = time.process_time(), time.perf_counter()
        out = jax.block_until_ready(fn(*args, **kwargs))
        shapes = tuple(getattr(a, "shape", a) for a in args)
        calls.append((name, str(shapes), time.process_time() - cpu, time.perf_counter() - wall))
        return out

    setattr(mod, name, wrapper)


def report(calls: list) -> list[str]:
    """The calls grouped by program, by CPU seconds."""
    groups = collections.defaultdict(lambda: [0, 0.0, 0.0])
    for name, shapes, cpu, wall in calls:
        g = groups[(name, shapes)]
        g[0], g[1], g[2] = g[0] + 1, g[1] + cpu, g[2] + wall
    return [f"{name:14s} calls {n:3d} CPU {cpu:6.2f} s wall {wall:6.2f} s {shapes[:150]}"
            for (name, shapes), (n, cpu, wall) in sorted(groups.items(), key=lambda t: -t[1][1])]


def main(env: str, preset: str) -> None:
    calls: list = []
    for mod, name in PROGRAMS:
        timed(calls, mod, name)
    for run in ("cold", "warm"):
        calls.clear()
        load, cpu, wall = os.getloadavg()[0], time.process_time(), time.perf_counter()
        b = hf.bake(env, preset=preset)
        print(f"== {run}: bake CPU {time.process_time() - cpu:.1f} s, wall {time.perf_counter() - wall:.1f} s, load {load:.1f}")
        print("   stages CPU s: " + ", ".join(f"{k[:-6]} {v:.2f}" for k, v in b.info["timings"].items() if k.endswith("_cpu_s")))
        print("\n".join(report(calls)))


if __name__ == "__main__":
    main(*(sys.argv[1:3] if len(sys.argv) > 2 else ("city", "best")))
