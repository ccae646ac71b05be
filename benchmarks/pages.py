"""The benchmark pages of the documentation site and the README's preset table, from the committed JSON.

    python benchmarks/pages.py        # regenerate them all (no fit, no measurement)

- ``docs/benchmarks/accuracy.md`` from ``benchmarks/accuracy.json`` (``python benchmarks/accuracy.py``);
- ``docs/benchmarks/speed.md``, ``refit.md``, ``scene.md`` from ``benchmarks/results.json`` (``make benchmark``,
  ``benchmarks/report.py``);
- ``docs/benchmarks/bake.md`` from ``benchmarks/bake_accuracy.json`` (``python benchmarks/bake_accuracy.py``), the
  three.js runs and the per-material fit runs (``benchmarks/bake_accuracy_fits*.json``);
- ``docs/benchmarks/presets.md`` and the README's "Choose a preset" table (between ``<!-- presets:start -->``
  and ``<!-- presets:end -->``): per preset its lookups, fit time and error against split-sum.

The preset table reads ``benchmarks/presets.json`` when it exists (the preset benchmark: a list of rows, each
with ``preset`` (or ``method: "preset NAME"``) and ``fit_s``, and, when measured against the accuracy
benchmark's ground truth, ``material``, ``environment`` and ``nrmse``). What that file does not hold comes
from the accuracy benchmark's rows of the presets' lookup budgets, ``max_lookups 4``, ``8`` and ``16``, and
the table says which file each column comes from. Errors are nrmse ratios to split-sum's on the same case
(range over the cases); fit times the range over the rows, measured on this 2-core machine.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

import accuracy  # noqa: E402 - the accuracy page (benchmarks/ is not a package)
import bake_accuracy  # noqa: E402 - the bake page
import report  # noqa: E402 - the speed, refit and scene pages

DOCS = ROOT / "docs" / "benchmarks"
README = ROOT / "README.md"
START, END = "<!-- presets:start -->", "<!-- presets:end -->"

#: The presets and their lookup budgets (pinned: ``preset: fast | balanced | best``).
PRESETS = {"fast": 4, "balanced": 8, "best": 16}


def load_rows(path: Path) -> list[dict]:
    """The rows of a benchmark JSON (a list of rows, or ``{"rows": [...]}``); none when the file is missing."""
    if not path.is_file():
        return []
    doc = json.loads(path.read_text())
    return list(doc["rows"] if isinstance(doc, dict) else doc)


def preset_of(row: dict) -> str | None:
    """The preset a row measured: its ``preset`` key, or a ``method`` named ``preset NAME``."""
    if row.get("preset") in PRESETS:
        return row["preset"]
    method = str(row.get("method", ""))
    if method in PRESETS:
        return method
    name = method.removeprefix("preset ").strip()
    return name if method.startswith("preset ") and name in PRESETS else None


def seconds(lo: float, hi: float) -> str:
    """A range of fit seconds, in minutes when the shortest is above two minutes."""
    if lo >= 120:
        a, b = round(lo / 60), round(hi / 60)
        return f"{a} min" if a == b else f"{a}-{b} min"
    a, b = f"{lo:.0f}", f"{hi:.0f}"
    return f"{a} s" if a == b else f"{a}-{b} s"


def _ratios(rows: list[dict], split: dict) -> list[float]:
    return [r["nrmse"] / split[(r["material"], r["environment"])] for r in rows
            if "nrmse" in r and (r.get("material"), r.get("environment")) in split]


def preset_summary(accuracy_rows: list[dict], preset_rows: list[dict]) -> list[dict]:
    """Per preset: lookups, fit seconds (min, max) and their source, error ratios to split-sum and their
    source, and the per-case rows they came from."""
    split = {(r["material"], r["environment"]): r["nrmse"] for r in accuracy_rows if r["method"] == "split_sum"}
    split.update({(r["material"], r["environment"]): r["nrmse"] for r in preset_rows
                  if r.get("method") == "split_sum" and "material" in r})
    out = []
    for name, lookups in PRESETS.items():
        measured = [r for r in preset_rows if preset_of(r) == name and not r.get("warm")]  # first runs only
        budget = [r for r in accuracy_rows if r["method"] == f"max_lookups {lookups}"]
        # a preset row's time: fit_s, or wall_s of a run on a quiet machine (run != "loaded")
        timed = [{**r, "fit_s": r.get("fit_s", r.get("wall_s"))} for r in measured
                 if ("fit_s" in r or "wall_s" in r) and r.get("run") != "loaded"]
        time_rows, time_src = (timed, "presets.json") if timed else (budget, "accuracy.json")
        ratios = _ratios(measured, split)
        wider = len(_ratios(budget, split)) > len(ratios)  # the accuracy benchmark covers more cases
        err_rows, err_src = (budget, "accuracy.json") if wider or not ratios else (measured, "presets.json")
        ratios = _ratios(err_rows, split)
        out.append({"preset": name, "lookups": lookups,
                    "fit_s": (min(r["fit_s"] for r in time_rows), max(r["fit_s"] for r in time_rows))
                    if time_rows else None, "time_source": time_src,
                    "ratio": (min(ratios), max(ratios)) if ratios else None, "cases": len(ratios),
                    "error_source": err_src, "rows": err_rows})
    return out


def preset_table(accuracy_rows: list[dict], preset_rows: list[dict]) -> str:
    """The README's "Choose a preset" table and the note that says where its figures come from."""
    summary = preset_summary(accuracy_rows, preset_rows)
    split = [r for r in accuracy_rows if r["method"] == "split_sum"]
    lines = ["| preset | lookups per pixel | fit time here | nrmse / split-sum's (range over cases) |",
             "|---|---:|---:|---:|"]
    for s in summary:
        t = seconds(*s["fit_s"]) if s["fit_s"] else "not measured"
        e = "not measured"
        if s["ratio"]:
            lo, hi = (f"{x:.2f}" for x in s["ratio"])
            e = f"{lo}x" if lo == hi else f"{lo}-{hi}x"
            e += f" ({s['cases']} case{'s' if s['cases'] > 1 else ''})"
        lines.append(f"| `{s['preset']}` | {s['lookups']} | {t} | {e} |")
    if split:
        lines.append(f"| split-sum (Karis 2013, for reference) | 3 | "
                     f"{seconds(min(r['fit_s'] for r in split), max(r['fit_s'] for r in split))} | 1x |")
    time_src = {s["time_source"] for s in summary}
    err_src = {s["error_source"] for s in summary}
    notes = []
    if time_src == {"presets.json"}:
        notes.append("Fit times: the preset benchmark (`benchmarks/presets.json`).")
    else:
        loaded = [r for r in preset_rows if r.get("run") == "loaded" and "wall_s" in r]
        notes.append("Fit times: the accuracy benchmark's runs of the lookup budgets 4, 8 and 16 "
                     "(`max_lookups`, before the presets' speed-up"
                     + (", for the presets `benchmarks/presets.json` does not hold" if "presets.json" in time_src
                        else "; the preset benchmark of this code ran on a loaded machine only: "
                        + ", ".join(f"`{r['method']}`" + (" with a warm compilation cache (another material's fit "
                                                           "before)" if r.get("warm") else "")
                                    + f" {r['wall_s']:.0f} s wall, {r['cpu_s']:.0f} s CPU at load "
                                    f"{r['load'][0]:.0f}" for r in loaded if "cpu_s" in r)
                        + " in `benchmarks/presets.json`" if loaded
                        else "; `benchmarks/presets.json` is not there yet") + ").")
    if err_src == {"presets.json"}:
        notes.append("Errors: the preset benchmark against the accuracy benchmark's ground truth.")
    else:
        notes.append("Errors: the accuracy benchmark's `max_lookups` 4, 8 and 16 rows (nrmse on 20000 pairs "
                     "against a converged ground truth; `best` ran on four cases).")
    return "\n".join(lines) + "\n\n" + " ".join(notes) + " Generated by `python benchmarks/pages.py`."


