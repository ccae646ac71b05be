"""Today's bake with the environment's brightest compact source taken out and shaded as an analytic light.

The measurement that led to the bake's ``analytic_source`` (homofac.bake.sources), kept reproducible with the
bake's own source removal off: the brightest pixel of the source lat-long map seeds a source; the pixels
within ``--radius`` rad of it whose luminance is at least 1/``--ratio`` of the seed's are replaced by the mean
of the ring ``radius``-``2 radius`` around it, and the removed power sum (L - fill) dw becomes one point light
at its power-weighted mean direction. The map without the source is baked as usual (``hf.bake`` on a
temporary EXR, the real bake path); L is then the bake's terms plus the source's exact glTF lobes
((1 - s5)/pi, (1 - s5) S, s5 S times n.l times its power), against the converged reference of the original
map, on the benchmark's pairs and materials (:mod:`bake_breakdown`'s draws), beside the bake of the original
map and the idealized split-sum.

    PYTHONPATH=src python benchmarks/bake_sun.py city [--bands 1 2 3] [--presets fast balanced]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import homofac as hf
from homofac.bake.kernels import _frame, _local
from homofac.brdf.gltf import gltf_lobes_at
from homofac.io.exr import read_exr, write_exr
from homofac.light.integrals import material_radiance
from homofac.light.latlong import latlong_directions, latlong_solid_angles
from homofac.light.reference import reference_integrals, source_map

sys.path.insert(0, str(Path(__file__).parent))
import bake_accuracy as ba  # noqa: E402

LUMA = np.array([0.2126, 0.7152, 0.0722])


def take_source(img: np.ndarray, radius: float, ratio: float):
    """``(image without the source, direction (3,), RGB power (3,), pixels removed)``."""
    h, w = img.shape[:2]
    d = latlong_directions(h, w).reshape(-1, 3)
    dw = np.broadcast_to(latlong_solid_angles(h, w)[:, None], (h, w)).reshape(-1)
    flat = img[..., :3].reshape(-1, 3).astype(np.float64)
    lum = flat @ LUMA
    seed = int(np.argmax(lum))
    ang = np.arccos(np.clip(d @ d[seed], -1.0, 1.0))
    core = (ang < radius) & (lum >= lum[seed] / ratio)
    ring = (ang >= radius) & (ang < 2 * radius)
    fill = (flat[ring] * dw[ring, None]).sum(0) / dw[ring].sum()
    power = ((flat[core] - fill) * dw[core, None]).sum(0)
    direction = ((flat[core] - fill) @ LUMA * dw[core]) @ d[core]
    out = flat.copy()
    out[core] = fill
    return out.reshape(h, w, 3).astype(np.float32), direction / np.linalg.norm(direction), power, int(core.sum())


def source_terms(n, v, rho, direction, power) -> np.ndarray:
    """(N, 3, 3): (I_d, I_A, I_B) of one point light ``direction`` of RGB ``power`` at the pairs."""
    nj, vj = jnp.asarray(n), jnp.asarray(v)
    t, b = _frame(nj)
    lj = jnp.broadcast_to(jnp.asarray(direction), nj.shape)
    wi = _local(lj, t, b, nj)
    wo = _local(vj, t, b, nj)
    above = wi[2] > 0
    wi = (jnp.where(above, wi[0], 0.0), jnp.where(above, wi[1], 0.0), jnp.where(above, wi[2], 1.0))
    gd, ga, gb = gltf_lobes_at(jnp.asarray(rho), wi, wo)
    cos = jnp.where(above, wi[2], 0.0)
    lobes = np.stack([np.asarray(g * cos) for g in (gd, ga, gb)], 1)  # (N, 3)
    return lobes[:, :, None] * np.asarray(power)[None, None, :]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("env")
    ap.add_argument("--bands", nargs="+", type=int, default=[1, 2, 3])
    ap.add_argument("--presets", nargs="+", default=["fast", "balanced"])
    ap.add_argument("--pairs", type=int, default=150)
    ap.add_argument("--samples", type=int, default=8192)
    ap.add_argument("--radius", type=float, default=0.15)
    ap.add_argument("--ratio", type=float, default=20.0)
    args = ap.parse_args(argv)
    name = args.env
    img = read_exr(hf.light.bundled(name))
    src = source_map(img, name)
    uniform = source_map(np.ones((8, 16, 3)))
    rest, direction, power, count = take_source(np.asarray(img), args.radius, args.ratio)
    total = (np.asarray(img)[..., :3].reshape(-1, 3) @ LUMA * np.broadcast_to(
        latlong_solid_angles(*img.shape[:2])[:, None], img.shape[:2]).reshape(-1)).sum()
    print(json.dumps({"env": name, "source": {"direction": np.round(direction, 4).tolist(), "power": np.round(power, 4).tolist(),
                                              "pixels": count, "share": round(float(power @ LUMA / total), 4)}}), flush=True)
    bakes = {}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{name}_nosource.exr"
        write_exr(path, rest)
        for preset in args.presets:
            for label, s in ((preset, name), (f"{preset}+source", str(path))):
                t = time.perf_counter()
                bakes[label] = hf.bake(s, preset=preset, analytic_source=False)  # the source by hand, as measured
                print(json.dumps({"bake": label, "seconds": round(time.perf_counter() - t, 1)}), flush=True)
    rng = np.random.default_rng(0)
    for _ in range(4 * list(hf.light.BUNDLED).index(name)):  # the benchmark's draws (bake_breakdown's)
        ba.pairs(args.pairs, rng), ba.materials(args.pairs, (0.0, 1.0), rng)
    draws = [(ba.pairs(args.pairs, rng), ba.materials(args.pairs, band, rng)) for band in ba.BANDS]
    for bi in args.bands:
        (n, v), (c, m, rho) = draws[bi]
        ref = np.asarray(reference_integrals(src, n, v, rho, samples=args.samples), np.float64)
        L = np.asarray(material_radiance(jnp.asarray(ref), c, m))
        ideal = ba.ideal_split_sum(src, uniform, name, n, v, rho, args.samples)
        err = lambda parts: float(np.linalg.norm(np.asarray(material_radiance(jnp.asarray(parts), c, m)) - L) / np.linalg.norm(L))  # noqa: E731
        row = {"env": name, "band": ba.BANDS[bi], "ideal": round(err(ideal), 4)}
        extra = source_terms(n, v, rho, direction, power)
        for label, b in bakes.items():
            parts = np.asarray(b.terms(n, v, rho), np.float64) + (extra if label.endswith("+source") else 0.0)
            e = err(parts)
            row[label] = [round(e, 4), round(e / row["ideal"], 2)]
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
