"""Two runs of benchmarks/emitter_profile.py side by side: per program, compile and run CPU on each emitter.

    python benchmarks/emitter_table.py FUSION.json LOOP.json [--min 0.05]   # docs/notes/speed.md

Prints a markdown table, costliest first: the program, its calls, compile CPU s and run CPU s under each run's
emitters, and the net of the second run against the first (compile + run). Programs under ``--min`` s in both
runs are summed into one row (the op-by-op dispatches, mostly).
"""
import argparse
import json


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("first")
    p.add_argument("second")
    p.add_argument("--min", type=float, default=0.05)
    args = p.parse_args()
    a, b = (json.load(open(f)) for f in (args.first, args.second))
    pa, pb = a["programs"], b["programs"]
    zero = {"compiles": 0, "compile_cpu": 0.0, "calls": 0, "run_cpu": 0.0}
    names = sorted(set(pa) | set(pb), key=lambda k: -max(pa.get(k, zero)["compile_cpu"] + pa.get(k, zero)["run_cpu"],
                                                         pb.get(k, zero)["compile_cpu"] + pb.get(k, zero)["run_cpu"]))
    print(f"{a['workload']}: {a['emitters']} ({a['summary']}; {a['cpu']:.1f} s CPU) against {b['emitters']} "
          f"({b['summary']}; {b['cpu']:.1f} s CPU)\n")
    print(f"| program | compiles / calls | compile {a['emitters']} / {b['emitters']} | run {a['emitters']} / "
          f"{b['emitters']} | net, {b['emitters']} - {a['emitters']} |")
    print("|---|---:|---:|---:|---:|")
    rest = [0.0, 0.0, 0.0, 0.0, 0, 0]
    totals = [0.0, 0.0, 0.0, 0.0]
    for k in names:
        x, y = pa.get(k, zero), pb.get(k, zero)
        vals = (x["compile_cpu"], y["compile_cpu"], x["run_cpu"], y["run_cpu"])
        totals = [t + v for t, v in zip(totals, vals)]
        if max(vals[0] + vals[2], vals[1] + vals[3]) < args.min:
            rest = [r + v for r, v in zip(rest, vals)] + [rest[4] + 1, rest[5]]
            rest = rest[:6]
            continue
        net = vals[1] + vals[3] - vals[0] - vals[2]
        print(f"| `{k}` | {max(x['compiles'], y['compiles'])} / {max(x['calls'], y['calls'])} | {vals[0]:.2f} / "
              f"{vals[1]:.2f} | {vals[2]:.2f} / {vals[3]:.2f} | {net:+.2f} |")
    if rest[4]:
        net = rest[1] + rest[3] - rest[0] - rest[2]
        print(f"| the other {rest[4]} | | {rest[0]:.2f} / {rest[1]:.2f} | {rest[2]:.2f} / {rest[3]:.2f} | {net:+.2f} |")
    net = totals[1] + totals[3] - totals[0] - totals[2]
    print(f"| **all** | | {totals[0]:.2f} / {totals[1]:.2f} | {totals[2]:.2f} / {totals[3]:.2f} | **{net:+.2f}** |")


if __name__ == "__main__":
    main()