def preset_page(accuracy_rows: list[dict], preset_rows: list[dict]) -> str:
    """docs/benchmarks/presets.md: the summary table, then per case the nrmse of each preset and its ratio."""
    summary = preset_summary(accuracy_rows, preset_rows)
    split = {(r["material"], r["environment"]): r for r in accuracy_rows if r["method"] == "split_sum"}
    cases = list(split)
    head = "| case | split-sum | " + " | ".join(f"`{s['preset']}` ({s['lookups']})" for s in summary) + " |"
    lines = [head, "|---|---:|" + "---:|" * len(summary)]
    for c in cases:
        cells = []
        for s in summary:
            r = next((r for r in s["rows"] if (r.get("material"), r.get("environment")) == c and "nrmse" in r), None)
            cells.append(f"{r['nrmse']:.3f} ({r['nrmse'] / split[c]['nrmse']:.2f}x), {seconds(r['fit_s'], r['fit_s'])}"
                         if r else "")
        lines.append(f"| {c[0]} / {c[1]} | {split[c]['nrmse']:.3f} | " + " | ".join(cells) + " |")
    return f"""# Presets: fit time and error

<!-- Generated by benchmarks/pages.py from benchmarks/accuracy.json and benchmarks/presets.json: do not edit. -->

The README's table, then per case the nrmse (its ratio to split-sum's, fit time) of each preset's
lookup budget. The materials and environments are the [accuracy benchmark](accuracy.md)'s.

{preset_table(accuracy_rows, preset_rows)}

{chr(10).join(lines)}
"""


