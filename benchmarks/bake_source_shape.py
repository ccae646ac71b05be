"""The analytic source's lobe shape, on the converged cells' pairs: point light, GGX widened by the source's
radius (:data:`homofac.bake.sources.SPREAD`), and a disc by the representative point (Karis 2013).

For the saved bakes of benchmarks/bake_accuracy.py (``--bake-dir``), the bake's maps (its terms without the
source) plus each model of the source, against the reference, on a cell's pairs (:mod:`bake_pairs`):

* ``point``: the glTF lobes at the source's direction l (a delta light);
* ``widened k``: GGX D at alpha^2 + (k radius)^2;
* ``widened_nv k``: GGX D at alpha^2 + (k radius)^2 / (4 n.v) (the source's angular radius k radius mapped to
  half vectors: dw_l = 4 (v.h) dw_h, v.h = n.v at the lobe's peak);
* ``disc c``: a uniform disc of angular radius t = c radius about l, by its representative point: the lobes
  (I_A, I_B) at the direction of the disc nearest the reflected direction r, D scaled by
  alpha^2 / (alpha^2 + t^2 / (4 n.v)) (at the mirror limit the disc's radiance Phi / (pi t^2) times the
  albedo; 1 where alpha >> t); I_d the point light's. c = sqrt 2: a uniform disc with the source's RMS radius.

    PYTHONPATH=src python benchmarks/bake_source_shape.py --bake-dir DIR [--envs city ...] [--bands 0 1] [--pairs 2048]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import homofac as hf
from homofac.bake.kernels import _frame, _local
from homofac.bake.sources import source_terms, widened_ratio
from homofac.brdf.gltf import gltf_lobes_at
from homofac.io.exr import read_exr
from homofac.light.integrals import material_radiance
from homofac.light.reference import reference_integrals, source_map

sys.path.insert(0, str(Path(__file__).parent))
import bake_accuracy as ba  # noqa: E402
from bake_pairs import weighted_nrmse, weighted_pairs  # noqa: E402


def source_model(src, n, v, rho, kind: str, k: float) -> np.ndarray:
    """(N, 3, 3) of one source under a model (module docstring)."""
    n, v = jnp.asarray(n, jnp.float32), jnp.asarray(v, jnp.float32)
    rho = jnp.broadcast_to(jnp.asarray(rho, jnp.float32), n.shape[:1])
    t, b = _frame(n)
    wo = _local(v, t, b, n)
    l = jnp.broadcast_to(jnp.asarray(src.direction, jnp.float32), n.shape)
    a2 = rho ** 4
    point = np.asarray(source_terms((src._replace(radius=0.0),), n, v, rho), np.float64)
    if kind == "point":
        return point
    if kind in ("widened", "widened_nv"):
        wi = _local(l, t, b, n)
        above = (wi[2] > 0) & (wo[2] > 0)
        h = [a + c for a, c in zip(wi, wo)]
        hn2 = h[0] ** 2 + h[1] ** 2 + h[2] ** 2
        s2 = (k * src.radius) ** 2 if kind == "widened" else (k * src.radius) ** 2 / (4 * jnp.maximum(wo[2], 1e-4))
        r = widened_ratio(a2, s2, s2, jnp.maximum(h[2], 0) ** 2 / hn2, (h[0] ** 2 + h[1] ** 2) / hn2, 0.0)
        out = point.copy()
        out[:, 1:] *= np.asarray(jnp.where(above, r, 1.0))[:, None, None]
        return out
    td = k * src.radius  # disc: representative point
    x = jnp.sum(n * v, -1)
    r = 2 * x[:, None] * n - v
    cr = jnp.sum(r * l, -1)
    perp = r - cr[:, None] * l
    perp = perp / jnp.maximum(jnp.linalg.norm(perp, axis=-1, keepdims=True), 1e-12)
    lr = jnp.where((cr >= np.cos(td))[:, None], r, np.cos(td) * l + np.sin(td) * perp)
    wi = _local(lr, t, b, n)
    above = (wi[2] > 0) & (wo[2] > 0)
    wi = tuple(jnp.where(above, c, 0.0 if i < 2 else 1.0) for i, c in enumerate(wi))
    _, la, lb = gltf_lobes_at(rho, wi, (wo[0], wo[1], jnp.where(above, wo[2], 1.0)))
    norm = a2 / (a2 + td * td / (4 * jnp.maximum(x, 1e-4)))
    lobes = jnp.where(above[:, None], jnp.stack([la, lb], 1) * (norm * wi[2])[:, None], 0.0)
    out = point.copy()
    out[:, 1:] = np.asarray(lobes)[:, :, None] * np.asarray(src.power)[None, None, :]
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bake-dir", required=True)
    ap.add_argument("--preset", default="balanced")
    ap.add_argument("--envs", nargs="+", default=["city", "interior", "forest", "studio"])
    ap.add_argument("--bands", nargs="+", type=int, default=[0, 1])
    ap.add_argument("--pairs", type=int, default=2048)
    ap.add_argument("--samples", type=int, default=4096)
    ap.add_argument("--k", nargs="+", type=float, default=[1.0, 1.25, 1.5, 2.0], help="widened_nv's k")
    args = ap.parse_args(argv)
    models = [("point", 0.0), ("widened", 1.0), ("widened", 1.5)] + [("widened_nv", k) for k in args.k]
    for name in args.envs:
        b = hf.load(Path(args.bake_dir) / f"{name}-{args.preset}")
        if not b.sources:
            print(json.dumps({"env": name, "source": None}))
            continue
        image = read_exr(hf.light.bundled(name))
        src = source_map(image, name)
        for bi in args.bands:
            band = ba.BANDS[bi]
            n, v, c, m, rho, w = weighted_pairs(image, band, args.pairs, ba.cell_seed(name, bi))
            L = np.asarray(material_radiance(jnp.asarray(reference_integrals(src, n, v, rho, samples=args.samples)), c, m))
            maps = np.asarray(b.terms(n, v, rho), np.float64) - np.asarray(source_terms(b.sources, n, v, rho), np.float64)
            row = {"env": name, "band": band, "pairs": args.pairs, "radius": round(b.sources[0].radius, 4)}
            for kind, k in models:
                t = maps + source_model(b.sources[0], n, v, rho, kind, k)
                row[f"{kind} {k:.3g}"] = round(weighted_nrmse(np.asarray(material_radiance(jnp.asarray(t), c, m)), L, w), 4)
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
