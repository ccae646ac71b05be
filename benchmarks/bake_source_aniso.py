"""The analytic source's lobe widened by its footprint in half vectors, isotropic (built) or anisotropic, on saved cells.

A source of angular radius t seen from v covers half vectors h = normalize(l + v) with dh = (I - h h^T) dl / (2 v.h)
(v.h = n.v at the peak): across the plane of incidence dh = dl / (2 n.v), in it the component of dl along h drops
out and dh = dl / 2. So the footprint is an ellipse of half-axes t / 2 (in the plane) and t / (2 n.v) (across),
area pi t^2 / (4 n.v). The built rule (homofac.bake.sources, SPREAD c) widens GGX isotropically to the ellipse's
area, alpha'^2 = alpha^2 + (c t)^2 / (4 n.v); the anisotropic rule widens each axis by its own half-axis:

    alpha_x'^2 = alpha^2 + (c t)^2 / (4 (n.v)^px),   alpha_y'^2 = alpha^2 + (c t)^2 / (4 (n.v)^py)          (1)

x along v's projection on the tangent plane, px = 0, py = 2 (the footprint); px = py = 1 is the built rule. D'
is the anisotropic GGX 1 / (pi ax ay (h_x^2 / ax^2 + h_y^2 / ay^2 + h_z^2)^2), normalized like D, so the source's
reflected power is unchanged. Only the source term changes (the maps do not depend on it), so the saved cells of
``bake_accuracy.py --save-pairs`` are re-read with the saved bakes, against their converged reference.

    PYTHONPATH=src python benchmarks/bake_source_aniso.py PAIRS_DIR BAKE_DIR --envs city forest --bands 1 2
        --rules iso 1.25,0,2 1,0,2
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import homofac as hf
from homofac.bake import model
from homofac.bake.kernels import _frame, _local
from homofac.brdf.gltf import gltf_lobes_at

from bake_pairs import weighted_nrmse

BUILT = model.source_terms


def aniso_terms(sources, n, v, roughness, c: float, px: float, py: float):
    """(I_d, I_A, I_B) (N, 3, 3) of the sources with D widened by (1) (homofac.bake.sources.source_terms' frame)."""
    n, v = jnp.asarray(n, jnp.float32), jnp.asarray(v, jnp.float32)
    rho = jnp.broadcast_to(jnp.asarray(roughness, jnp.float32), n.shape[:1])
    out = jnp.zeros(n.shape[:1] + (3, 3), jnp.float32)
    t, b = _frame(n)
    wo = _local(v, t, b, n)
    a2 = rho ** 4
    for s in sources:
        wi = _local(jnp.broadcast_to(jnp.asarray(s.direction, jnp.float32), n.shape), t, b, n)
        above = (wi[2] > 0) & (wo[2] > 0)
        wi = tuple(jnp.where(above, q, 0.0 if i < 2 else 1.0) for i, q in enumerate(wi))
        wo_ = (wo[0], wo[1], jnp.where(above, wo[2], 1.0))
        d, la, lb = gltf_lobes_at(rho, wi, wo_)
        h = [a + q for a, q in zip(wi, wo_)]
        hn2 = h[0] ** 2 + h[1] ** 2 + h[2] ** 2
        nh2 = jnp.maximum(h[2], 0.0) ** 2 / hn2
        sin2 = (h[0] ** 2 + h[1] ** 2) / hn2
        tl = jnp.sqrt(jnp.maximum(wo_[0] ** 2 + wo_[1] ** 2, 1e-12))
        hx2 = ((h[0] * wo_[0] + h[1] * wo_[1]) / tl) ** 2 / hn2
        hy2 = jnp.maximum(sin2 - hx2, 0.0)
        x = jnp.maximum(wo_[2], 1e-4)
        base = (c * s.radius) ** 2 / 4
        ax2, ay2 = a2 + base / x ** px, a2 + base / x ** py
        q = hx2 / ax2 + hy2 / ay2 + nh2
        k = (a2 * nh2 + sin2) ** 2 / (a2 * jnp.sqrt(ax2 * ay2) * q * q)  # D' / D
        lobes = jnp.where(above[:, None], jnp.stack([d, la * k, lb * k], 1) * wi[2][:, None], 0.0)
        out = out + lobes[:, :, None] * jnp.asarray(s.power, jnp.float32)[None, None, :]
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("pairs", help="bake_accuracy.py --save-pairs DIR")
    ap.add_argument("bakes", help="bake_accuracy.py --bake-dir DIR (NAME-PRESET)")
    ap.add_argument("--envs", nargs="+", default=list(hf.light.BUNDLED))
    ap.add_argument("--bands", nargs="+", type=int, default=[0, 1, 2, 3])
    ap.add_argument("--presets", nargs="+", default=["balanced"])
    ap.add_argument("--rules", nargs="+", default=["iso", "1.25,0,2"], help="iso (built) or c,px,py of (1)")
    args = ap.parse_args(argv)
    for rule in args.rules:
        if rule == "iso":
            model.source_terms = BUILT
        else:
            c, px, py = (float(a) for a in rule.split(","))
            model.source_terms = lambda s, n, v, r, c=c, px=px, py=py: aniso_terms(s, n, v, r, c, px, py)
        for name in args.envs:
            for preset in args.presets:
                b = hf.load(Path(args.bakes) / f"{name}-{preset}")
                for bi in args.bands:
                    f = Path(args.pairs) / f"{name}-{bi}.npz"
                    if not f.exists():
                        continue
                    z = np.load(f)
                    a = np.asarray(b.evaluate(z["n"], z["v"], z["c"], z["m"], z["rho"]), np.float64)
                    ideal = weighted_nrmse(z["split_sum_ideal"], z["reference"], z["w"])
                    x = weighted_nrmse(a, z["reference"], z["w"])
                    print(json.dumps({"rule": rule, "environment": name, "preset": preset, "band": bi, "pairs": len(a),
                                      "nrmse": round(x, 4), "ideal": round(ideal, 4), "ratio": round(x / ideal, 3),
                                      "source": bool(b.sources)}), flush=True)


if __name__ == "__main__":
    main()
