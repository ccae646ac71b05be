"""Accuracy of the material-parametric bake against a converged reference, beside split-sum and glTF-IBL-Sampler.

For each bundled environment and roughness band (0.045-0.15, 0.15-0.3, 0.3-0.6, 0.6-1), a cell: the weighted
nrmse (:func:`bake_pairs.weighted_nrmse`) of L = (1 - m) 0.96 c I_d + f0_eff I_A + I_B over the pairs of
:func:`bake_pairs.weighted_pairs`: n.v as over the pixels of a rendered object (v cosine-distributed about n),
random glTF materials (roughness uniform in the band, base colour uniform, metallic 0, 1 or uniform by thirds),
the reflected directions importance-sampled by the environment's luminance with weights 1 / probability (so
the cell estimates the population's nrmse; bake_pairs.py's docstring). A cell starts at ``--pairs`` (512) and
doubles (the first N pairs of 2N are the N) until one more doubling moves every method's figure by < 5 %
(relative), or ``--max-pairs`` (8192); its row keeps the final count, each method's last movement and the
history. Every method reads the same pairs; against

* the reference: :func:`homofac.light.reference.reference_integrals` (the glTF BRDF integrated against the
  source lat-long map read bilinearly, multiple importance sampling, float64) with 2048, 4096, ... samples per
  strategy (``--ref-start``), doubled per batch of new pairs until one more doubling moves the batch's L by < 1 %
  weighted nrmse (or the cap, reported); then, per cell, the pairs carrying most of |L|^2 and of the first
  bake's squared error (16 each) recomputed at 4x the samples (:func:`pair_check`: the largest relative change
  of one pair, which is how converged the reference is where the cell's figure comes from);
* the bake (per preset), each in a fresh process (``python -m homofac.bake`` with ``HOMOFAC_JAX_CACHE=0``: every
  program compiles, as on a new user's first run; textures written as float32 and read back with ``hf.load``):
  its wall and CPU time beside the sampler's in the same run, fetches, texture memory (half floats, RGB) and the
  memory of split-sum at the same sharpness: the smallest engines' chain (below) that reads, at every layer's
  roughness, a face at least as fine as the bake's layer (:func:`same_sharpness_face`), plus a 32^2 x 6
  irradiance cube and a 32 x 32 DFG table;
* glTF-IBL-Sampler's default bake (:mod:`homofac.baselines.ibl_sampler`: GGX cube 256 x 256 x 6, 8 mips, half
  floats, 1024 samples, its 256 x 256 LUT, and a Lambertian cube 64), run in the same process just before the
  bake, read the engines' way: the glTF Sample Viewer's ``ibl.glsl`` (``sampler``) and the plain split sum
  ``textureLod(GGX, r, lod) (f0 A + B) + c_diff Lambertian(n)`` (``sampler split-sum``); 3 fetches; memory the
  GGX chain and the Lambertian cube in half RGB plus the LUT in half RG (its PNG is 8 bits);
* idealized split-sum: I_A ~ P(r) A, I_B ~ P(r) B, I_d ~ E(n)/pi d, with P(r) the environment integrated
  against the glTF specular lobe itself at n = v = r at the pair's roughness (the split sum's own assumption,
  normalized by that lobe's albedo; computed by the same reference), A, B, d the exact directional albedos at
  the pair's (n.v, rho) (the reference under constant radiance 1, ``--albedo-samples`` 1024: within 0.25 % of
  16384 in d and A), E(n) the exact irradiance (light sum at 64);
* split-sum the engines' way (emulated here): E(n) from a 32^2 x 6 irradiance map, P from a prefiltered mip
  chain (face size the source's detail down to 4, level lod = rho (levels - 1), each level prefiltered at its
  roughness, read bilinearly per face and blended between levels), A, B, d from 32 x 32 tables (bilinear);
* a per-material homofac fit (``--fits`` materials per band on the ``--fit-envs``, drawn like the others): ``hf.fit.factorize`` of
  that material's lighting (``hf.brdf.gltf``) at ``max_lookups`` ``--fit-lookups`` with small settings
  (:data:`FIT_SETTINGS`), on the cell's first 512 pairs (weighted) with that material, beside the bake and
  split-sum on the same.

    PYTHONPATH=src python benchmarks/bake_accuracy.py [--pairs 512] [--max-pairs 8192] [--nv cosine|uniform]
        [--presets fast balanced] [--envs forest ...] [--fits 0] [--bands 0 1 2 3] [--no-sampler] [--bake-dir DIR]

writes benchmarks/bake_accuracy.json and .md (``--out`` another stem); ``python benchmarks/pages.py`` turns the JSON
into docs/benchmarks/bake.md; both are written after every environment. ``--bake-dir DIR`` keeps the bakes there
(``DIR/NAME-PRESET``) and reads them back on a later run (then without their timings).
``benchmarks/bake_breakdown.py`` splits a cell's error by term and cause; ``benchmarks/bake_source_shape.py``
compares models of the analytic source on a cell's pairs.
"""

from __future__ import annotations

import argparse
import functools
import json
import time
from pathlib import Path

import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile

import jax.numpy as jnp
import numpy as np

