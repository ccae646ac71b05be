"""The face gauge's read against the 5-channel tensor's on a real balanced bake (issue 42): per pixel, the
relative difference of Y(I_A), Y(I_B) over 20 000 random pairs at roughness 0.45-1, split by whether the lobe
axis lies on the half-texel strip along a face edge of the layer's map (pairs where the term is > 5 % of its
largest value). The bake is fitted once with the 5-channel tensors kept; both reads are
benchmarks/bake_memory.py's ``terms`` (the bake's own read with the maps given).

    PYTHONPATH=src python benchmarks/bake_gauge_seam.py [ENVIRONMENT]      (about 1 minute)
"""
import sys
from pathlib import Path
import numpy as np, jax.numpy as jnp
sys.path.insert(0, str(Path(__file__).parent))
import bake_memory as bm
import homofac as hf
from homofac.bake import build
from homofac.bake.gauge import face_gauge


def main():
    orig = build.stored
    build.stored = lambda b: b  # keep the 5-channel tensors
    b = hf.bake(sys.argv[1] if len(sys.argv) > 1 else "studio", preset="balanced")
    build.stored = orig
    rng = np.random.default_rng(0)
    N = 20000
    n = rng.normal(size=(N, 3)); n /= np.linalg.norm(n, axis=1, keepdims=True)
    v = rng.normal(size=(N, 3)); v /= np.linalg.norm(v, axis=1, keepdims=True)
    v = np.where((np.sum(n * v, 1) < 0.05)[:, None], -v, v)
    P1 = [np.asarray(p[:, :, 0]) for p in b.P]
    P2 = [np.asarray(p[:, :, 1]) if np.any(p[:, :, 1]) else None for p in b.P]
    H5 = list(b.H)
    Hg = [None if h is None else face_gauge(h, h.shape[0]) for h in H5]
    for rho in (0.45, 0.6, 0.8, 1.0):
        r = np.full(N, rho)
        t5 = np.asarray(bm.terms(b, n, v, r, P1, P2, H5, False))
        tg = np.asarray(bm.terms(b, n, v, r, P1, P2, Hg, True))
        x = np.sum(n * v, 1); refl = 2 * x[:, None] * n - v
        u = float(b.layer_coordinate(rho)); j = min(int(u), 10)
        sh = b.shift[j]; a = (1 - sh) * refl + sh * n; a /= np.linalg.norm(a, axis=1, keepdims=True)
        s = b.P[j].shape[0]
        ab = np.sort(np.abs(a), 1)
        # distance to the face edge in texels: (1 - second/major) * s / 2
        edge = (1 - ab[:, 1] / ab[:, 2]) * s / 2 < 0.5
        for k, name in ((1, "I_A"), (2, "I_B")):
            lum = lambda q: q @ np.array([0.2126, 0.7152, 0.0722])
            d = np.abs(lum(tg[:, k]) - lum(t5[:, k])) / np.maximum(lum(t5[:, k]), 1e-12)
            big = lum(t5[:, k]) > 0.05 * lum(t5[:, k]).max()
            print(f"rho {rho} layer {j} face {s} {name}: edge strip {edge.mean():.3f} of pairs; rel diff max/median inside {np.max(d[~edge & big]):.4f}/{np.median(d[~edge & big]):.5f}, "
                  f"edge {np.max(d[edge & big]) if np.any(edge & big) else 0:.4f}/{np.median(d[edge & big]) if np.any(edge & big) else 0:.5f}", flush=True)


if __name__ == "__main__":
    main()
