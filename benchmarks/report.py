"""Turn pytest-benchmark JSON into the markdown table and the Pareto plot of error against run time.

    python benchmarks/report.py [benchmarks/results.json] [--readme README.md]

Writes ``benchmarks/results.md`` and ``benchmarks/pareto.png`` beside the JSON; with ``--readme`` it
also replaces the part of README.md between ``<!-- bench:start -->`` and ``<!-- bench:end -->`` (and
the refit table of benchmarks/test_refit.py between ``<!-- refit:start -->`` and ``<!-- refit:end -->``,
and the scene-sampling table of benchmarks/test_scene.py between ``<!-- scene:start -->`` and
``<!-- scene:end -->``).
Times are warm (compile reported apart); run time = sampling + assembling + solving.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

START, END = "<!-- bench:start -->", "<!-- bench:end -->"
REFIT_START, REFIT_END = "<!-- refit:start -->", "<!-- refit:end -->"
SCENE_START, SCENE_END = "<!-- scene:start -->", "<!-- scene:end -->"


def records(path: Path) -> tuple[list[dict], list[dict], list[dict], dict]:
    """(scene cases, NumPy baselines, sums-of-products records, machine info) of a pytest-benchmark JSON."""
    doc = json.loads(path.read_text())
    cases, baselines, sums = [], [], []
    for b in doc["benchmarks"]:
        r = b.get("extra_info", {})
        if r.get("solver") == "numpy-baseline":
            baselines.append(r)
        elif r.get("kind") == "sums":
            sums.append(r)
        elif r.get("kind") in ("refit", "scene"):
            continue  # refit_records, scene_records
        elif "val_nrmse" in r:
            cases.append(r)
    return cases, baselines, sums, doc.get("machine_info", {})


def refit_records(path: Path) -> list[dict]:
    """The records of benchmarks/test_refit.py (``kind: refit``) in a pytest-benchmark JSON."""
    doc = json.loads(path.read_text())
    return [b["extra_info"] for b in doc["benchmarks"] if b.get("extra_info", {}).get("kind") == "refit"]


def refit_table(rows: list[dict]) -> str:
    """Refits and the material library (issue 15) against the full runs they replace."""
    if not rows:
        return ""
    lines = ["| case (gold / forest, default sizes) | change | first s | warm s | full run s warm (first) | "
             "ratio | target | val nrmse (full run) | metrics vs full run |",
             "|---|---|---:|---:|---:|---:|---|---:|---:|"]
    for r in rows:
        ratio = r.get("ratio", r["warm_s"] / r["full_s"] if r["full_s"] > 0 else float("nan"))
        lines.append(f"| {r['case']} | {r['what']} | {r['first_s']:.2f} | {r['warm_s']:.3f} | "
                     f"{r['full_s']:.2f} ({r['full_first_s']:.1f}) | {ratio:.3g}x | {r['target']}: "
                     f"{'met' if r['met'] else 'NOT met'} | {r['val_nrmse']:.4f} ({r['full_val_nrmse']:.4f}) | "
                     f"{r['max_rel_metric_diff']:.1e} |")
    return "\n".join(lines)


def scene_records(path: Path) -> list[dict]:
    """The records of benchmarks/test_scene.py (``kind: scene``) in a pytest-benchmark JSON."""
    doc = json.loads(path.read_text())
    return [b["extra_info"] for b in doc["benchmarks"] if b.get("extra_info", {}).get("kind") == "scene"]


def scene_table(rows: list[dict]) -> str:
    """The demo scene's image-space error per sampling (issue 15, part 3), and each sampling's error
    relative to scene sampling of the same case."""
    if not rows:
        return ""
    ref = {r["case"]: r for r in rows if r["sampling"] == "scene"}
    lines = ["| case | sampling | training pairs | scene nrmse | x scene sampling | scene nrmse 8-bit | "
             "scene avg rel | held-out views nrmse | x scene sampling | own validation nrmse | fit s |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        base = ref.get(r["case"])
        x = r["scene_nrmse"] / base["scene_nrmse"] if base else float("nan")
        hx = r["held_out_nrmse"] / base["held_out_nrmse"] if base else float("nan")
        lines.append(f"| {r['case']} | {r['sampling']} | {r['pairs']:,} | {r['scene_nrmse']:.4f} | {x:.2f} | "
                     f"{r['scene_nrmse_8bit']:.4f} | {r['scene_avg_rel']:.4f} | {r['held_out_nrmse']:.4f} | "
                     f"{hx:.2f} | {r['own_val_nrmse']:.4f} | {r['fit_s']:.1f} |")
    return "\n".join(lines)


def replace_block(text: str, start: str, end: str, block: str, name: str) -> str:
    """``text`` with the part between the markers ``start`` and ``end`` replaced by ``block``."""
    if start not in text or end not in text:
        raise SystemExit(f"{name}: no {start} ... {end} markers")
    head, rest = text.split(start, 1)
    _, tail = rest.split(end, 1)
    return head + f"{start}\n{block}\n{end}" + tail


def sums_table(rows: list[dict]) -> str:
    """Fit time and validation nrmse of the linear-space sums (issue 13)."""
    if not rows:
        return ""
    lines = ["| sum of products (gold / forest) | lookups | method | backend | samples | fit s warm (first) | val nrmse |",
             "|---|---:|---|---|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['lookups']} | {r['method']} ({r['iterations']}) | {r['backend']} | "
                     f"{r['samples']:,} | {r['fit_s']:.2f} ({r['fit_first_s']:.1f}) | {r['val_nrmse']:.4f} |")
    return "\n".join(lines)


def run_time(r: dict) -> float:
    return r["sample_s"] + r["assemble_s"] + r["solve_s"]


def table(cases: list[dict], baselines: list[dict]) -> str:
    lines = [
        "| scene | quality | solver | pairs | lights | sample s (compile) | solve s (compile) | iterations | val nrmse | gap to optimum | lsmr speedup |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    by = {(r["scene"], r["quality"], r["solver"]): r for r in cases}
    for r in cases:
        lsmr = by.get((r["scene"], r["quality"], "lsmr"))
        speed = f"{r['solve_s'] / lsmr['solve_s']:.1f}x" if lsmr and r["solver"] != "lsmr" and lsmr["solve_s"] > 0 else ""
        conv = "" if r["converged"] else " (cap)"
        lines.append(
            f"| {r['scene']} | {r['quality']} | {r['solver']} | {r['pairs']:,} | {r['lights']:,} | "
            f"{r['sample_s']:.2f} ({r['sample_compile_s']:.1f}) | {r['solve_s']:.2f} ({r['solve_compile_s']:.1f}) | "
            f"{r['iterations']}{conv} | {r['val_nrmse']:.4f} | {r['objective_gap']:.1e} | {speed} |"
        )
    out = "\n".join(lines)
    if baselines:
        out += "\n\n| NumPy baseline | pairs | NumPy s (extrapolated from a slice) | homofac s | speedup |\n|---|---:|---:|---:|---:|\n"
        out += "\n".join(
            f"| {b['scene']} {b['quality']} | {b['pairs']:,} | {b['numpy_s_extrapolated']:.1f} | "
            f"{b['homofac_train_sample_s']:.2f} | {b['numpy_s_extrapolated'] / b['homofac_train_sample_s']:.0f}x |"
            for b in baselines
        )
    return out


def pareto_front(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The points no other point beats in both run time and error, by increasing time."""
    front, best = [], float("inf")
    for t, e in sorted(points):
        if e < best:
            front.append((t, e))
            best = e
    return front