def replace_block(text: str, block: str) -> str:
    """``text`` with the part between :data:`START` and :data:`END` replaced by ``block``."""
    if START not in text or END not in text:
        raise SystemExit(f"README.md: no {START} ... {END} markers")
    head, rest = text.split(START, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{START}\n{block}\n{END}{tail}"


#: Roughness bands of the three.js page (benchmarks/threejs.py).
BANDS = ((0.045, 0.15), (0.15, 0.3), (0.3, 0.6), (0.6, 1.01))


def _reference_words(doc: dict) -> str:
    """How a three.js run's exact lighting was computed (old runs: the light sum at a resolution)."""
    if "exact_resolution" in doc:
        return (f"the light sum at resolution {doc['exact_resolution']} (not converged below roughness 0.15: lobes "
                "narrower than a light texel)")
    samples = ", ".join(f"{r['environment']} {r['reference']['samples']}" for r in doc["rows"])
    return ("the converged reference (`homofac.light.reference`: the glTF BRDF integrated against the source map "
            f"read bilinearly, which is the equirect three.js is given; MIS, float64, samples per strategy doubled "
            f"until the image moved by < {doc['tolerance']:g} nrmse: {samples})")


def threejs_rows(doc: dict) -> list[str]:
    """The table of a three.js run: per environment, homofac / PMREM nrmse overall and per roughness band,
    fetches per pixel and texture memory."""
    lines = ["| environment | all pixels | " + " | ".join(f"rho {lo}-{min(hi, 1.0):g}" for lo, hi in BANDS)
             + " | fetches per pixel | texture MB |",
             "|---|---:|" + "---:|" * len(BANDS) + "---:|---:|"]
    for r in doc["rows"]:
        bands = {tuple(b["roughness"]): b for b in r["bands"]}
        cells = []
        for lo, hi in BANDS:
            b = bands.get((lo, min(hi, 1.0)))
            cells.append(f"{b['homofac']:.3f} / {b['pmrem']:.3f}" if b else "-")
        tb = r["texture_bytes"]
        mine = f"{tb['homofac'] / 1e6:.2f}" + (f" ({tb['homofac_rgba'] / 1e6:.2f} RGBA)" if "homofac_rgba" in tb else "")
        lines.append(f"| {r['environment']} | {r['nrmse']['homofac']:.3f} / {r['nrmse']['pmrem']:.3f} | "
                     + " | ".join(cells)
                     + f" | {r['lookups']['homofac']} / {r['lookups']['pmrem']} | {mine} / {tb['pmrem'] / 1e6:.2f} |")
    if doc["rows"] and "pmrem_cube" in doc["rows"][0]:
        c = doc["rows"][0]["pmrem_cube"]
        lines += ["", f"Fetches count a `textureLod` as one (as `bake.lookups` does): PMREM (three r187) reads its cube "
                  f"twice (radiance at the roughness' mip, irradiance at the roughest) and its 16 x 16 DFG table once. "
                  f"Texture memory: the bake's textures in half floats, RGB (in parentheses RGBA, as its KTX2 files "
                  f"load in three.js), against PMREM's cube render target ({c['size']}^2 x 6, {c['levels']} mip levels, "
                  "RGBA half floats) and DFG table."]
    return lines


def _other_runs(others: list[dict]) -> list[str]:
    """The tables of further three.js runs (other bake presets: benchmarks/threejs_<preset>.json)."""
    lines: list[str] = []
    for o in others:
        m = o["machine"]
        reused = [r["environment"] for r in o["rows"] if r["reference"].get("reused")]
        lines += ["", f"With a `{o.get('preset')}` bake (`{o['command']}`; run {m['date_utc']} UTC, {m['wall_s'] / 60:.1f} min "
                  f"wall, load average {m['load_average_before']:.1f}"
                  + (f"; the exact lighting of {', '.join(reused)} read from an earlier run's saved pixels, the G-buffer "
                     "the same bit for bit" if reused else "") + "):", "", *threejs_rows(o)[:2 + len(o["rows"])]]
    return lines


def threejs_runs() -> tuple[dict, list[dict]]:
    """benchmarks/threejs.json and the other presets' runs beside it (benchmarks/threejs_<preset>.json)."""
    main = json.loads((HERE / "threejs.json").read_text())
    return main, [json.loads(f.read_text()) for f in sorted(HERE.glob("threejs_*.json"))]


def threejs_page(doc: dict, others: list[dict] = ()) -> str:
    """docs/benchmarks/threejs.md from benchmarks/threejs.json (and ``others``, runs with other bake presets):
    three.js PMREM beside homofac in three.js."""
    size, preset = doc["size"], doc.get("preset", "balanced")
    lines = ["# three.js PMREM and homofac in three.js", "",
             f"Generated by `python benchmarks/threejs.py` (`benchmarks/threejs.json`): the bundled material sphere "
             f"rendered at {size}x{size} by three.js' MeshStandardMaterial in headless Chromium, once with three's "
             f"PMREM of the environment and once with homofac's drop-in reading a `{preset}` bake; nrmse at the "
             f"covered pixels against {_reference_words(doc)}. three's PMREM adds multiple scattering, which the "
             "single-scattering glTF BRDF does not have. Each cell: homofac / PMREM.", "", *threejs_rows(doc),
             *_other_runs(list(others))]
    if "machine" in doc:
        m = doc["machine"]
        lines += ["", f"Run {m['date_utc']} UTC, {m['wall_s'] / 60:.1f} min wall, load average {m['load_average_before']:.1f} "
                  f"before and {m['load_average_after']:.1f} after ({m['cpus']} cores): `{doc['command']}`."]
    return "\n".join(lines) + "\n"


def threejs_section(doc: dict, others: list[dict] = ()) -> str:
    """The "three.js PMREM" rows of docs/benchmarks/bake.md: the split-sum engines really ship, measured in
    three.js itself beside homofac's drop-in (benchmarks/threejs.json)."""
    return "\n".join([
        "## three.js PMREM", "",
        f"The split-sum that engines ship, run in the real three.js (r187, headless Chromium): the bundled material "
        f"sphere at {doc['size']}x{doc['size']}, three's MeshStandardMaterial with its PMREM beside the same material "
        f"with homofac's drop-in (`js/homofac-three.js`) reading a `{doc.get('preset', 'balanced')}` bake; nrmse of "
        f"the rendered pixels against {_reference_words(doc)}. Each cell: homofac / three.js PMREM. Generated by "
        "`python benchmarks/threejs.py` (details: [three.js](threejs.md)).", "", *threejs_rows(doc),
        *_other_runs(list(others))]) + "\n"


def fit_runs() -> list[dict]:
    """The per-material fit runs beside the bake: benchmarks/bake_accuracy_fits*.json (``bake_accuracy.py --fits N
    --out benchmarks/bake_accuracy_fitsNN``)."""
    return [json.loads(f.read_text()) for f in sorted(HERE.glob("bake_accuracy_fits*.json"))]


def fits_section(runs: list[dict]) -> str:
    """The "Per-material fits" rows of docs/benchmarks/bake.md: a homofac fit of one material at the bake's fetches,
    beside the bake and the ideal split-sum on the same pairs with that material (:func:`fit_runs`)."""
    lines = ["## Per-material fits at the same fetches", "",
             "A homofac fit of one material's lighting (`hf.fit.factorize`, the small settings below), beside the "
             "bake, which serves every material, and the ideal split-sum, each scored on the cell's first pairs "
             "(up to 512, weighted as above) shaded with that one material; *fit time*: wall seconds on the shared "
             "machine at the run's load. Generated by `python benchmarks/bake_accuracy.py --fits N --fit-envs ... "
             "--fit-lookups L`."]
    for run in runs:
        m = run["machine"]
        lines += ["", *bake_accuracy.fits_markdown(run), "",
                  f"Run {m['date_utc']} UTC, {m['wall_s'] / 60:.1f} min wall, load average "
                  f"{m['load_average_before'][0]:.1f} before and {m['load_average_after'][0]:.1f} after "
                  f"({m['cpus']} cores): `{run['command']}`."]
    return "\n".join(lines) + "\n"


def bake_page(doc: dict, threejs: dict | None = None, threejs_others: list[dict] = (), fits: list[dict] = ()) -> str:
    """docs/benchmarks/bake.md from benchmarks/bake_accuracy.json: the bake beside split-sum and glTF-IBL-Sampler,
    with ``threejs`` (benchmarks/threejs.json) the "three.js PMREM" rows (:func:`threejs_section`) and with
    ``fits`` (:func:`fit_runs`) the per-material fits' rows (:func:`fits_section`)."""
    return "\n".join([
        "# The bake against a converged reference, beside split-sum and glTF-IBL-Sampler", "",
        "Generated by `python benchmarks/bake_accuracy.py` (`benchmarks/bake_accuracy.json`). Each cell "
        "(environment x roughness band) is the nrmse of the outgoing radiance over pairs (n, v) placed as on the "
        "pixels of a rendered object (n.v with density 2 n.v) and random glTF materials (base colour uniform, "
        "metallic 0, 1 or uniform by thirds), their reflected directions importance-sampled by the environment's "
        "luminance and weighted by 1 / probability (`benchmarks/bake_pairs.py`), doubled until one more doubling "
        "moves every column by < 5 % (*pairs*: the final count and that move; *cap*: not converged at 8192), "
        "against the glTF BRDF integrated against the source map (`homofac.light.reference`: importance "
        "sampling, float64, samples doubled until the batch moves by < 1 %; *check*: the largest change of one "
        "of the cell's heaviest pairs at 4x the samples). *goal*: <= 0.5x the ideal split-sum from roughness "
        "0.15 up, <= 0.8x below, and below the sampler. "
        "*split-sum ideal*: the environment prefiltered by the specular lobe at n = v = r at the pair's own "
        "roughness and the exact DFG terms; *split-sum engines*: an emulated mip chain (level = roughness x "
        "(levels - 1)) and 32 x 32 tables; *sampler*: the Khronos glTF-IBL-Sampler's default bake (GGX cube "
        "256, 8 mips, half floats; its LUT; Lambertian cube 64) read as the glTF Sample Viewer does (with its "
        "multiple-scattering term; *sampler split-sum*: without it). Fetches per pixel and texture memory "
        "(half floats) are in the last table; each bake runs in a fresh process with JAX's compilation cache off "
        "(every program compiles), its wall and CPU time beside the sampler's in the same run on a shared 2-core "
        "machine (load average at the bake's start); *split-sum same sharpness*: the smallest engines' chain that "
        "reads, at every layer's roughness, a face at least as fine as the bake's (docs/notes/bake.md).", "",
        bake_accuracy.markdown(doc)] + ([threejs_section(threejs, threejs_others)] if threejs else [])
        + ([fits_section(list(fits))] if fits else []))


def main() -> int:
    acc = load_rows(HERE / "accuracy.json")
    presets = load_rows(HERE / "presets.json")
    DOCS.mkdir(parents=True, exist_ok=True)
    written = [accuracy.write_page(acc, DOCS)]
    (DOCS / "presets.md").write_text(preset_page(acc, presets))
    written.append(DOCS / "presets.md")
    (DOCS / "threejs.md").write_text(threejs_page(*threejs_runs()))
    written.append(DOCS / "threejs.md")
    bake = HERE / "bake_accuracy.json"
    if bake.is_file() and isinstance(json.loads(bake.read_text()), dict):
        (DOCS / "bake.md").write_text(bake_page(json.loads(bake.read_text()), *threejs_runs(), fits=fit_runs()))
        written.append(DOCS / "bake.md")
    README.write_text(replace_block(README.read_text(), preset_table(acc, presets)))
    report.main([str(HERE / "results.json"), "--docs", str(DOCS)])
    for p in written + [README]:
        print(f"wrote {p.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
