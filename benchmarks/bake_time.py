"""Bake time beside glTF-IBL-Sampler's default bake, in the same run (issue 42), without the accuracy part.

Per environment: the sampler's default bake (GGX cube 256 x 256 x 6 with its mips, 1024 samples, and the
Lambertian cube 64; :func:`homofac.baselines.ibl_sampler.bake`, its own processes, lavapipe on this CPU), then one
bake per preset, each ``python -m homofac.bake ENV --preset P`` in a fresh process with JAX's persistent compilation
cache off (``HOMOFAC_JAX_CACHE=0``: every program compiles, as on a new user's first run; wall time includes
Python's start, the imports and writing the directory; :func:`bake_accuracy.fresh_bake`). Each row: wall and
CPU seconds, the load average when it started, the ratio to the sampler's default bake of the same environment
(wall and CPU), and the bake's own stages (wall and CPU, ``bake.json`` ``info.timings``). The goals: every bake
within 2x the sampler's wall time, and below 60 s wall.

    PYTHONPATH=src python benchmarks/bake_time.py [--envs forest city interior studio]
        [--presets fast balanced best] [--no-sampler] [--out benchmarks/bake_time]

writes OUT.json and OUT.md after every environment. About 1-1.5 min per bake at load 1-2 (sampler 35-40 s wall),
so the default run takes about 4-6 min per environment on a quiet 2-core machine. On a loaded machine compare the
CPU columns: wall time moves with the others' load.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import homofac as hf  # noqa: E402
from bake_accuracy import fresh_bake  # noqa: E402
from homofac.baselines import ibl_sampler as ibl  # noqa: E402

#: Issue 42's goals: at most this ratio to the sampler's default bake (wall, side by side) ...
RATIO_GOAL = 2.0
#: ... and at most this many seconds of wall time.
WALL_GOAL = 60.0

STAGES = ("load", "diffuse", "kernels", "maps", "harmonic", "weights", "sh9")


def sampler_row(name: str) -> dict:
    """The sampler's default bake of ``name``: wall (its two runs and reading them back), CPU of its processes."""
    load = os.getloadavg()[0]
    t = time.perf_counter()
    sb = ibl.bake(name)
    wall = time.perf_counter() - t
    return {"environment": name, "method": "sampler", "wall_s": wall,
            "cpu_s": sb.runs["ggx"]["cpu_s"] + sb.runs["lambertian"]["cpu_s"],
            "ggx_wall_s": sb.runs["ggx"]["wall_s"], "lambertian_wall_s": sb.runs["lambertian"]["wall_s"],
            "load_average": load}


def bake_row(name: str, preset: str, tmp: str, sampler: dict | None) -> dict:
    """One fresh-process bake of ``name`` at ``preset`` with its ratios to ``sampler``'s row."""
    load = os.getloadavg()[0]
    b, wall, cpu = fresh_bake(name, preset, tmp)
    row = {"environment": name, "method": preset, "wall_s": wall, "cpu_s": cpu, "load_average": load,
           "lookups": b.lookups, "bytes": int(b.texture_bytes()), "timings": b.info.get("timings", {})}
    if sampler is not None:
        row["wall_ratio"] = wall / sampler["wall_s"]
        row["cpu_ratio"] = cpu / sampler["cpu_s"]
    row["met"] = wall <= WALL_GOAL and row.get("wall_ratio", 0.0) <= RATIO_GOAL
    return row