def plot(cases: list[dict], path: Path, machine: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = sorted({r["scene"] for r in cases})
    solvers = sorted({r["solver"] for r in cases})
    qualities = ["preview", "default", "high"]
    markers = dict(zip(qualities, "o^s"))
    colours = dict(zip(solvers, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    fig, axes = plt.subplots(1, len(scenes), figsize=(4.2 * len(scenes), 3.8), squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        rs = [r for r in cases if r["scene"] == scene]
        for r in rs:
            ax.scatter(run_time(r), r["val_nrmse"], color=colours[r["solver"]], marker=markers.get(r["quality"], "x"),
                       s=36, edgecolor="k" if r["converged"] else "none")
        f = pareto_front([(run_time(r), r["val_nrmse"]) for r in rs])
        ax.step([t for t, _ in f], [e for _, e in f], where="post", color="0.4", lw=1, ls="--")
        ax.set_xscale("log")
        ax.set_title(scene)
        ax.set_xlabel("sampling + solve, s (warm)")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("validation nrmse")
    handles = [plt.Line2D([], [], ls="", marker="o", color=colours[s], label=s) for s in solvers]
    handles += [plt.Line2D([], [], ls="", marker=markers[q], color="0.3", label=q) for q in qualities
                if any(r["quality"] == q for r in cases)]
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), frameon=False)
    fig.suptitle(f"homofac: error against run time ({machine})", fontsize=10)
    fig.tight_layout(rect=(0, 0.08, 1, 0.95))
    fig.savefig(path, dpi=110)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("json", nargs="?", default=str(Path(__file__).with_name("results.json")))
    p.add_argument("--readme", help="README.md to update between the bench markers")
    args = p.parse_args(argv)
    path = Path(args.json)
    cases, baselines, sums, _ = records(path)
    refits = refit_records(path)
    scenes = scene_records(path)
    if not cases and not sums and not refits and not scenes:
        raise SystemExit(f"{path}: no benchmark records")
    machine = (cases or sums or refits or scenes)[0].get("machine", "")
    md = ""
    if cases or sums:
        md = f"Machine: {machine}.\n\n" + (table(cases, baselines) + "\n" if cases else "")
        if sums:
            md += "\n" + sums_table(sums) + "\n"
        (path.parent / "results.md").write_text(md)
    if cases:
        plot(cases, path.parent / "pareto.png", machine)
    refit_md = f"Machine: {machine}.\n\n{refit_table(refits)}\n" if refits else ""
    scene_md = (f"Machine: {machine}; the demo scene's {scenes[0]['scene_pixels']:,} covered pixels (held-out "
                f"views: {scenes[0]['held_out_pixels']:,}).\n\n"
                f"{scene_table(scenes)}\n") if scenes else ""
    if args.readme:
        readme = Path(args.readme)
        text = readme.read_text()
        if md:
            text = replace_block(text, START, END, f"{md}\n![error against run time](benchmarks/pareto.png)", str(readme))
        if refit_md:
            text = replace_block(text, REFIT_START, REFIT_END, refit_md, str(readme))
        if scene_md:
            text = replace_block(text, SCENE_START, SCENE_END, scene_md, str(readme))
        readme.write_text(text)
    print(md + refit_md + scene_md)


if __name__ == "__main__":
    main()
