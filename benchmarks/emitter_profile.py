"""Every compiled program's compile CPU and run CPU on one of XLA CPU's emitters (gold / forest or a bake).

    HOMOFAC_JAX_CACHE=0 PYTHONPATH=src python benchmarks/emitter_profile.py fast fusion --json F   # docs/notes/speed.md
    HOMOFAC_JAX_CACHE=0 PYTHONPATH=src python benchmarks/emitter_profile.py fast loop --json F
    HOMOFAC_JAX_CACHE=0 PYTHONPATH=src python benchmarks/emitter_profile.py bake fusion --json F
    HOMOFAC_JAX_CACHE=0 PYTHONPATH=src python benchmarks/emitter_profile.py fast rule --json F

The workload: ``fast`` / ``balanced`` / ``best`` (a preset's fit of gold / forest, the sample cache off) or ``bake``
(``python -m homofac.bake forest --preset balanced`` into a temporary directory). The emitters: ``fusion`` compiles
every program with ``xla_cpu_use_fusion_emitters: true`` (XLA's default), ``loop`` every program with ``false``
(whatever options the library gave it), ``rule`` leaves the library's own options. Per program (its module name):
the compiles, their CPU s (the process CPU around ``backend_compile_and_load``), the calls and their run CPU s
(each call waited for: JAX's C++ dispatch is turned off so that every call goes through ``ExecuteReplicated``,
timed with its outputs ready; the Python's dispatch overhead is in it). The blocking removes the overlap of Python
with XLA, so the run's total is not a preset row's; each program's figures are what compare across emitters.
"""
import argparse
import collections
import json
import sys
import tempfile
import time
import traceback

import jax
from jax._src import compiler, pjit
from jax._src.interpreters import pxla

MODE = {"fusion": True, "loop": False, "rule": None}
STATE = {"emitters": None}
#: module name -> [compiles, compile CPU s, calls, run CPU s]
PROGRAMS: dict[str, list] = collections.defaultdict(lambda: [0, 0.0, 0, 0.0])
#: module name -> Counter of the innermost homofac source lines that made each compile
ORIGINS: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
_backend_compile = compiler.backend_compile_and_load
_call = pxla.ExecuteReplicated.__call__


def _compile(backend, module, executable_devices, options, host_callbacks):
    name = str(module.operation.attributes["sym_name"]).strip('"')
    if STATE["emitters"] is not None:
        kept = [(k, v) for k, v in options.env_option_overrides if k != "xla_cpu_use_fusion_emitters"]
        options.env_option_overrides = kept + [("xla_cpu_use_fusion_emitters", STATE["emitters"])]
    ours = [f for f in traceback.extract_stack() if "/homofac/" in f.filename]
    ORIGINS[name][f"{ours[-1].filename.split('/homofac/')[-1]}:{ours[-1].lineno}" if ours else "?"] += 1
    c0 = time.process_time()
    try:
        return _backend_compile(backend, module, executable_devices, options, host_callbacks)
    finally:
        row = PROGRAMS[name]
        row[0] += 1
        row[1] += time.process_time() - c0


def _timed_call(self, *args):
    c0 = time.process_time()
    out = _call(self, *args)
    jax.block_until_ready(out)
    name = self.name
    row = PROGRAMS["jit_" + name[4:-1] if name.startswith("jit(") else name]  # the module's name
    row[2] += 1
    row[3] += time.process_time() - c0
    return out


compiler.backend_compile_and_load = _compile
pxla.ExecuteReplicated.__call__ = _timed_call
pjit._get_fastpath_data = lambda *args, **kwargs: None

import homofac as hf  # noqa: E402


def workload(name: str) -> str:
    """Run the workload; a one-line summary."""
    if name == "bake":
        from homofac.app import bake_cli  # noqa: PLC0415 - the bake's entry point, only for this workload

        with tempfile.TemporaryDirectory() as out:
            rc = bake_cli.main(["forest", "--preset", "balanced", "--out", out + "/bake"])
        return f"bake rc {rc}"
    brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    target = hf.light.lighting_target(brdf, hf.light.load_environment("forest", 32))
    fac = hf.fit.factorize(target, preset=name, sampling={"cache": False})
    return f"{fac.parametrization}, validation nrmse {fac.metrics['validation']['float']['nrmse']:.8f}"


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("workload", choices=["fast", "balanced", "best", "bake"])
    p.add_argument("emitters", choices=sorted(MODE))
    p.add_argument("--json")
    args = p.parse_args()
    STATE["emitters"] = MODE[args.emitters]
    t0, c0 = time.perf_counter(), time.process_time()
    summary = workload(args.workload)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    rows = sorted(PROGRAMS.items(), key=lambda r: -(r[1][1] + r[1][3]))
    compile_cpu, run_cpu = sum(r[1] for _, r in rows), sum(r[3] for _, r in rows)
    print(f"{args.workload} / {args.emitters}: {summary}; {wall:.1f} s wall, {cpu:.1f} s CPU; {len(rows)} programs, "
          f"compile {compile_cpu:.2f} s CPU, run {run_cpu:.2f} s CPU")
    for name, (nc, cc, nr, rc) in rows[:40]:
        print(f"  {cc:6.2f} compile ({nc}) {rc:7.2f} run ({nr:5d})  {name}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"workload": args.workload, "emitters": args.emitters, "summary": summary, "wall": wall, "cpu": cpu,
                       "programs": {k: dict(zip(("compiles", "compile_cpu", "calls", "run_cpu"), v))
                                    for k, v in rows},
                       "origins": {k: dict(v) for k, v in ORIGINS.items()}}, f, indent=1)


if __name__ == "__main__":
    sys.exit(main())
