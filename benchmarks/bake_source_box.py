"""Prototype (not the built rule): the analytic source's core as a box convolved with a Gaussian, read on saved cells.

Per principal axis of the source (variance var_i = |a_i|^2 / 2), a rectangle of variance k^2 var_i - q (half-width
b = sqrt(3 (k^2 var_i - q))) convolved with a Gaussian of variance q plus the lobe's own (homofac.bake.sources'
G, taken diagonal in the source's axes: the coupling g_12 is dropped), 1-D profile
(erf((b - t) / sqrt g) + erf((b + t) / sqrt g)) / 4b; ``gauss:CORE`` is the built Gaussian at another CORE. Only
the source term changes (Bake.evaluate with this source_terms); docs/notes/bake.md, "Studio below 0.15,
twentieth session".

    PYTHONPATH=src python benchmarks/bake_source_box.py PAIRS_DIR studio 0 BAKES/studio-balanced box:2e-4:1.15 gauss:1.2

``rule:BLUR[:PIXEL]`` is the built box (homofac.bake.sources.box_widths with the coupled box_blob): each source of
the bake gets the box of its axes at that BLUR (pixel: the source map's pixel angle, default pi / 128, a 256-wide
lat-long); ``rule:0:1`` with a huge pixel is the Gaussian (no box). Twenty-first session.
"""
import dataclasses
import json
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
from jax.scipy.special import erf
from homofac.bake import sources as hs
from homofac.bake.kernels import _frame, _local
from homofac.brdf.gltf import gltf_lobes_at
import homofac as hf
import homofac.bake.model as hm

sys.path.insert(0, str(Path(__file__).parent))
from bake_pairs import weighted_nrmse  # noqa: E402
from bake_source_aniso import cell  # noqa: E402

P = {"q": 0.0, "core": hs.CORE, "box": True, "kbox": 1.0}

def prof(t, b, g):
    """1-D box of half-width b (variance b^2/3) convolved with exp(-t^2/g)/sqrt(pi g) (variance g/2)."""
    sg = jnp.sqrt(g)
    bs = jnp.maximum(b, 1e-7)
    box = (erf((bs - t) / sg) + erf((bs + t) / sg)) / (4 * bs)
    gau = jnp.exp(-t * t / g) / jnp.sqrt(jnp.pi * g)
    return jnp.where(b > 1e-3 * sg, box, gau)

