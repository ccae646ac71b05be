"""Count the XLA programs a tiny preset fit compiles, and their compile seconds, by program and by the
homofac line that caused each (docs/notes/speed.md, "Compilation").

    HOMOFAC_JAX_CACHE=0 PYTHONPATH=src python benchmarks/compiles.py fast [--top 30] [--full]

Gold / forest at light resolution 8, texture size 8, 20 000 grid pairs; a fresh process, no persistent
compilation cache (``HOMOFAC_JAX_CACHE=0``); the seconds move with the machine's load, the counts do not.
``--full``: the preset's own gold / forest case (lights 32, texture size 32, its pair counts).
"""
from __future__ import annotations

import argparse
import collections
import logging
import os
import re
import time
import traceback

os.environ.setdefault("HOMOFAC_JAX_CACHE", "0")

import jax  # noqa: E402

import homofac as hf  # noqa: E402

FINISHED = re.compile(r"Finished XLA compilation of jit\((\S+)\) in ([0-9.e+-]+) sec")


class Compiles(logging.Handler):
    """Counts ``jax_log_compiles``' records: per program name and per the innermost homofac frame."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.by_name = collections.defaultdict(lambda: [0, 0.0])
        self.by_line = collections.defaultdict(lambda: [0, 0.0])
        self.by_stage = collections.defaultdict(lambda: [0, 0.0])

    def emit(self, record):
        m = FINISHED.search(record.getMessage())
        if not m:
            return
        frames = [f for f in traceback.extract_stack() if "/homofac/" in f.filename]
        line = f"{frames[-1].filename.split('/homofac/')[1]}:{frames[-1].lineno} {frames[-1].name}" if frames else "?"
        # the fit's stage: the innermost frame of the pipeline, the candidates' fits or the polish
        stage = [f for f in frames if any(k in f.filename for k in ("fit/pipeline.py", "fit/sums.py", "fit/polish.py"))]
        stage = f"{stage[-1].filename.split('/homofac/')[1]}:{stage[-1].lineno} {stage[-1].name}" if stage else "?"
        for table, key in ((self.by_name, m.group(1)), (self.by_line, line), (self.by_stage, stage)):
            table[key][0] += 1
            table[key][1] += float(m.group(2))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("preset", nargs="?", default="fast")
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--full", action="store_true",
                    help="the preset's own gold / forest case (lights at 32, texture size 32, the preset's pairs)")
    args = ap.parse_args()
    brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    target = hf.light.lighting_target(brdf, hf.light.load_environment("forest", 32 if args.full else 8))
    counter = Compiles()
    log = logging.getLogger("jax")
    log.addHandler(counter)
    log.setLevel(logging.WARNING)
    log.propagate = False
    jax.config.update("jax_log_compiles", True)
    t0, c0 = time.perf_counter(), time.process_time()
    small = {} if args.full else {"texture_size": 8, "sampling": {"count": 20000}}
    fac = hf.fit.factorize(target, preset=args.preset, **small)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = sum(v[0] for v in counter.by_name.values())
    s = sum(v[1] for v in counter.by_name.values())
    print(f"{args.preset}: {n} programs, {s:.1f} s compiling; fit {wall:.1f} s wall, {cpu:.1f} s CPU, load "
          f"{os.getloadavg()[0]:.1f}; {fac.metrics['validation']['float']['nrmse']:.5f} "
          f"validation nrmse")
    for title, table in (("by program", counter.by_name), ("by homofac line", counter.by_line),
                         ("by the fit's stage (pipeline / sums / polish line)", counter.by_stage)):
        print(f"\n{title}:")
        for key, (c, sec) in sorted(table.items(), key=lambda kv: -kv[1][1])[:args.top]:
            print(f"{c:5d} {sec:7.2f} s  {key}")


if __name__ == "__main__":
    main()
