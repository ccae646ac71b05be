"""Accuracy against what engines ship: every method on every case, against a converged ground truth.

    python benchmarks/accuracy.py                      # all cases and methods -> benchmarks/accuracy.json
                                                       # and its page docs/benchmarks/accuracy.md
    python benchmarks/accuracy.py --cases metal/forest --methods split_sum,NR --json /tmp/a.json  # a subset
                                                       # (table in /tmp/a.md; the committed files untouched)
    python benchmarks/accuracy.py ... --fits DIR       # save each row's fit in DIR; rows found there are
                                                       # measured from the saved fit, not fitted again

Cases: the bundled environments (city, forest, interior, studio) x four materials (a metal, a
dielectric plastic, a rough dielectric, a near-mirror metal). Methods: the baselines (split-sum,
Kautz-McCool 2D and sliced), homofac's log-space products (NR, NRV, NRW) and its sums of products
(exact diffuse + K fitted terms, with and without the n.v factor); each fitted on the environment at
light resolution ``--fit-resolution`` (default 32; a method may name its own: ``max_lookups 16``, the quality
mode, fits at 64) with dual-paraboloid textures of size 32.

Ground truth: the brute-force lighting computation at the light resolution where one more doubling
changes it by less than 0.5 % (nrmse over the validation pairs; checked per case, starting at 64, up to
512; the straddling texels' BRDF evaluated at their visible centroids, see homofac.light.geometry),
cached in benchmarks/.cache. Metrics on 20000 random valid (n, v) pairs (seeded; n uniform, v uniform on
n's hemisphere; 141 normals): nrmse, avg_rel, nrmse in the n.v bins grazing (< 0.25), mid, frontal (> 0.5), the share of
the squared error held by the pairs with n.v < 0.02 and < 0.1 and by the worst 0.1 % of the pairs; and
the image-space nrmse of a rendered sphere (OpenGL, the exported shader) against the ground truth at
its pixels. Each row also records lookups per pixel, texels, the fit (or build) seconds, and the nrmse on
270000 dense pairs of 9000 normals (:func:`dense_pairs`), a steadier estimate under a sun.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import sys
import time
from pathlib import Path

import numpy as np

import homofac as hf
from homofac.errors import HomofacError
from homofac.fit import sampling
from homofac.fit.structures import Structure
from homofac.fit.samples import Samples, evaluate_grouped
from homofac.target import Target

HERE = Path(__file__).resolve().parent
CACHE = HERE / ".cache"
#: The generated pages of the documentation site (benchmarks/pages.py regenerates them all).
DOCS = HERE.parent / "docs" / "benchmarks"

MATERIALS = {
    "metal": lambda: hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34)),
    "plastic": lambda: hf.brdf.cook_torrance(kd=0.3, ks=1.0, roughness=0.6, f0=0.04),
    "rough": lambda: hf.brdf.ggx(kd=(0.4, 0.25, 0.15), ks=1.0, roughness=0.9, f0=0.04),
    "mirror": lambda: hf.brdf.ggx(kd=0.0, ks=1.0, roughness=0.1, f0=(0.95, 0.93, 0.88)),
}
ENVIRONMENTS = ("city", "forest", "interior", "studio")
BINS = {"grazing": (0.0, 0.25), "mid": (0.25, 0.5), "frontal": (0.5, 1.0001)}

#: Training pairs of the linear-space sums: the grid design (texel-centre (n, r) pairs of the textures).
GRID = {"kind": "grid", "count": 300_000}

def _fixed(name: str, linear: dict | None = None) -> dict:
    """The keywords of hf.fit.factorize for the structure a row's name labels (:meth:`Structure.parse`, then
    :meth:`Structure.keywords`; "E'+NRW+RW+R" is read as "E'+NRW x1+RW x1+R"), on the grid design."""
    label = re.sub(r"^((?:E'?\+)?(?:SS\+)?[A-Z]{2,}|(?:E'?\+)?(?:SS\+)?[NR])(?=\+|$)", r"\1 x1", name)
    label = re.sub(r"\+RW(?= |\+|$)(?! x)", "+RW x1", label)
    kw = Structure.parse(label).keywords()
    if linear:
        kw["advanced"] = {**kw["advanced"], "linear": linear}
    return {**kw, "sampling": GRID}


#: method name -> keywords of hf.fit.factorize (texture size and mapper are common)
METHODS = {
    "split_sum": {"parametrization": "split_sum"},
    "kautz_mccool": {"parametrization": "kautz_mccool"},
    "kautz_mccool_3d": {"parametrization": "kautz_mccool", "advanced": {"baseline": {"slices": 4}}},
    "NR": {"parametrization": "NR"},
    "NRW": {"parametrization": "NRW"},
    # the fixed structures: their labels parsed (Structure.parse), fitted on the grid design; a name
    # without " x1" is the label of one product (the rows' names predate the labels' " xK")
    **{name: _fixed(name) for name in ("E+NRW", "E'+NRW", "E'+NRW x2+R", "E'+NROW", "E'+ROW+R", "E'+NROW x2+R",
                                       "E'+ROW x3+R", "E'+RW+R", "E'+RW x3+R", "E'+NRW+RW+R", "E'+NRW+RW x2",
                                       "E'+SS+NRW+R", "E+NRW x5")},
    **{f"E'+NRW x2+R {tag}": _fixed("E'+NRW x2+R", linear) for tag, linear in
       (("bal1", {"nv_balance": 1.0}), ("pol8", {"polish": 8}), ("bal1 pol8", {"nv_balance": 1.0, "polish": 8}))},
    "E'+NRW bal1 pol8": _fixed("E'+NRW", {"nv_balance": 1.0, "polish": 8}),
    "max_lookups 4": {"parametrization": "NR", "max_lookups": 4, "sampling": GRID},
    "max_lookups 8": {"parametrization": "NR", "max_lookups": 8, "sampling": GRID},
    # the quality mode: the lighting fitted at resolution 64 (docs/notes/sums-research.md, "The lighting the fit
    # sees"), the grid's count and the plain objective of the chooser's quality-mode rule (homofac.fit.pipeline.grid_count)
    "max_lookups 16": {"parametrization": "NR", "max_lookups": 16, "sampling": {"kind": "grid"}, "fit_resolution": 64},
}


#: The columns of the docs page (benchmarks/accuracy.md has every method of the run): the baselines, one
#: product, the 4-, 8- and 16-lookup budgets of the presets and the fixed structures the notes name.
PAGE_METHODS = ("split_sum", "kautz_mccool", "kautz_mccool_3d", "NR", "E'+NRW", "max_lookups 4", "E'+NRW x2+R",
                  "E'+NRW x2+R pol8", "max_lookups 8", "E+NRW x5", "max_lookups 16")


def validation_pairs(count: int = 20000, seed: int = 12345):
    return sampling.grouped_random(count, seed)


#: The dense pair set: 9000 normals with 30 views each (the table's 20000 pairs have 141 normals). Under a sun
#: a few pairs whose reflection grazes the normal's horizon next to the sun hold most of the squared error, so
#: the nrmse of 141 normals is a noisy estimate (docs/notes/sums-research.md, "The grazing ridge of the sun"); this set
#: has 64 times as many normals, and its three disjoint thirds (3000 normals each) show the spread.
DENSE_NORMALS, DENSE_VIEWS, DENSE_SEED, DENSE_PARTS = 9000, 30, 2026, 3


def dense_pairs():
    return sampling.grouped_random(DENSE_NORMALS * DENSE_VIEWS, DENSE_SEED, views=DENSE_VIEWS)


def dense_errors(approx: np.ndarray, exact: np.ndarray, groups) -> dict:
    """nrmse on the dense pairs (``exact`` its converged ground truth), the nrmse of each of its
    :data:`DENSE_PARTS` disjoint parts (whole normals each) and the frontal bin's."""
    flat = groups.flatten()
    nv = np.sum(flat.a * flat.b, axis=1)
    per = np.cumsum(groups.mask.sum(axis=1))  # flattened pairs are grouped by normal
    cuts = [0] + [int(per[len(per) * (k + 1) // DENSE_PARTS - 1]) for k in range(DENSE_PARTS)]
    e = errors(approx, exact, nv)
    return {"nrmse_dense": e["nrmse"], "nrmse_dense_frontal": e["nrmse_frontal"],
            "nrmse_dense_parts": [hf.fit.metrics.metrics(approx[a:b], exact[a:b])["nrmse"] for a, b in zip(cuts[:-1], cuts[1:])],
            "dense_pairs": int(len(nv)), "dense_normals": int(groups.normals.shape[0])}


def fit_dir(root: Path, material: str, env: str, method: str) -> Path:
    """Where ``--fits`` keeps the fit of one row: ``<root>/<material>_<env>_<method>`` (method slugged)."""
    slug = "".join(c if c.isalnum() else "_" for c in method.replace("'", "p"))
    return root / f"{material}_{env}_{slug}"


def _key(*parts) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def ground_truth(material: str, env: str, groups, log=print, start: int = 64, limit: int = 512, tol: float = 0.005):
    """(values (M, 3), resolution, change at the last doubling): the converged brute-force lighting."""
    CACHE.mkdir(exist_ok=True)
    brdf = MATERIALS[material]()
    prev, prev_r, change = None, None, None
    r = start
    while r <= limit:
        f = CACHE / f"gt_{material}_{env}_{r}_{_key(hf.__version__, groups.normals.shape, float(groups.normals.sum()))}.npy"
        if f.exists():
            y = np.load(f)
        else:
            t0 = time.perf_counter()
            e = hf.light.load_environment(env, r)
            target = Target("lighting", hf.light.Lighting(brdf, e, horizon="centroid"), "lighting")
            y = np.asarray(evaluate_grouped(target, groups), np.float64)
            np.save(f, y)
            log(f"  ground truth {material}/{env} at light resolution {r}: {time.perf_counter() - t0:.1f} s")
        if prev is not None:
            change = float(np.mean(np.linalg.norm(y - prev, axis=0) / np.linalg.norm(y, axis=0)))
            if change < tol:
                return y, r, change
        prev, prev_r = y, r
        r *= 2
    return prev, prev_r, change


#: n.v bands and the top fraction of pairs whose share of the squared error :func:`errors` reports
SHARE_BANDS = (0.02, 0.1)
SHARE_TOP = 0.001


def error_shares(approx: np.ndarray, exact: np.ndarray, nv: np.ndarray) -> dict:
    """Where the squared error (the numerator of nrmse, summed over RGB) lives: the share held by the
    pairs with n.v below each of SHARE_BANDS, and by the worst SHARE_TOP of the pairs."""
    d2 = np.sum((approx - exact) ** 2, axis=1)
    total = max(float(d2.sum()), 1e-30)
    out = {f"share_nv_lt_{b:g}": float(d2[nv < b].sum() / total) for b in SHARE_BANDS}
    k = max(1, int(round(SHARE_TOP * len(d2))))
    out["share_top"] = float(np.sort(d2)[::-1][:k].sum() / total)
    return out


def errors(approx: np.ndarray, exact: np.ndarray, nv: np.ndarray) -> dict:
    """nrmse and avg_rel (pinned definitions, per channel then averaged), nrmse per n.v bin, and the
    shares of the squared error of :func:`error_shares`."""
    m = hf.fit.metrics.metrics(approx, exact)
    out = {"nrmse": m["nrmse"], "avg_rel": m["avg_rel"]}
    for name, (lo, hi) in BINS.items():
        sel = (nv >= lo) & (nv < hi)
        d, e = approx[sel] - exact[sel], exact[sel]
        out[f"nrmse_{name}"] = float(np.mean(np.linalg.norm(d, axis=0) / np.maximum(np.linalg.norm(e, axis=0), 1e-30)))
    return {**out, **error_shares(approx, exact, nv)}


#: exact renders by (material, environment, resolution, pixel hash): every method renders the same pixels
_EXACT: dict = {}


def image_error(fac, material: str, env: str, resolution: int, size: int = 96) -> float | None:
    """nrmse of a rendered sphere (the exported shader on the GPU) against the ground truth at its pixels."""
    try:
        frame = hf.gl.render(fac, "sphere", size=size)
    except HomofacError:
        return None
    m = frame.mask
    n, v = frame.a[m], frame.b[m]
    ok = np.sum(n * v, axis=1) > 0
    key = (material, env, resolution, hashlib.sha256(np.ascontiguousarray(n).tobytes() + v.tobytes()).hexdigest())
    if key not in _EXACT:
        e = hf.light.load_environment(env, resolution)
        target = Target("lighting", hf.light.Lighting(MATERIALS[material](), e, horizon="centroid"), "lighting")
        exact = np.zeros((len(n), 3))
        exact[ok] = np.asarray(hf.target.evaluate(target, n[ok], v[ok]), np.float64)
        _EXACT[key] = exact
    exact = _EXACT[key]
    got = np.where(ok[:, None], frame.value[m], 0.0)
    return float(np.mean(np.linalg.norm(got - exact, axis=0) / np.maximum(np.linalg.norm(exact, axis=0), 1e-30)))


def run_case(material: str, env: str, methods: list[str], fit_resolution: int, size: int, log=print,
             fits: Path | None = None) -> list[dict]:
    """The rows of one case. ``fits``: a directory of saved fits, one per row (:func:`fit_dir`): a row whose
    fit is there is measured from it (``fit_s``: the seconds its fit took, recorded in it), the others are
    fitted and saved there, so new metrics can be added to old rows without fitting again."""
    groups = validation_pairs()
    val = groups.flatten()
    nv = np.sum(val.a * val.b, axis=1)
    gt, r_gt, change = ground_truth(material, env, groups, log)
    dense = dense_pairs()
    dval = dense.flatten()
    dgt, dr, _ = ground_truth(material, env, dense, log)
    targets = {}  # light resolution -> target
    samples_cache = {}
    rows = []
    for name in methods:
        kw = dict(METHODS[name])
        p = kw.pop("parametrization")
        res = kw.pop("fit_resolution", fit_resolution)
        if res not in targets:
            targets[res] = hf.light.lighting_target(MATERIALS[material](), hf.light.load_environment(env, res))
        target = targets[res]
        # the fits' own validation pairs (at the fit's light resolution; the package's count, 20000 or
        # the quality mode's 80000: homofac.fit.pipeline.validation_count) choose structures; rows are
        # measured on the ground-truth pairs below
        sampling_cfg = {"kind": "texels", "size": 24, **kw.pop("sampling", {})}
        if sampling_cfg["kind"] == "grid":
            sampling_cfg.update(size=size, mapper="dual_paraboloid")
        # the grid design of the off-specular products (NRO, RO) puts r_off on texel centres: their own pairs
        target_p = hf.light.lighting_target(target.fn.brdf, target.fn.env, parametrization=p)
        grid_p = p if p in hf.param.parametrizations.PARAMETRIZATIONS else "NR"
        skey = json.dumps([sampling_cfg, hf.param.parametrizations.reflection_projection(grid_p), res], sort_keys=True)
        saved = fit_dir(fits, material, env, name) if fits is not None else None
        if saved is not None and (saved / "factorization.json").exists():
            fac = hf.load(saved)
            fit_s = float(json.loads((saved / "factorization.json").read_text())["timings"]["total_s"])
            log(f"  {material}/{env} {name}: the fit saved in {saved}")
        else:
            if skey not in samples_cache and "max_lookups" not in kw:
                samples_cache[skey] = hf.fit.draw_samples(target_p, grid_p, sampling_cfg)
            t0 = time.perf_counter()
            if "max_lookups" in kw:  # the chooser draws the grid pairs of each candidate's direction (r, r_off)
                fac = hf.fit.factorize(target_p, p, texture_size=size, sampling=sampling_cfg, **kw)
            else:
                fac = hf.fit.factorize(target_p, p, texture_size=size, samples=samples_cache[skey], **kw)
            fit_s = time.perf_counter() - t0
            if saved is not None:
                fac.save(saved)
        approx = np.asarray(fac.evaluate(val.a, val.b), np.float64)
        pol = (fac.selection or {}).get("polish")  # the chooser's polish of the kept structure (kept or not)
        row = {"method": name, "material": material, "environment": env, "lookups": fac.model.lookups,
               "structure": fac.parametrization, "chosen": (fac.selection or {}).get("chosen", {}).get("label"),
               "polished": bool(pol is not None and pol.get("kept", True)),
               "line_size": max((t.size for t in fac.model.textures if t.mapper == "line"), default=None),
               "texels": fac.model.texels, "fit_s": fit_s, **errors(approx, gt, nv),
               "image_nrmse": image_error(fac, material, env, r_gt), "ground_truth_resolution": r_gt,
               "ground_truth_change": change, "fit_resolution": res, "texture_size": size,
               **dense_errors(np.asarray(fac.evaluate(dval.a, dval.b), np.float64), dgt, dense),
               "dense_ground_truth_resolution": dr}
        rows.append(row)
        log(f"  {material}/{env} {name}: nrmse {row['nrmse']:.4f} (grazing {row['nrmse_grazing']:.3f}, frontal "
            f"{row['nrmse_frontal']:.3f}), {row['lookups']} lookups, {fit_s:.1f} s")
    return rows


def report(rows: list[dict], only: tuple[str, ...] | None = None) -> str:
    """The markdown table: per case the nrmse of every method (or of those in ``only``), and its ratio to
    split-sum, columns in the order of ``only``; then the n.v bins of the same methods, and (for the whole
    table only) the error shares."""
    if only is not None:
        rows = sorted((r for r in rows if r["method"] in only), key=lambda r: only.index(r["method"]))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    cases = list(dict.fromkeys((r["material"], r["environment"]) for r in rows))
    by = {(r["material"], r["environment"], r["method"]): r for r in rows}
    look = {m: next(r["lookups"] for r in rows if r["method"] == m) for m in methods}
    head = "| case | " + " | ".join(f"{m} ({look[m]})" for m in methods) + " |"
    lines = [head, "|---|" + "---:|" * len(methods)]
    for c in cases:
        ss = by.get((*c, "split_sum"))
        cells = []
        for m in methods:
            r = by.get((*c, m))
            if r is None:
                cells.append("")
                continue
            ratio = f" ({r['nrmse'] / ss['nrmse']:.2f}x)" if ss and m != "split_sum" else ""
            cells.append(f"{r['nrmse']:.3f}{ratio}")
        lines.append(f"| {c[0]} / {c[1]} | " + " | ".join(cells) + " |")
    lines += ["", bins_table(rows)]
    if any("nrmse_dense" in r for r in rows):
        lines += ["", dense_table(rows)]
    if only is None and any("share_top" in r for r in rows):
        lines += ["", shares_table(rows)]
    # one entry a case (runs of the same case may differ in the change's last float digits)
    gt = sorted({(r["material"], r["environment"]): (r["material"], r["environment"], r["ground_truth_resolution"],
                                                     r["ground_truth_change"]) for r in rows}.values())
    lines.append("")
    lines.append("Ground truth light resolution (and nrmse change at the last doubling): " + ", ".join(
        f"{m}/{e} {res} ({ch:.2%})" for m, e, res, ch in gt if ch is not None))
    return "\n".join(lines)


def dense_table(rows: list[dict]) -> str:
    """The rows measured on the dense pairs too (:func:`dense_pairs`): nrmse on the table's 20000 pairs and on
    the dense ones, the spread over the dense set's disjoint parts, and the ratio to split-sum's there."""
    by = {(r["material"], r["environment"], r["method"]): r for r in rows}
    r0 = next(r for r in rows if "nrmse_dense" in r)
    lines = [f"nrmse on {r0['dense_pairs']} pairs of {r0['dense_normals']} normals (the rows measured there; its "
             f"{len(r0['nrmse_dense_parts'])} disjoint parts of whole normals give the spread):", "",
             "| case | method | lookups | 20000 pairs | dense pairs | its parts | / split-sum there | frontal |",
             "|---|---|---:|---:|---:|---|---:|---:|"]
    for r in rows:
        if "nrmse_dense" not in r:
            continue
        ss = by.get((r["material"], r["environment"], "split_sum"), {})
        ratio = f"{r['nrmse_dense'] / ss['nrmse_dense']:.2f}x" if "nrmse_dense" in ss and r is not ss else ""
        parts = " / ".join(f"{x:.3f}" for x in r["nrmse_dense_parts"])
        lines.append(f"| {r['material']} / {r['environment']} | {r['method']} | {r['lookups']} | {r['nrmse']:.3f} | "
                     f"{r['nrmse_dense']:.3f} | {parts} | {ratio} | {r['nrmse_dense_frontal']:.3f} |")
    return "\n".join(lines)


def bins_table(rows: list[dict]) -> str:
    """Where the error lives: per method the nrmse in each n.v bin as a ratio to split-sum's (geometric mean
    over the cases), the worst case's total ratio, and the cases it is worse than split-sum in the frontal bin."""
    methods = [m for m in dict.fromkeys(r["method"] for r in rows) if m != "split_sum"]
    by = {(r["material"], r["environment"], r["method"]): r for r in rows}
    lines = ["| method | lookups | grazing / split-sum | mid | frontal | worst total ratio | frontal worse than split-sum | fit s |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for m in methods:
        rs = [(r, by.get((r["material"], r["environment"], "split_sum"))) for r in rows if r["method"] == m]
        rs = [(r, q) for r, q in rs if q is not None]
        if not rs:
            continue
        g = {b: float(np.exp(np.mean([np.log(r[f"nrmse_{b}"] / q[f"nrmse_{b}"]) for r, q in rs]))) for b in BINS}
        worst = max(r["nrmse"] / q["nrmse"] for r, q in rs)
        frontal = sum(r["nrmse_frontal"] > q["nrmse_frontal"] for r, q in rs)
        fit_s = float(np.mean([r["fit_s"] for r, _ in rs]))
        lines.append(f"| {m} | {rs[0][0]['lookups']} | {g['grazing']:.2f}x | {g['mid']:.2f}x | {g['frontal']:.2f}x | "
                     f"{worst:.2f}x | {frontal} of {len(rs)} | {fit_s:.1f} |")
    return "\n".join(lines)


def shares_table(rows: list[dict]) -> str:
    """Per case and method, the share of the squared error held by the grazing-most pairs and by the worst
    0.1 % of the pairs (the rows that record them)."""
    bands = " | ".join(f"n.v < {b:g}" for b in SHARE_BANDS)
    lines = [f"| case | method | lookups | nrmse | share of squared error: {bands} | worst {SHARE_TOP:.1%} of pairs |",
             "|---|---|---:|---:|" + "---:|" * (len(SHARE_BANDS) + 1)]
    for r in rows:
        if "share_top" not in r:
            continue
        cells = " | ".join(f"{r[f'share_nv_lt_{b:g}']:.0%}" for b in SHARE_BANDS)
        lines.append(f"| {r['material']} / {r['environment']} | {r['method']} | {r['lookups']} | {r['nrmse']:.3f} | "
                     f"{cells} | {r['share_top']:.0%} |")
    return "\n".join(lines)


def plots(rows: list[dict], out: Path) -> list[Path]:
    import matplotlib  # noqa: PLC0415 - plotting only

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    paths = []
    methods = list(dict.fromkeys(r["method"] for r in rows))
    for key, label, fname in (("lookups", "texture lookups per pixel", "accuracy_lookups.png"),
                              ("fit_s", "fit / build seconds", "accuracy_time.png")):
        fig, ax = plt.subplots(figsize=(7, 4.5))
        for m in methods:
            rs = [r for r in rows if r["method"] == m]
            x = np.mean([r[key] for r in rs])
            y = np.mean([r["nrmse"] for r in rs])
            lo, hi = min(r["nrmse"] for r in rs), max(r["nrmse"] for r in rs)
            ax.errorbar([x], [y], yerr=[[y - lo], [hi - y]], fmt="o", capsize=3, label=m)
        ax.set_xlabel(label)
        ax.set_ylabel("nrmse (mean over cases; bars: min-max)")
        if key == "fit_s":
            ax.set_xscale("log")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
        fig.tight_layout()
        p = out / fname
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)
    return paths


def write_page(rows: list[dict], docs: Path = DOCS) -> Path:
    """docs/benchmarks/accuracy.md: the table of :data:`PAGE_METHODS` (:func:`report`) with the two plots,
    which are copied beside the page. Returns the page's path."""
    docs.mkdir(parents=True, exist_ok=True)
    for name in ("accuracy_lookups.png", "accuracy_time.png"):
        (docs / name).write_bytes((HERE / name).read_bytes())
    text = f"""# Accuracy against split-sum

<!-- Generated by benchmarks/accuracy.py (or benchmarks/pages.py) from benchmarks/accuracy.json: do not edit. -->

Every method on 16 cases (four materials under the four bundled environments) against a converged
ground truth: nrmse on 20000 random (n, v) pairs, the ratio to split-sum's in brackets, lookups per
pixel in the header. `max_lookups 4`, `8` and `16` are the lookup budgets of the presets `fast`,
`balanced` and `best`. The second table says where the error lives (the n.v bins: grazing < 0.25,
frontal > 0.5, as ratios to split-sum's, geometric mean over the cases) and the mean fit seconds;
the third reads the rows measured on 270000 dense pairs, a steadier figure under a sun.

```sh
python benchmarks/accuracy.py            # every case and method: hours (a 16-lookup fit takes 30-80 minutes)
```

{report(rows, PAGE_METHODS)}

![nrmse against lookups](accuracy_lookups.png)
![nrmse against fit time](accuracy_time.png)

Every method of the run, and the error shares of the worst pairs: `benchmarks/accuracy.md`. The
research notes ([sums of products](../notes/sums-research.md), [README history](../notes/readme-history.md))
say how each row was obtained.
"""
    page = docs / "accuracy.md"
    page.write_text(text)
    return page


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", default=str(HERE / "accuracy.json"))
    ap.add_argument("--cases", help="material/environment,... (default: all)")
    ap.add_argument("--methods", help="comma-separated (default: all)")
    ap.add_argument("--fit-resolution", type=int, default=32)
    ap.add_argument("--size", type=int, default=32)
    ap.add_argument("--merge", action="append", default=[],
                    help="a JSON of an earlier run whose rows are kept (its cases are not run again)")
    ap.add_argument("--fits", type=Path,
                    help="a directory of saved fits, one per row: rows found there are measured from them, the "
                         "others are fitted and saved there")
    args = ap.parse_args(argv)
    cases = [tuple(c.split("/")) for c in args.cases.split(",")] if args.cases else [
        (m, e) for m in MATERIALS for e in ENVIRONMENTS]
    methods = args.methods.split(",") if args.methods else list(METHODS)
    rows = [r for m in args.merge for r in json.loads(Path(m).read_text())]
    done = {(r["material"], r["environment"]) for r in rows}
    for material, env in cases:
        if (material, env) in done:
            continue
        rows += run_case(material, env, methods, args.fit_resolution, args.size, fits=args.fits)
        Path(args.json).write_text(json.dumps(rows, indent=1))  # after every case: a killed run keeps its rows
    Path(args.json).write_text(json.dumps(rows, indent=1))  # also when every case came from --merge
    table = report(rows)
    out = Path(args.json)
    out.with_suffix(".md").write_text(table + "\n")  # the default run: benchmarks/accuracy.md
    if out.resolve() == (HERE / "accuracy.json").resolve():
        # a run into another JSON (a subset) leaves the committed plots and the page alone
        plots([r for r in rows if r["method"] in PAGE_METHODS], HERE)
        write_page(rows)
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