def source_terms(srcs, n, v, roughness):
    n = jnp.asarray(n, jnp.float32); v = jnp.asarray(v, jnp.float32)
    rho = jnp.broadcast_to(jnp.asarray(roughness, jnp.float32), n.shape[:1])
    out = jnp.zeros(n.shape[:1] + (3, 3), jnp.float32)
    t, b = _frame(n); wo = _local(v, t, b, n)
    a2 = rho ** 4
    x = jnp.where(wo[2] > 0, wo[2], 1.0)
    r = 2 * x[:, None] * n - v
    u = jnp.cross(n, v)
    ut2 = jnp.maximum(wo[0] * wo[0] + wo[1] * wo[1], 1e-12)
    lam = 0.5 * (jnp.sqrt(1 + a2 * (1 - x * x) / (x * x)) - 1)
    m5 = (1 - x) ** 5
    for s in srcs:
        ell = jnp.asarray(s.direction, jnp.float32)
        wi = _local(jnp.broadcast_to(ell, n.shape), t, b, n)
        above = (wi[2] > 0) & (wo[2] > 0)
        wi = tuple(jnp.where(above, c, 0.0 if i < 2 else 1.0) for i, c in enumerate(wi))
        wo_ = (wo[0], wo[1], x)
        d, la, lb = gltf_lobes_at(rho, wi, wo_)
        h = [a + c for a, c in zip(wi, wo_)]
        hn2 = h[0] * h[0] + h[1] * h[1] + h[2] * h[2]
        hy2 = (h[1] * wo[0] - h[0] * wo[1]) ** 2 / ut2 / hn2
        sin2 = (h[0] * h[0] + h[1] * h[1]) / hn2
        base = (hs.SPREAD * s.radius) ** 2 / 4
        k = hs.widened_ratio(a2, base, base / (x * x), jnp.maximum(h[2], 0.0) ** 2 / hn2, jnp.maximum(sin2 - hy2, 0.0), hy2)
        S = base / x
        w = S / (a2 + S)
        axes, _ = s.core_frame()
        lengths = np.linalg.norm(np.asarray(s.axes, np.float64).reshape(-1, 3), axis=1) if s.axes else np.full(2, s.radius)
        var = lengths ** 2 / 2  # variance per axis (rad^2)
        e1, e2 = (jnp.asarray(a, jnp.float32) for a in axes)
        u1, u2 = u @ e1, u @ e2
        e = r - ell
        t1, t2, t3 = e @ e1, e @ e2, e @ ell
        if P["box"]:
            q = P["q"]
            vb = np.maximum(P["kbox"] ** 2 * var - q, 0.0)  # box variance
            bw = np.sqrt(3 * vb)
            gq = 2 * np.minimum(q, P["kbox"] ** 2 * var)  # gaussian part in G convention
            g1 = gq[0] + 4 * a2 * (1 - u1 * u1)
            g2 = gq[1] + 4 * a2 * (1 - u2 * u2)
            blob = prof(t1, float(bw[0]), g1) * prof(t2, float(bw[1]), g2) * jnp.exp(-t3 * t3 / jnp.minimum(g1, g2)) / (1 + 2 * lam)
        else:
            widths = (P["core"] * lengths) ** 2
            g11, g12, g22 = hs.core_widths(widths.astype(np.float32), u1, u2, a2)
            det = g11 * g22 - g12 * g12
            qq = (g22 * t1 * t1 - 2 * g12 * t1 * t2 + g11 * t2 * t2) / det + t3 * t3 / jnp.minimum(g11, g22)
            blob = jnp.exp(-qq) / (jnp.pi * jnp.sqrt(det)) / (1 + 2 * lam)
        tail = jnp.stack([d, la * k, lb * k], 1) * wi[2][:, None]
        core = jnp.stack([jnp.zeros_like(x), (1 - m5) * blob, m5 * blob], 1)
        lobes = jnp.where(above[:, None], (1 - w)[:, None] * tail + w[:, None] * core, 0.0)
        lobes = lobes.at[:, 0].set(jnp.where(above, tail[:, 0], 0.0))
        out = out + lobes[:, :, None] * jnp.asarray(s.power, jnp.float32)[None, None, :]
    return out


def main():
    pairs, name, band, bake = Path(sys.argv[1]), sys.argv[2], int(sys.argv[3]), sys.argv[4]
    z = cell(pairs, name, band)
    b = hf.load(bake)
    a = np.asarray(b.evaluate(z["n"], z["v"], z["c"], z["m"], z["rho"]), np.float64)
    print(json.dumps({"cfg": "built", "cell": f"{name}-{band}", "bake": bake, "nrmse": round(weighted_nrmse(a, z["L"], z["w"]), 4)}))
    built = hm.source_terms
    for cfg in sys.argv[5:]:
        kind, *ks = cfg.split(":")
        if kind == "core":  # the CORE of every later cfg (the built Gaussian's and the rule's total variance)
            hs.CORE = float(ks[0])
            continue
        if kind == "rule":
            hm.source_terms = built
            pixel = float(ks[1]) if len(ks) > 1 else np.pi / 128
            srcs = tuple(s._replace(box=hs.box_widths(s._replace(box=()), pixel, float(ks[0]))) for s in b.sources)
            bb = dataclasses.replace(b, sources=srcs)
            a = np.asarray(bb.evaluate(z["n"], z["v"], z["c"], z["m"], z["rho"]), np.float64)
            boxed = sum(1 for s in srcs if s.box)
            print(json.dumps({"cfg": cfg, "cell": f"{name}-{band}", "boxed": f"{boxed}/{len(srcs)}",
                              "nrmse": round(weighted_nrmse(a, z["L"], z["w"]), 4)}), flush=True)
            continue
        hm.source_terms = source_terms
        if kind == "box":
            P.update(box=True, q=float(ks[0]), kbox=float(ks[1]))
        else:
            P.update(box=False, core=float(ks[0]))
        a = np.asarray(b.evaluate(z["n"], z["v"], z["c"], z["m"], z["rho"]), np.float64)
        print(json.dumps({"cfg": cfg, "cell": f"{name}-{band}", "nrmse": round(weighted_nrmse(a, z["L"], z["w"]), 4)}), flush=True)


if __name__ == "__main__":
    main()
