"""Where a preset fit's XLA compilation goes: every program's backend compile, summed (gold / forest).

    HOMOFAC_JAX_CACHE=0 PYTHONPATH=src python benchmarks/compile_profile.py fast   # docs/notes/speed.md

Wraps JAX's ``backend_compile_and_load`` to read the process CPU and wall seconds of each program's XLA
compile (the fit runs nothing else meanwhile: its compiles are on the calling thread), and listens to
``jax.monitoring``'s tracing and lowering durations (wall only). Prints the fit's log (wall, CPU s), the
number of programs, their summed compile CPU, the 25 costliest, and the tracing / lowering totals. The
sample cache is off (``sampling.cache: false``); run with the compilation cache off (``HOMOFAC_JAX_CACHE=0``).
"""
import collections
import sys
import time

from jax._src import compiler, monitoring

#: (module name, CPU s, wall s) of every backend compile, in order.
COMPILES: list[tuple[str, float, float]] = []
_backend_compile = compiler.backend_compile_and_load


def _timed_compile(backend, module, *args, **kwargs):
    name = str(module.operation.attributes["sym_name"])
    c0, t0 = time.process_time(), time.perf_counter()
    try:
        return _backend_compile(backend, module, *args, **kwargs)
    finally:
        COMPILES.append((name, time.process_time() - c0, time.perf_counter() - t0))


compiler.backend_compile_and_load = _timed_compile
EVENTS: dict[str, float] = collections.defaultdict(float)
COUNTS: collections.Counter = collections.Counter()


def _listen(event: str, duration: float, **kwargs) -> None:
    EVENTS[event] += duration
    COUNTS[event] += 1


monitoring.register_event_duration_secs_listener(_listen)

import homofac as hf  # noqa: E402


def main() -> None:
    preset = sys.argv[1] if len(sys.argv) > 1 else "fast"
    t0, c0 = time.perf_counter(), time.process_time()

    def log(m):
        print(f"{time.perf_counter() - t0:7.2f} {time.process_time() - c0:7.2f} {m}", flush=True)

    brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    target = hf.light.lighting_target(brdf, hf.light.load_environment("forest", 32))
    fac = hf.fit.factorize(target, preset=preset, log=log, sampling={"cache": False})
    log(f"done: {fac.parametrization}, validation nrmse {fac.metrics['validation']['float']['nrmse']:.8f}")
    print(f"backend compiles: {len(COMPILES)} programs, {sum(r[1] for r in COMPILES):.2f} s CPU, "
          f"{sum(r[2] for r in COMPILES):.2f} s wall")
    for name, c, w in sorted(COMPILES, key=lambda r: -r[1])[:25]:
        print(f"  {c:6.2f} CPU {w:6.2f} wall  {name}")
    for e in sorted(EVENTS):
        print(f"{e}: {COUNTS[e]} events, {EVENTS[e]:.2f} s wall")


if __name__ == "__main__":
    main()