import homofac as hf
from homofac.bake import kernels as kn
from homofac.bake.build import source_size
from homofac.bake.plan import plan as bake_plan
from homofac.bake.filter import prefilter
from homofac.baselines import ibl_sampler as ibl
from homofac.baselines.base import irradiance_map
from homofac.io.exr import read_exr
from homofac.light.integrals import material_radiance
from homofac.light.reference import reference_integrals, source_map
from homofac.param import mappers

from bake_pairs import NV_SHARE, weighted_nrmse, weighted_pairs

BANDS = ((0.045, 0.15), (0.15, 0.3), (0.3, 0.6), (0.6, 1.0))
HERE = Path(__file__).parent


def pairs(count, rng):
    """Uniform pairs (n uniform, v uniform on its hemisphere): the draw of the runs before the weighted cells,
    kept for the studies that repeat them (bake_memory.py, bake_sizes.py, ...)."""
    n = rng.normal(size=(count, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    v = rng.normal(size=(count, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v = np.where((np.sum(n * v, 1) < 0)[:, None], -v, v)
    return n, v


def materials(count, band, rng):
    rho = rng.uniform(*band, count)
    c = rng.uniform(0, 1, (count, 3))
    m = np.where(np.arange(count) % 3 == 0, 0.0, np.where(np.arange(count) % 3 == 1, 1.0, rng.uniform(0, 1, count)))
    return c, m, rho


def nrmse(a, e):
    return float(np.linalg.norm(np.asarray(a) - np.asarray(e)) / np.linalg.norm(np.asarray(e)))


class DFG:
    """The DFG terms A, B (albedos of the lobes (1 - s5) S and s5 S) and d (of (1 - s5)/pi, so that I_d ~ E d)
    on a grid, bilinear in (n.v, rho)."""

    def __init__(self, size):
        self.x = kn.nv_centres(size)
        self.r = np.linspace(0.04, 1.0, size)
        self.ab = np.stack([kn.albedos(float(r), self.x) for r in self.r])  # (R, 2, X)
        self.d = kn.mass(kn.diffuse_kernels(self.x))

    def __call__(self, x, rho):
        x, rho = np.asarray(x, np.float64), np.asarray(rho, np.float64)
        fr = np.clip((rho - self.r[0]) / (self.r[1] - self.r[0]), 0, len(self.r) - 1.0001)
        i = np.floor(fr).astype(int)
        t = fr - i
        xs = np.clip(x, self.x[0], self.x[-1])
        fx = (xs - self.x[0]) / (self.x[1] - self.x[0])
        k = np.clip(np.floor(fx).astype(int), 0, len(self.x) - 2)
        s = fx - k

        def at(j, lobe):  # linear in n.v on row j (np.interp per pair, vectorized)
            return (1 - s) * self.ab[j, lobe, k] + s * self.ab[j, lobe, k + 1]
        a = (1 - t) * at(i, 0) + t * at(i + 1, 0)
        b = (1 - t) * at(i, 1) + t * at(i + 1, 1)
        return a, b, np.interp(x, self.x, self.d)


@functools.lru_cache(maxsize=32)
def environment(name, resolution):
    """``hf.light.load_environment(name, resolution)``, loaded once per run."""
    return hf.light.load_environment(name, resolution)


class EnginesSplitSum:
    """I_d, I_A, I_B the engines' way (module docstring): the irradiance cube and the prefiltered chain are built
    once per environment, then read at any pairs."""

    def __init__(self, name, dfg32, source):
        self.dfg = dfg32
        self.e = jnp.asarray(irradiance_map(environment(name, 32), "cube", 32), jnp.float32)
        self.levels = int(np.log2(source)) - 1  # down to 4
        self.sizes = [source >> j for j in range(self.levels)]
        q = kn.q_grid()
        ch2 = 1 - q * q
        cosg = 1 - 2 * q * q
        self.chain = []
        for j, s in enumerate(self.sizes):
            rj = j / (self.levels - 1)
            env = environment(name, max(s, 8))
            dirs = mappers.texel_directions("cube", s).reshape(-1, 3)
            a2 = max(rj, 0.045) ** 4  # level 0: the sharpest roughness the engines serve (a near mirror)
            kern = kn.smooth((a2 / (np.pi * (ch2 * (a2 - 1) + 1) ** 2) * np.maximum(cosg, 0))[None], (np.pi / 2) / max(s, 8))
            num, den = prefilter(kern, dirs, env)
            self.chain.append(jnp.asarray((num[:, 0] / den[:, :1]).reshape(s, 6 * s, 3), jnp.float32))
        self.bytes = sum(6 * s * s * 3 * 2 for s in self.sizes)

    def __call__(self, n, v, rho):
        x = np.sum(n * v, 1)
        r = 2 * x[:, None] * n - v
        ev = np.asarray(mappers.lookup("cube", self.e, jnp.asarray(n, jnp.float32)))
        lod = rho * (self.levels - 1)
        p = 0.0
        for j, level in enumerate(self.chain):
            w = np.maximum(0, 1 - np.abs(lod - j))[:, None]
            p = p + w * np.asarray(mappers.lookup("cube", level, jnp.asarray(r, jnp.float32)))
        a, b, d = self.dfg(x, rho)
        return np.stack([ev / np.pi * d[:, None], p * a[:, None], p * b[:, None]], 1)


def engines_split_sum(name, n, v, rho, dfg32, source):
    """I_d, I_A, I_B the engines' way (see the module docstring) and the chain's bytes."""
    e = EnginesSplitSum(name, dfg32, source)
    return e(n, v, rho), e.bytes


#: The per-material fit's settings (beside ``max_lookups``): small, so that a fit takes 30-90 s here.
#: ``prefiltered: false``: the chooser's split-sum candidates need a ggx / cook_torrance target, not gltf.
FIT_SETTINGS = dict(texture_size=32, sampling={"count": 8192, "validation": 4096},
                    advanced={"prefiltered": False, "linear": {"polish": 0, "iterations": 15}})
#: Light resolution of the fitted target's lighting.
FIT_RESOLUTION = 32
#: Samples per strategy of the constant-radiance reference (the directional albedos A, B, d).
ALBEDO_SAMPLES = 8192


def reference(src, n, v, rho, c, m, start=4096, cap=65536, w=None):
    """(parts, samples, converged, last change): the samples doubled until L moves by < 1 % nrmse (weighted by
    ``w`` when given, :func:`bake_pairs.weighted_nrmse`)."""
    w = np.ones(len(n)) if w is None else w
    prev, samples, change = None, start, None
    while True:
        parts = reference_integrals(src, n, v, rho, samples=samples)
        L = np.asarray(material_radiance(jnp.asarray(parts), c, m))
        if prev is not None:
            change = weighted_nrmse(prev, L, w)
            if change < 0.01:
                return parts, samples, True, change
        if samples >= cap:
            return parts, samples, False, change
        prev, samples = L, 2 * samples


def ideal_split_sum(src, uniform, name, n, v, rho, samples, albedo_samples=None):
    """I_d, I_A, I_B of the idealized split sum (module docstring)."""
    albedo_samples = albedo_samples or ALBEDO_SAMPLES
    x = np.sum(n * v, 1)
    r = 2 * x[:, None] * n - v
    alb = reference_integrals(uniform, n, v, rho, samples=albedo_samples)[:, :, 0]  # (N, 3): d, A, B
    lobe = reference_integrals(src, r, r, rho, samples=samples)
    norm = reference_integrals(uniform, r, r, rho, samples=albedo_samples)[:, :, 0]
    p = (lobe[:, 1] + lobe[:, 2]) / (norm[:, 1] + norm[:, 2])[:, None]
    e = np.asarray(hf.light.irradiance(environment(name, 64), jnp.asarray(n, jnp.float32)), np.float64)
    return np.stack([e / np.pi * alb[:, :1], p * alb[:, 1:2], p * alb[:, 2:3]], 1)


def preset_flags(preset: str) -> list[str]:
    """The CLI flags of a benchmark preset: a preset name followed by any of ``+hR`` (``--harmonic R
    --no-mixed``: the layers from roughness R up carry the second harmonic, unpacked; ``+h0``: none), ``+mR``
    (``--harmonic R --mixed``: those layers carry K - 1 products and the harmonic in the K-th's channels), ``+tex``
    / ``+sh9`` (``--diffuse``) and ``+own`` (``--no-shared-gain``: h_A and h_B). The eighteenth session's
    ``balanced`` (7 fetches) is ``balanced+m0.35+tex``."""
    base, *parts = preset.split("+")
    flags = ["--preset", base]
    for p in parts:
        if p[:1] in "hm" and p[1:]:
            flags += ["--harmonic", p[1:], "--mixed" if p[0] == "m" else "--no-mixed"]
        elif p in ("tex", "sh9"):
            flags += ["--diffuse", "texture" if p == "tex" else "sh9"]
        elif p == "own":
            flags += ["--no-shared-gain"]
        else:
            raise SystemExit(f"bake_accuracy: unknown preset part +{p} in {preset!r}")
    return flags


def fresh_bake(name, preset, tmp):
    """``python -m homofac.bake NAME --preset PRESET`` in a fresh process with JAX's persistent compilation
    cache off (``HOMOFAC_JAX_CACHE=0``: every program compiles, as on a new user's first run), the textures
    written as float32 (what the in-memory bake reads); (the bake read back, wall s, CPU s of the process)."""
    out = Path(tmp) / f"{name}-{preset}"
    env = {**os.environ, "HOMOFAC_JAX_CACHE": "0"}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "homofac.bake", name, *preset_flags(preset), "--out", str(out), "--exr", "float32"],
                   check=True, env=env, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return hf.load(out), wall, cpu


def chain_face(rho: float, size: int) -> int:
    """The face an engines' prefiltered chain with level 0 of face ``size`` (levels down to 4,
    ``lod = rho (levels - 1)``, as :func:`engines_split_sum`) reads at roughness ``rho``: ``size 2^-lod`` as the
    nearest power of two (in log2)."""
    levels = int(np.log2(size)) - 1
    return int(2 ** round(np.log2(size) - rho * (levels - 1)))


def same_sharpness_face(roughness, sizes) -> int:
    """Level 0 of split-sum at the same sharpness as a bake: the smallest power-of-two face whose chain reads,
    at every layer's roughness, a face at least as fine as the bake's layer there (docs/notes/bake.md, "Memory
    at the same sharpness"). Layers at the bake's smallest face (8) are left out: the chain's last levels are 4
    whatever its level 0, and 8 is the bake's floor, not a resolution its lobes ask for."""
    size = max(sizes)
    while any(chain_face(r, size) < s for r, s in zip(roughness, sizes) if s > min(sizes)):
        size *= 2
    return size


def chain_bytes(size: int) -> int:
    """Half RGB bytes of the engines' prefiltered cube mip chain with level 0 of face ``size``, down to 4 (the
    emulated split-sum's chain, :func:`engines_split_sum`)."""
    levels = int(np.log2(size)) - 1
    return sum(6 * (size >> j) ** 2 * 3 * 2 for j in range(levels))


#: Half bytes of the emulated split-sum's irradiance cube (32^2 x 6, RGB) and DFG table (32 x 32, RGB).
SPLIT_SUM_EXTRA = 32 * 32 * 6 * 3 * 2 + 32 * 32 * 3 * 2


def sampler_bytes(b) -> int:
    """The sampler's textures as an engine holds them: GGX chain and Lambertian cube in half RGB, LUT in half RG."""
    return sum(a.size * 2 for a in (*b.ggx, b.lambertian)) + b.lut.size * 2


def fit_rows(name, band, n, v, rng, count, lookups, src, samples, bakes, presets, uniform, w):
    """Per-material fits (module docstring): one row per material."""
    out = []
    env = environment(name, FIT_RESOLUTION)
    for _ in range(count):
        c, rho = rng.uniform(0, 1, 3), float(rng.uniform(*band))
        m = float((0.0, 1.0, rng.uniform(0, 1))[int(rng.integers(3))])
        brdf = hf.brdf.gltf(base_color=tuple(float(a) for a in c), metallic=m, roughness=rho)
        t = time.perf_counter()
        fac = hf.fit.factorize(hf.light.lighting_target(brdf, env), max_lookups=lookups, **FIT_SETTINGS)
        fit_s = time.perf_counter() - t
        cc, mm, rr = np.tile(c, (len(n), 1)), np.full(len(n), m), np.full(len(n), rho)
        parts = reference_integrals(src, n, v, rr, samples=samples)
        L = np.asarray(material_radiance(jnp.asarray(parts), cc, mm))
        ideal = ideal_split_sum(src, uniform, name, n, v, rr, samples)
        row = {"environment": name, "band": list(band), "base_color": [float(a) for a in c], "metallic": m,
               "roughness": rho, "pairs": len(n), "fit_lookups": int(fac.model.lookups), "fit_max_lookups": lookups,
               "fit_s": fit_s, "fit": weighted_nrmse(np.asarray(fac.evaluate(n.astype(np.float32), v.astype(np.float32))), L, w),
               "fit_validation": fac.metrics["validation"]["float"]["nrmse"],
               "fit_choice": (fac.selection or {}).get("reason"),
               "split_sum_ideal": weighted_nrmse(material_radiance(jnp.asarray(ideal), cc, mm), L, w)}
        for p in presets:
            row[f"bake_{p}"] = weighted_nrmse(np.asarray(bakes[(name, p)].evaluate(n, v, cc, mm, rr)), L, w)
        out.append(row)
        print("fit", json.dumps({k: (round(x, 4) if isinstance(x, float) else x) for k, x in row.items()}), flush=True)
    return out


#: A cell's first batch of pairs, its cap, and the largest movement of one more doubling that counts as converged.
START_PAIRS = 512
MAX_PAIRS = 8192
TOLERANCE = 0.05
#: Pairs per cell whose reference is recomputed at 4x the samples (the per-pair check), and that factor.
CHECK_PAIRS = 16
CHECK_FACTOR = 4


def cell_seed(name: str, band_index: int) -> int:
    """The Sobol' seed of a cell: the same pairs for a bundled environment and band in any run."""
    envs = list(hf.light.BUNDLED)
    return 1000 * (envs.index(name) + 1 if name in envs else 99) + band_index


def methods_at(n, v, c, m, rho, ctx):
    """Every method's radiance (N, 3) at the pairs, with the reference and its record (:func:`cell`)."""
    parts, samples, conv, change = reference(ctx["src"], n, v, rho, c, m, start=ctx["ref_start"], cap=ctx["cap"], w=ctx["w"])
    out = {"reference": np.asarray(material_radiance(jnp.asarray(parts), c, m)), "reference_parts": np.asarray(parts),
           "split_sum_ideal": np.asarray(material_radiance(jnp.asarray(ideal_split_sum(
               ctx["src"], ctx["uniform"], ctx["name"], n, v, rho, samples, ctx["albedo_samples"])), c, m)),
           "split_sum_engines": np.asarray(material_radiance(jnp.asarray(ctx["engines"](n, v, rho)), c, m))}
    if ctx["sampler"] is not None:
        out["sampler"] = ctx["sampler"].evaluate(n, v, c, m, rho)
        out["sampler_split_sum"] = ctx["sampler"].evaluate(n, v, c, m, rho, formula="split_sum")
    for preset, b in ctx["bakes"].items():
        out[f"bake_{preset}"] = np.asarray(b.evaluate(n, v, c, m, rho), np.float64)
    return out, {"samples": samples, "converged": conv, "change": change, "pairs": len(n)}


def pair_check(ctx, n, v, c, m, rho, w, L, err, samples):
    """The reference at the pairs that carry a cell: the ``CHECK_PAIRS`` largest ``w |L|^2`` and the
    ``CHECK_PAIRS`` largest ``w |a - L|^2`` of ``err`` (N,), recomputed at ``CHECK_FACTOR`` times the samples:
    the largest relative change |dL| / |L| of one pair and the checked pairs' share of the cell's squared error."""
    top = np.unique(np.concatenate([np.argsort(w * np.sum(L * L, 1))[-CHECK_PAIRS:], np.argsort(w * err)[-CHECK_PAIRS:]]))
    parts = reference_integrals(ctx["src"], n[top], v[top], rho[top], samples=CHECK_FACTOR * samples)
    fine = np.asarray(material_radiance(jnp.asarray(parts), c[top], m[top]))
    rel = np.linalg.norm(fine - L[top], axis=1) / np.maximum(np.linalg.norm(fine, axis=1), 1e-30)
    return {"pairs": int(len(top)), "samples": CHECK_FACTOR * samples, "max_relative_change": float(rel.max()),
            "median_relative_change": float(np.median(rel)), "error_share": float(np.sum((w * err)[top]) / np.sum(w * err)),
            "lowest_nv": float(np.sum(n[top] * v[top], 1).min())}


def cell(image, band, band_index, ctx, start, cap, nv, nv_share=NV_SHARE):
    """One cell (environment x band): pairs (:func:`bake_pairs.weighted_pairs`) doubled from ``start`` until one
    more doubling moves every method's weighted nrmse by < ``TOLERANCE`` (relative), or ``cap``; the reference
    doubled per batch of new pairs (:func:`reference`). Returns the row and the arrays."""
    count, have, vals, history, batches = start, 0, {}, [], []
    arrays = None
    while True:
        n, v, c, m, rho, w = weighted_pairs(image, band, count, ctx["seed"], nv, nv_share)
        new = slice(have, count)
        ctx["w"] = w[new]
        out, rec = methods_at(n[new], v[new], c[new], m[new], rho[new], ctx)
        batches.append(rec)
        vals = {k: (np.concatenate([vals[k], x]) if k in vals else x) for k, x in out.items()}
        L = vals["reference"]
        cells = {k: weighted_nrmse(x, L, w) for k, x in vals.items() if not k.startswith("reference")}
        history.append({"pairs": count, **{k: round(x, 5) for k, x in cells.items()}})
        move = None
        if len(history) > 1:
            prev = history[-2]
            move = {k: abs(x - prev[k]) / x for k, x in cells.items()}
        print(f"  {band}: {count} pairs " + " ".join(f"{k}={x:.4f}" for k, x in cells.items())
              + (f"; largest move {max(move.values()):.3f} ({max(move, key=move.get)})" if move else ""), flush=True)
        if (move and max(move.values()) < TOLERANCE) or count >= cap:
            break
        have, count = count, 2 * count
    arrays = (n, v, c, m, rho, w)
    first = next((k for k in vals if k.startswith("bake_")), "split_sum_ideal")
    err = np.sum((vals[first] - L) ** 2, 1)
    check = pair_check(ctx, n, v, c, m, rho, w, L, err, max(r["samples"] for r in batches))
    x = np.sum(n * v, 1)
    row = {"environment": ctx["name"], "band": list(band), "pairs": count, "nv": nv, "nv_share": nv_share, "converged": bool(move and max(move.values()) < TOLERANCE),
           "movement": {k: round(x_, 4) for k, x_ in (move or {}).items()}, "history": history,
           "reference_samples": max(r["samples"] for r in batches), "reference_converged": all(r["converged"] for r in batches),
           "reference_last_change": max(r["change"] or 0 for r in batches), "reference_batches": batches, "reference_check": check,
           "weights_max": float(w.max()), "error_share_nv<0.3": float(np.sum((w * err)[x < 0.3]) / np.sum(w * err)),
           "error_share_top5": float(np.sort(w * err)[-5:].sum() / np.sum(w * err)),
           "split_sum_engines_bytes": chain_bytes(ctx["source"]) + SPLIT_SUM_EXTRA,
           **cells}
    for preset, b in ctx["bakes"].items():
        row[f"bake_{preset}_lookups"] = b.lookups
    return row, arrays, vals


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pairs", type=int, default=START_PAIRS, help="pairs of a cell's first batch (a power of two)")
    ap.add_argument("--max-pairs", type=int, default=MAX_PAIRS, help="cap of a cell's pairs")
    ap.add_argument("--nv", choices=("cosine", "uniform"), default="cosine",
                    help="n.v as on a rendered object (cosine) or uniform on the hemisphere (the earlier runs)")
    ap.add_argument("--nv-share", type=float, default=NV_SHARE,
                    help="share of the population's own n.v law in the proposal of n | r, the rest favouring grazing "
                         "views (bake_pairs.py (2'); 1: the seventeenth session's pairs)")
    ap.add_argument("--presets", nargs="+", default=["fast", "balanced"],
                    help="presets, or PRESET+hR: the preset with the second harmonic from roughness R, unpacked "
                         "(--harmonic R --no-mixed; +h0: none); PRESET+mR: mixed (--harmonic R --mixed)")
    ap.add_argument("--envs", nargs="+", default=list(hf.light.BUNDLED))
    ap.add_argument("--cap", type=int, default=65536, help="largest reference sample count per strategy")
    ap.add_argument("--ref-start", type=int, default=2048, help="first reference sample count per strategy")
    ap.add_argument("--albedo-samples", type=int, default=1024, help="samples of the constant-radiance albedos")
    ap.add_argument("--fits", type=int, default=0, help="per-material homofac fits per band (0: none)")
    ap.add_argument("--fit-envs", nargs="+", default=["forest", "studio"], help="environments with per-material fits")
    ap.add_argument("--fit-lookups", type=int, default=4, help="max_lookups of the per-material fits")
    ap.add_argument("--bands", nargs="+", type=int, default=list(range(len(BANDS))), help="indices into BANDS")
    ap.add_argument("--no-sampler", action="store_true", help="leave glTF-IBL-Sampler out")
    ap.add_argument("--bake-dir", default=None, help="read the bakes from DIR/NAME-PRESET when there (else bake and keep them there)")
    ap.add_argument("--out", default=str(HERE / "bake_accuracy"), help="stem of the .json and .md written")
    ap.add_argument("--save-pairs", default=None,
                    help="write each cell's pairs, weights, every method's radiance and the reference's (d, A, B) to "
                         "DIR/NAME-BAND.npz (what benchmarks/bake_breakdown.py --pairs-from reads)")
    args = ap.parse_args(argv)
    fit_rng = np.random.default_rng(1)
    dfg32 = DFG(32)
    uniform = source_map(np.ones((8, 16, 3)))
    rows, fits, bakes, runs = [], [], {}, []
    why = None if not args.no_sampler else "--no-sampler"
    why = why or ibl.available()
    t_run = time.perf_counter()
    load_before = os.getloadavg()
    tmp = args.bake_dir or tempfile.mkdtemp(prefix="bake_accuracy-")
    for name in args.envs:
        source = source_size(name)
        image = read_exr(hf.light.bundled(name))
        src = source_map(image, name)
        sb = sampler_wall = None
        if why is None:
            t = time.perf_counter()
            sb = ibl.bake(name)
            wall = time.perf_counter() - t
            runs.append({"environment": name, "method": "glTF-IBL-Sampler (default: GGX 256, 8 mips; Lambertian 64)",
                         "lookups": 3, "wall_s": wall, "ggx_wall_s": sb.runs["ggx"]["wall_s"],
                         "lambertian_wall_s": sb.runs["lambertian"]["wall_s"],
                         "cpu_s": sb.runs["ggx"]["cpu_s"] + sb.runs["lambertian"]["cpu_s"],
                         "peak_rss_mb": max(sb.runs["ggx"]["peak_rss_mb"], sb.runs["lambertian"]["peak_rss_mb"]),
                         "bytes": sampler_bytes(sb), "files_bytes": sb.files, "mips": sb.mips})
            sampler_wall = wall
            print(f"{name} sampler: {wall:.1f} s", flush=True)
        env_bakes = {}
        for preset in args.presets:
            load = os.getloadavg()[0]
            kept = Path(tmp) / f"{name}-{preset}"
            if args.bake_dir and kept.is_dir():
                env_bakes[preset] = b = hf.load(kept)
                print(f"{name} {preset}: read from {kept}", flush=True)
                continue
            b, wall, cpu = fresh_bake(name, preset, tmp)
            env_bakes[preset] = bakes[(name, preset)] = b
            finest = max(int(p.shape[0]) for p in b.P)
            same = same_sharpness_face(b.roughness, [int(p.shape[0]) for p in b.P])
            runs.append({"environment": name, "method": f"homofac bake {preset}", "lookups": b.lookups, "wall_s": wall,
                         "cpu_s": cpu, "load_average": load, "fresh_process": True,
                         "timings": b.info["timings"], "bytes": b.texture_bytes(), "finest_face": finest,
                         "split_sum_same_sharpness_face": same,
                         "split_sum_same_sharpness_bytes": chain_bytes(same) + SPLIT_SUM_EXTRA,
                         "sampler_wall_s": sampler_wall})
            print(f"{name} {preset}: {wall:.1f} s wall, {cpu:.1f} s CPU (fresh process); {b.describe()}", flush=True)
        bakes.update({(name, p): b for p, b in env_bakes.items()})
        ctx = {"name": name, "src": src, "uniform": uniform, "engines": EnginesSplitSum(name, dfg32, source), "source": source,
               "sampler": sb, "bakes": env_bakes, "cap": args.cap, "ref_start": args.ref_start,
               "albedo_samples": args.albedo_samples}
        for bi in args.bands:
            band = BANDS[bi]
            ctx["seed"] = cell_seed(name, bi)
            t_cell = time.process_time()
            row, (n, v, c, m, rho, w), vals = cell(image, band, bi, ctx, args.pairs, args.max_pairs, args.nv, args.nv_share)
            if args.save_pairs:
                Path(args.save_pairs).mkdir(parents=True, exist_ok=True)
                np.savez_compressed(Path(args.save_pairs) / f"{name}-{bi}.npz", n=n, v=v, c=c, m=m, rho=rho, w=w, **vals)
            row["cpu_s"] = time.process_time() - t_cell
            rows.append(row)
            print(json.dumps({k: (round(x, 4) if isinstance(x, float) else x) for k, x in row.items()
                              if k not in ("history", "reference_batches")}), flush=True)
            if args.fits and name in args.fit_envs:
                k = min(len(n), START_PAIRS)
                fits += fit_rows(name, band, n[:k], v[:k], fit_rng, args.fits, args.fit_lookups, src, row["reference_samples"],
                                 bakes, args.presets, uniform, w[:k])
        save(args, argv, rows, fits, runs, why, load_before, t_run)
    if not args.bake_dir:
        shutil.rmtree(tmp, ignore_errors=True)
    print(save(args, argv, rows, fits, runs, why, load_before, t_run))


def save(args, argv, rows, fits, runs, why, load_before, t_run) -> str:
    """Write the run so far (.json and .md; called after every environment, so a stopped run keeps its rows)."""
    doc = {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
                       "load_average_before": load_before, "load_average_after": os.getloadavg(),
                       "wall_s": time.perf_counter() - t_run},
           "command": "PYTHONPATH=src python benchmarks/bake_accuracy.py " + " ".join(argv if argv is not None else sys.argv[1:]),
           "presets": args.presets, "sampler": why or "measured", "fit_settings": {"max_lookups": args.fit_lookups, **FIT_SETTINGS,
                                                                               "light_resolution": FIT_RESOLUTION},
           "rows": rows, "fits": fits, "runs": runs}
    out = Path(args.out)
    out.with_suffix(".json").write_text(json.dumps(doc, indent=1))
    text = markdown(doc)
    out.with_suffix(".md").write_text(text)
    return text


def _band(row) -> str:
    return f"{row['band'][0]}-{row['band'][1]}"


def goal(row, preset) -> tuple[bool, bool]:
    """(met the ideal goal, below the sampler) of a cell for a preset: nrmse <= 0.5x the idealized split-sum from
    roughness 0.15 up, <= 0.8x below; below glTF-IBL-Sampler's (True when the sampler is not in the row)."""
    x = row[f"bake_{preset}"]
    return (x <= (0.5 if row["band"][0] >= 0.15 else 0.8) * row["split_sum_ideal"], x < row.get("sampler", float("inf")))


def summary(doc: dict) -> list[str]:
    """One line per preset: the goal counts, and the cells converged in their pairs."""
    rows = doc["rows"]
    out = []
    conv = sum(bool(r.get("converged")) for r in rows)
    out.append(f"Cells converged in their pairs (one more doubling moves every column by < {TOLERANCE:.0%}): {conv} of {len(rows)}"
               + ("" if conv == len(rows) else " (the others at the cap: their largest move is in the pairs column)") + ".")
    for p in doc["presets"]:
        hi = [r for r in rows if r["band"][0] >= 0.15]
        lo = [r for r in rows if r["band"][0] < 0.15]
        with_sampler = [r for r in rows if "sampler" in r]
        out.append(f"`{p}`: <= 0.5x ideal in {sum(goal(r, p)[0] for r in hi)} of {len(hi)} cells from 0.15 up, "
                   f"<= 0.8x in {sum(goal(r, p)[0] for r in lo)} of {len(lo)} below"
                   + (f"; below the sampler in {sum(goal(r, p)[1] for r in with_sampler)} of {len(with_sampler)}" if with_sampler else "")
                   + ".")
    return out


def fits_markdown(doc: dict) -> list[str]:
    """The per-material fits' table of a run (``--fits``): per fit its material, fetches and time, and the nrmse of
    the fit, the ideal split-sum and each preset's bake on the cell's first pairs with that one material."""
    presets, fs = doc["presets"], doc["fit_settings"]
    lines = [f"Per-material homofac fits (`hf.fit.factorize(lighting_target(gltf(...), env at {fs['light_resolution']}), "
             f"max_lookups={fs['max_lookups']}, texture_size={fs['texture_size']}, sampling={fs['sampling']}, "
             f"advanced={fs['advanced']})`), nrmse on the band's pairs with that one material (*fit*: in parentheses "
             "the fit's own validation nrmse, on its validation pairs and lighting):", "",
             "| environment | band | material (c; m; rho) | fit fetches | fit time (s) | fit | split-sum ideal | "
             + " | ".join(f"bake {p}" for p in presets) + " |",
             "|---|---|---|---:|---:|---:|---:|" + "---:|" * len(presets)]
    for f in doc["fits"]:
        mat = f"({', '.join(f'{a:.2f}' for a in f['base_color'])}); {f['metallic']:.2f}; {f['roughness']:.3f}"
        lines.append(f"| {f['environment']} | {_band(f)} | {mat} | {f['fit_lookups']} | {f['fit_s']:.0f} | {f['fit']:.4f} "
                     f"({f['fit_validation']:.3f}) | {f['split_sum_ideal']:.4f} | "
                     + " | ".join(f"{f[f'bake_{p}']:.4f}" for p in presets) + " |")
    chosen = [f"{f['environment']} {_band(f)}: {f['fit_choice']}" for f in doc["fits"] if f.get("fit_choice")]
    return lines + (["", "The fits' choices: " + "; ".join(chosen) + "."] if chosen else [])


def markdown(doc: dict) -> str:
    """The tables of a run (benchmarks/bake_accuracy.md; docs/benchmarks/bake.md adds a heading)."""
    presets, rows = doc["presets"], doc["rows"]
    has_sampler = any("sampler" in r for r in rows)
    lookups = {p: next((r[f"bake_{p}_lookups"] for r in rows), "?") for p in presets}
    head = (["environment", "band", "pairs (largest move)", "reference samples (check)", "split-sum ideal", "split-sum engines"]
            + (["sampler", "sampler split-sum"] if has_sampler else [])
            + [f"bake {p} ({lookups[p]} fetches)" for p in presets]
            + [f"{p} / ideal" for p in presets] + ([f"{p} / sampler" for p in presets] if has_sampler else [])
            + [f"{p} goal" for p in presets])
    lines = ["| " + " | ".join(head) + " |", "|---|---|" + "---:|" * (len(head) - 2)]
    for r in rows:
        conv = "" if r["reference_converged"] else f", not converged: last {r['reference_last_change'] or 0:.3f}"
        check = r.get("reference_check")
        conv += f"; {check['samples']}: {check['max_relative_change']:.1%}" if check else ""
        move = max(r["movement"].values()) if r.get("movement") else float("nan")
        cells = [r["environment"], _band(r), f"{r['pairs']} ({move:.1%}{'' if r.get('converged') else ', cap'})",
                 f"{r['reference_samples']}{conv}", f"{r['split_sum_ideal']:.4f}", f"{r['split_sum_engines']:.4f}"]
        if has_sampler:
            cells += [f"{r.get('sampler', float('nan')):.4f}", f"{r.get('sampler_split_sum', float('nan')):.4f}"]
        cells += [f"{r[f'bake_{p}']:.4f}" for p in presets]
        cells += [f"{r[f'bake_{p}'] / r['split_sum_ideal']:.2f}" for p in presets]
        if has_sampler:
            cells += [f"{r[f'bake_{p}'] / r['sampler']:.2f}" if "sampler" in r else "-" for p in presets]
        cells += [("met" if goal(r, p)[0] else "missed") + ("" if goal(r, p)[1] else ", above sampler") for p in presets]
        lines.append("| " + " | ".join(cells) + " |")
    lines += [""] + summary(doc)
    if doc.get("fits"):
        lines += ["", *fits_markdown(doc)]
    lines += ["", "| environment | method | fetches | wall time (s) | CPU (s) | load | / sampler | texture MB (half) | "
              "finest face | split-sum same sharpness: level 0, MB | / split-sum |", "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    eng = {r["environment"]: r["split_sum_engines_bytes"] for r in rows}
    for run in doc["runs"]:
        t = run.get("timings")
        detail = (f" (maps {t['maps_s']:.1f}, weights {t['weights_s']:.1f}, kernels {t['kernels_s']:.1f}, "
                  f"diffuse {t['diffuse_s']:.1f}{', fresh process' if run.get('fresh_process') else ''})" if t else
                  f" (GGX {run['ggx_wall_s']:.1f}, Lambertian {run['lambertian_wall_s']:.1f})")
        cpu = f"{run['cpu_s']:.1f}" if run.get("cpu_s") is not None else "-"
        load = f"{run['load_average']:.1f}" if run.get("load_average") is not None else "-"
        ratio = f"{run['wall_s'] / run['sampler_wall_s']:.2f}" if run.get("sampler_wall_s") else "-"
        same = run.get("split_sum_same_sharpness_bytes")
        lines.append(f"| {run['environment']} | {run['method']} | {run['lookups']} | {run['wall_s']:.1f}{detail} | {cpu} | {load} | "
                     f"{ratio} | {run['bytes'] / 1e6:.2f} | {run.get('finest_face', '-')} | "
                     f"{run.get('split_sum_same_sharpness_face')}, {same / 1e6:.2f} | {run['bytes'] / same:.2f} |" if same else
                     f"| {run['environment']} | {run['method']} | {run['lookups']} | {run['wall_s']:.1f}{detail} | {cpu} | {load} | "
                     f"{ratio} | {run['bytes'] / 1e6:.2f} | - | - | - |")
    for name, b in eng.items():
        lines.append(f"| {name} | split-sum engines (emulated, source detail) | 3 | - | - | - | - | {b / 1e6:.2f} | - | - | - |")
    bakes = [r for r in doc["runs"] if r.get("timings")]
    if bakes:
        worst = max(bakes, key=lambda r: r["wall_s"])
        lines += ["", f"Slowest bake: {worst['environment']} {worst['method']} {worst['wall_s']:.1f} s wall "
                  f"({worst.get('cpu_s') or 0:.1f} s CPU; cap 60 s)."]
        timed = [r for r in bakes if r.get("sampler_wall_s")]
        if timed:
            w = max(timed, key=lambda r: r["wall_s"] / r["sampler_wall_s"])
            lines.append(f"Largest ratio to the sampler's default bake in the same run: {w['environment']} {w['method']} "
                         f"{w['wall_s'] / w['sampler_wall_s']:.2f}x (goal <= 2x).")
    m = doc["machine"]
    lines += ["", f"Run {m['date_utc']} UTC, {m['wall_s'] / 60:.1f} min wall, load average {m['load_average_before'][0]:.1f} "
              f"before and {m['load_average_after'][0]:.1f} after ({m['cpus']} cores): `{doc['command']}`."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