def markdown(doc: dict) -> str:
    """The rows as tables: time and ratios, then the bakes' stages (CPU)."""
    rows = doc["rows"]
    lines = [f"# Bake time beside glTF-IBL-Sampler's default bake ({doc['machine']['date_utc']} UTC)", "",
             f"`{doc['command']}`: {doc['machine']['wall_s']:.0f} s wall, load average {doc['machine']['load_average_before']:.1f}"
             f" before, {doc['machine']['load_average_after']:.1f} after, {doc['machine']['cpus']} CPUs. Every bake is a fresh"
             " process with JAX's persistent compilation cache off. Goals (issue 42): wall <= "
             f"{RATIO_GOAL:g}x the sampler's in the same run, and <= {WALL_GOAL:g} s.", "",
             "| environment | method | wall s | CPU s | load | wall / sampler | CPU / sampler | goal |",
             "|---|---|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        ratio = (f"{r['wall_ratio']:.2f}", f"{r['cpu_ratio']:.2f}") if "wall_ratio" in r else ("", "")
        goal = "" if r["method"] == "sampler" else ("met" if r["met"] else "missed")
        lines.append(f"| {r['environment']} | {r['method']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | {r['load_average']:.1f} | "
                     f"{ratio[0]} | {ratio[1]} | {goal} |")
    bakes = [r for r in rows if r["method"] != "sampler"]
    if bakes:
        lines += ["", "The bakes' stages, CPU s (wall s) from `bake.json` (`info.timings`; the process's CPU above also "
                  "counts Python's start, the imports and writing the directory):", "",
                  "| environment | preset | " + " | ".join(STAGES) + " | bake |", "|---|---|" + "---:|" * (len(STAGES) + 1)]
        for r in bakes:
            t = r["timings"]
            cells = [f"{t.get(f'{s}_cpu_s', 0.0):.1f} ({t.get(f'{s}_s', 0.0):.1f})" for s in STAGES + ("total",)]
            lines.append(f"| {r['environment']} | {r['method']} | " + " | ".join(cells) + " |")
        met = sum(r["met"] for r in bakes)
        lines += ["", f"**{met} of {len(bakes)} bakes meet both goals.**"]
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--envs", nargs="+", default=list(hf.light.BUNDLED))
    ap.add_argument("--presets", nargs="+", default=["fast", "balanced", "best"])
    ap.add_argument("--no-sampler", action="store_true", help="leave glTF-IBL-Sampler out")
    ap.add_argument("--out", default=str(HERE / "bake_time"), help="stem of the .json and .md written")
    args = ap.parse_args(argv)
    why = "--no-sampler" if args.no_sampler else ibl.available()
    start, load = time.time(), os.getloadavg()[0]
    rows: list[dict] = []
    doc: dict = {}
    with tempfile.TemporaryDirectory(prefix="bake_time-") as tmp:
        for name in args.envs:
            sampler = None
            if why is None:
                sampler = sampler_row(name)
                rows.append(sampler)
                print(f"{name} sampler: {sampler['wall_s']:.1f} s wall, {sampler['cpu_s']:.1f} s CPU", flush=True)
            for preset in args.presets:
                row = bake_row(name, preset, tmp, sampler)
                rows.append(row)
                print(f"{name} {preset}: {row['wall_s']:.1f} s wall, {row['cpu_s']:.1f} s CPU, load {row['load_average']:.1f}"
                      + (f", {row['wall_ratio']:.2f}x the sampler's wall, {row['cpu_ratio']:.2f}x its CPU" if sampler else ""),
                      flush=True)
            doc = {"rows": rows, "sampler": why or "measured", "presets": args.presets,
                   "goals": {"ratio_to_sampler_wall": RATIO_GOAL, "wall_s": WALL_GOAL},
                   "command": "PYTHONPATH=src python benchmarks/bake_time.py " + " ".join(argv if argv is not None else sys.argv[1:]),
                   "machine": {"date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime(start)), "wall_s": time.time() - start,
                               "load_average_before": load, "load_average_after": os.getloadavg()[0], "cpus": os.cpu_count(),
                               "platform": platform.platform(), "homofac": hf.__version__}}
            Path(args.out + ".json").write_text(json.dumps(doc, indent=1) + "\n")
            Path(args.out + ".md").write_text(markdown(doc))
    return doc


if __name__ == "__main__":
    main()
