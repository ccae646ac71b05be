"""Where a bake's texture memory goes, and what smaller per-map faces cost in accuracy (issue 42).

Bakes each environment once in this process (``--preset``, default ``balanced``: K = 2, mixed harmonic layers)
and prints its memory per map and per layer. Then it reads the same bake with *emulated* layouts, on the
benchmark's pairs and materials (drawn as benchmarks/bake_accuracy.py draws them, in the bundled order, so the
cells are the benchmark's) against the same converged reference:

* ``p2/F``: the second product P_2 stored at 1/F of its layer's face (the layer's map box-filtered F x F per
  face, then read bilinearly at its own size: what a per-map atlas with P_2 at the smaller face reads);
* ``p2f/2``: P_2 filtered at half its layer's face from its own kernel (what a bake would store: the layer fitted
  as the bake fits it, its maps filtered again at half the face, the bake's alignment rotation applied);
* ``h/F``: likewise the harmonic's tensor maps (no smaller than 8);
* ``e/F``: the diffuse maps E_d at 1/F of their face;
* ``p1L/F``: P_1 (and P_2) of layer L at 1/F of its face;
* ``gauge``: the memory of the layout with the tensor in 3 channels (homofac.bake.gauge, what a bake stores from
  schema 5 on: every variant reads the bake's tensors in that gauge) and P_1's RGB and the tensor or P_2's RGB in
  two RGB maps, each its own atlas; without it, the memory of the one-atlas RGBA layout of schema 4.

Every variant is the bake's own read (homofac.bake.model) with those maps swapped, starting from the maps as
the bake stores them (``Bake.read_maps``: since step 3 of schema 5, P_2 at half its layer's face in
``balanced``, so ``p2/2`` reads it at a quarter): ``base`` equals ``Bake.evaluate`` (checked). The memory of each layout (half floats, RGB per map, shelf-packed atlases, E_d and
the tables) is printed beside; the goal is split-sum at the same sharpness (0.829 MB: a 128 chain).

    PYTHONPATH=src python benchmarks/bake_memory.py [--envs studio forest] [--bands 1 2] [--variants base p2/2 ...]
        [--json ROWS.jsonl]
    PYTHONPATH=src python benchmarks/bake_memory.py --breakdown [--preset balanced]   (the stored layout's memory
        per map and block, homofac.bake.build.map_layouts; no bake)

All four environments and bands with seven variants took 6 minutes here (load 6-8; one in-process bake per
environment, the reference as the benchmark's). Rows: benchmarks/bake_memory.jsonl (``V MB``: the layout's memory;
``p2/F``, ``h/F``, ``e/F`` without ``gauge`` are counted in today's one-atlas RGBA layout, where they save nothing
but the E_d bytes). docs/notes/bake.md, "Memory, sixteenth session".
"""

from __future__ import annotations

import argparse
import json
import time

import jax.numpy as jnp
import numpy as np

import bake_accuracy as ba
import homofac as hf
from homofac.bake import build
from homofac.bake.atlas import blocks_of, bottom_left, down, pack
from homofac.bake.build import layer_size, map_layouts, sharp
from homofac.bake.plan import plan as make_plan
from homofac.bake.gauge import face_gauge, gauge_read
from homofac.bake.model import TANGENT_FLOOR, _cube, _line, harmonic_colour, tensor_read
from homofac.bake.sources import source_terms
from homofac.io.exr import read_exr
from homofac.light.integrals import material_radiance
from homofac.light.reference import source_map

#: half bytes of split-sum at the same sharpness (128 chain + 32^2 x 6 irradiance + 32 x 32 DFG)
GOAL = ba.chain_bytes(128) + ba.SPLIT_SUM_EXTRA


