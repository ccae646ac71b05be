"""The plan's validation-lighting decision on the four speed cases: the decided resolution, its changes per
doubling and its CPU seconds, each case in a fresh process (no compilation cache), so that the cost includes
the compiled lighting programs (docs/notes/speed.md, "fast, sixteenth session").

    PYTHONPATH=src python benchmarks/decision_cost.py [--cases metal/forest,...] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CASES = "metal/forest,plastic/city,mirror/studio,metal/interior"

ONE = """
import json, sys, time
c0 = time.process_time()
import homofac as hf
sys.path.insert(0, "benchmarks")
import accuracy as acc
from homofac.fit import validation
material, env = sys.argv[1].split("/")
target = hf.light.lighting_target(acc.MATERIALS[material](), hf.light.load_environment(env, 32))
c1 = time.process_time()
v = validation.decide(target, 20000, 1)
print(json.dumps({"case": sys.argv[1], "import_s": c1 - c0, "decide_cpu_s": time.process_time() - c1,
                  "resolution": v.resolution, "changes": v.changes, "converged": v.converged}))
"""


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", default=CASES)
    ap.add_argument("--json")
    a = ap.parse_args()
    rows = []
    for case in a.cases.split(","):
        out = subprocess.run([sys.executable, "-c", ONE, case], capture_output=True, text=True, check=True,
                             env={**os.environ, "HOMOFAC_JAX_CACHE": "0"})
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
        r = rows[-1]
        print(f"{case:16s} R {r['resolution']:4d} changes {[round(c, 4) for _, c in r['changes']]} "
              f"decide {r['decide_cpu_s']:.2f} s CPU", flush=True)
    with open("/proc/loadavg") as f:
        load = float(f.read().split()[0])
    print(f"load {load}")
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"load": load, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