def bake_with_half_maps(name, preset):
    """``(bake, {layer: P_2 filtered at half the face})``: the bake, with every layer fit of rank >= 2 filtered
    a second time at half its face (:func:`homofac.bake.build.layer_fit` at size / 2 reads the same data, since
    the data are at min(size, 32), so its weights equal the full fit's). Each layer's final P_2 is then matched
    to its fit through the alignment rotation (least squares of the bake's P[j] on that fit's maps)."""
    original, seen = build.layer_fit, []

    def fit(kernels, size, env, rank, data_size=32, masses=None, coarse=None):
        out = original(kernels, size, env, rank, data_size, masses, coarse)
        if rank >= 2 and masses is None and size >= 16:
            half = original(kernels, size // 2, env, rank, data_size, masses, coarse)
            seen.append((size, out[2], half[2]))
        return out

    build.layer_fit = fit
    try:
        b = hf.bake(name, preset=preset)
    finally:
        build.layer_fit = original
    halves = {}
    for j, p in enumerate(b.P):
        if b.blocks and b.blocks[j] != j or p.shape[2] < 2 or not np.any(p[:, :, 1]):
            continue
        s = p.shape[0]
        target = np.asarray(p, np.float64).reshape(6 * s * s, -1, 3)
        best = None
        for size, full, half in seen:
            if size != s:
                continue
            a = np.moveaxis(full, 2, 1).reshape(-1, full.shape[1])
            rot, *_ = np.linalg.lstsq(a, np.moveaxis(target, 2, 1).reshape(-1, target.shape[1]), rcond=None)
            res = np.linalg.norm(a @ rot - np.moveaxis(target, 2, 1).reshape(-1, target.shape[1])) / np.linalg.norm(target)
            if best is None or res < best[0]:
                best = (res, np.einsum("tic,i->tc", half, rot[:, 1]))
        assert best is not None and best[0] < 1e-4, (j, best and best[0])
        halves[j] = best[1].reshape(s // 2, 3 * s, 3).astype(np.float32)
    return b, halves


def terms(b, n, v, rho, P1, P2, H, gauged=False, E=None):
    """The bake's (I_d, I_A, I_B) with P_1, P_2 and the tensors given per layer (each at its own size)."""
    n = jnp.asarray(n, jnp.float32)
    v = jnp.asarray(v, jnp.float32)
    u = b.layer_coordinate(jnp.asarray(rho, jnp.float32))
    x = jnp.sum(n * v, -1)
    r = 2 * x[:, None] * n - v
    p1 = p2 = hb = 0.0
    for j in range(len(P1)):
        hat = jnp.maximum(0.0, 1.0 - jnp.abs(u - j))[:, None]
        a = (1 - b.shift[j]) * r + b.shift[j] * n
        a = a / jnp.maximum(jnp.linalg.norm(a, axis=-1, keepdims=True), 1e-12)
        p1 = p1 + hat * _cube(jnp.asarray(P1[j]), a).reshape(-1, 3)
        if P2[j] is not None:
            p2 = p2 + hat * _cube(jnp.asarray(P2[j]), a).reshape(-1, 3)
        if H[j] is not None:
            tg = n - jnp.sum(n * a, -1, keepdims=True) * a
            tg = tg / jnp.maximum(jnp.linalg.norm(tg, axis=-1, keepdims=True), TANGENT_FLOOR)
            m = _cube(jnp.asarray(H[j]), a).reshape(len(a), -1)
            hb = hb + hat[:, 0] * (gauge_read(m, a, tg) if gauged else tensor_read(m, tg))
    W = jnp.asarray(b.W, jnp.float32)
    rows = jnp.arange(W.shape[0], dtype=jnp.float32)
    hats = jnp.maximum(0.0, 1.0 - jnp.abs(u[:, None] - rows[None]))
    t = jnp.sum(hats[:, :, None] * _line(W, jnp.clip(x, 0, 1)), axis=1)
    ia = p1 * t[:, 0:1] + p2 * t[:, 2:3]
    ib = p1 * t[:, 1:2] + p2 * t[:, 3:4]
    hc = b.plan.harmonic_channel
    ia = harmonic_colour(ia, hb * t[:, hc])
    ib = harmonic_colour(ib, hb * t[:, hc + 1])
    e = _cube(jnp.asarray(b.E if E is None else E, jnp.float32), n).reshape(-1, b.plan.diffuse, 3)
    idf = jnp.sum(e * t[:, 2 * b.plan.terms:2 * b.plan.terms + b.plan.diffuse, None], 1)
    out = jnp.where((x > 0)[:, None, None], jnp.stack([idf, ia, ib], 1), 0.0)
    return out + source_terms(b.sources, n, v, jnp.asarray(rho, jnp.float32)) if b.sources else out


def layout_bytes(b, sizes_a, sizes_b, channels_a: int, channels_b: int, e_size: int) -> dict:
    """Half bytes of a two-map layout: map A's layer sizes (blocks shared as the bake shares them), map B's
    (None: the layer stores nothing there; read as a shared 8-face block of zeros), E_d and the tables."""
    blocks = b.blocks or tuple(range(len(sizes_a)))
    order = sorted(range(len(sizes_a)), key=lambda j: -sizes_a[j])
    at = pack([sizes_a[j] for j in order], [order.index(blocks[j]) for j in order])
    kept = [s for s in sizes_b if s is not None]
    bt = pack(sorted(kept, reverse=True) + ([8] if len(kept) < len(sizes_b) else [])) if kept else None
    e = b.plan.diffuse * 6 * e_size ** 2 * 3 * 2
    w = b.plan.tables * b.plan.layers * b.plan.nv_size * 3 * 2
    pa = at.width * at.height * channels_a * 2
    pb = bt.width * bt.height * channels_b * 2 if bt else 0
    wa, ha = bottom_left([sizes_a[j] for j in sorted(set(blocks))])[:2]
    wb, hb = bottom_left(sorted(kept, reverse=True) + ([8] if len(kept) < len(sizes_b) else []))[:2] if kept else (0, 0)
    bl = (wa * ha * channels_a + wb * hb * channels_b) * 2
    return {"A": pa, "B": pb, "A_atlas": [at.width, at.height], "B_atlas": [bt.width, bt.height] if bt else None,
            "E": e, "W": w, "total": pa + pb + e + w, "ratio": (pa + pb + e + w) / GOAL,
            "bottom_left": {"A_atlas": [wa, ha], "B_atlas": [wb, hb], "total": bl + e + w, "ratio": (bl + e + w) / GOAL}}


def variant(b, spec: str, halves=None):
    """(P1, P2, H, gauged, E, bytes) of a variant spec: ``base`` or '+'-joined ``p2/F``, ``h/F``, ``p1L/F``, ``gauge``."""
    L = b.plan.layers
    read, read_h = b.read_maps()  # each map at its block's size, as the bake reads it (``base`` is the bake)
    P1 = [np.asarray(p[0]) for p in read]
    P2 = [np.asarray(p[1]) if b.plan.terms > 1 and np.any(np.asarray(p[1])) else None for p in read]
    H = [None if (not b.H or h is None) else np.asarray(read_h[j]) for j, h in enumerate(b.H or [None] * L)]
    gauged = False
    E = np.asarray(b.E)
    for part in spec.split("+"):
        if part == "base":
            continue
        if part == "gauge":
            gauged = True
            continue
        what, f = part.split("/")
        f = int(f)
        if what == "p2":
            P2 = [None if p is None else down(p, min(f, p.shape[0] // 8)) for p in P2]
        elif what == "h":
            H = [None if h is None else down(h, max(1, min(f, h.shape[0] // 8))) for h in H]
        elif what == "p2f":
            P2 = [None if p is None else halves[j] for j, p in enumerate(P2)]
        elif what == "e":
            E = down(E, f)
        elif what.startswith("p1"):
            j = int(what[2:])
            P1[j] = down(P1[j], f)
            P2[j] = None if P2[j] is None else down(P2[j], f)
        else:
            raise SystemExit(f"unknown variant part {part!r}")
    if H and any(h is not None and h.shape[-1] == 5 for h in H):  # a bake of the 5-channel tensor (schema <= 4)
        H = [None if h is None else face_gauge(h, h.shape[0]) for h in H]
    read_gauge = any(h is not None for h in H)  # the tensors are in the face gauge (homofac.bake.gauge)
    sizes_a = [p.shape[0] for p in P1]
    sizes_b = [max(p.shape[0] if p is not None else 0, h.shape[0] if h is not None else 0) or None for p, h in zip(P2, H)]
    if gauged:  # two RGB maps: A = P_1, B = P_2 or the 3-channel tensor, each map its own layer sizes
        mem = layout_bytes(b, sizes_a, sizes_b, 3, 3, E.shape[0])
    else:  # two maps, A = P_1 RGB + (P_2.r | M_xx), B = RGBA rest: sized as the larger of the two per layer
        mem = layout_bytes(b, [max(a, s or 0) for a, s in zip(sizes_a, sizes_b)], [None] * L, 4, 4, E.shape[0])
        mem["B"] = mem["A"]
        mem["total"] += mem["A"]
        mem["ratio"] = mem["total"] / GOAL
    return P1, P2, H, read_gauge, E, mem


def breakdown(preset: str = "balanced", max_size: int = 64) -> list[dict]:
    """The layout a bake of ``preset`` stores (:func:`homofac.bake.build.map_layouts`, from the plan; no bake): per
    map and own block, the layers it serves, their roughness, its face, texels and half bytes (RGB); then each
    map's unused texels, E_d and the tables. The sum is ``Bake.texture_bytes`` of such a bake."""
    pl = make_plan(preset, max_size=max_size)
    r = pl.roughnesses()
    sizes = [layer_size(x, max_size) for x in r]
    shared = [sharp(x, max_size) for x in r]
    blocks = tuple(int(np.argmax(shared)) if shared[j] else j for j in range(pl.layers))
    harm = [j in pl.harmonic_layers() and not shared[j] for j in range(pl.layers)]
    rows = []
    for i, a in enumerate(map_layouts(pl, sizes, blocks, shared, harm)):
        firsts = blocks_of(a.offsets, a.sizes)
        used = 0
        for j in sorted(set(firsts)):
            serves = [k for k in range(pl.layers) if firsts[k] == j]
            t = 6 * a.sizes[j] ** 2
            used += t
            rows.append({"map": i, "layers": serves, "roughness": [round(r[k], 3) for k in serves], "face": a.sizes[j],
                         "layer_face": sizes[j], "texels": t, "bytes": t * 3 * 2})
        rows.append({"map": i, "layers": "packing", "texels": a.width * a.height - used,
                     "bytes": (a.width * a.height - used) * 3 * 2, "atlas": [a.width, a.height]})
    rows.append({"layers": "E_d" if pl.diffuse_basis == "texture" else "E_d (SH9 constants, no texture)",
                 "bytes": pl.diffuse * 6 * pl.diffuse_size ** 2 * 3 * 2 if pl.diffuse_basis == "texture" else 0})
    rows.append({"layers": "tables", "bytes": pl.tables * pl.layers * pl.nv_size * 3 * 2})
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--envs", nargs="+", default=list(hf.light.BUNDLED))
    ap.add_argument("--bands", nargs="+", type=int, default=[0, 1, 2, 3])
    ap.add_argument("--preset", default="balanced")
    ap.add_argument("--pairs", type=int, default=150)
    ap.add_argument("--variants", nargs="+", default=["base", "p2/2", "p2/4", "gauge", "gauge+p2/2", "gauge+p2/2+h/2"])
    ap.add_argument("--json", default=None, help="append the rows to this JSON-lines file")
    ap.add_argument("--breakdown", action="store_true", help="print the preset's memory per block and stop")
    args = ap.parse_args(argv)
    if args.breakdown:
        rows = breakdown(args.preset)
        for row in rows:
            print(json.dumps(row))
        total = sum(r['bytes'] for r in rows)
        print(f"total {total} bytes; goal {GOAL}; {total / GOAL:.3f}x")
        return
    rng = np.random.default_rng(0)
    for name in hf.light.BUNDLED:  # the benchmark's draw order
        todo = name in args.envs
        if todo:
            t = time.perf_counter()
            b, halves = bake_with_half_maps(name, args.preset)
            print(f"{name}: baked in {time.perf_counter() - t:.1f} s; {b.describe()}", flush=True)
            specs = {s: variant(b, s, halves) for s in args.variants}
            for s, (P1, P2, H, g, E, mem) in specs.items():
                print(f"  {s}: P1 {[p.shape[0] for p in P1]} P2 {[None if p is None else p.shape[0] for p in P2]} "
                      f"H {[None if h is None else h.shape[0] for h in H]} -> {json.dumps(mem)}", flush=True)
            src = source_map(read_exr(hf.light.bundled(name)), name)
        for i, band in enumerate(ba.BANDS):
            n, v = ba.pairs(args.pairs, rng)
            c, m, rho = ba.materials(args.pairs, band, rng)
            if not todo or i not in args.bands:
                continue
            parts, samples, _, _ = ba.reference(src, n, v, rho, c, m)
            L = np.asarray(material_radiance(jnp.asarray(parts), c, m))
            ideal = ba.ideal_split_sum(src, source_map(np.ones((8, 16, 3))), name, n, v, rho, samples)
            row = {"environment": name, "band": list(band), "preset": args.preset,
                   "split_sum_ideal": ba.nrmse(material_radiance(jnp.asarray(ideal), c, m), L),
                   "bake": ba.nrmse(np.asarray(b.evaluate(n, v, c, m, rho)), L)}
            for s, (P1, P2, H, g, E, mem) in specs.items():
                row[s] = ba.nrmse(np.asarray(material_radiance(terms(b, n, v, rho, P1, P2, H, g, E), c, m)), L)
                row[s + " MB"] = round(mem["total"] / 1e6, 4)
            print(json.dumps({k: (round(x, 4) if isinstance(x, float) else x) for k, x in row.items()}), flush=True)
            if args.json:
                with open(args.json, "a") as fh:
                    fh.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
