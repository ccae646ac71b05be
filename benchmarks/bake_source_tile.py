"""The per-source tile's reach, measured on a saved converged cell before it is built (issue 42, lever 1).

A tile of N x N texels at a finer face's angular density about each light, read at the mirror direction r of the
nearest light (one fetch), is modelled as: inside the nearest light's tile, the sharp layers' maps of a bake at the
finer block (``FINE``, e.g. ``--block-size 128``); outside, the maps of the bake as shipped (``BASE``); the analytic
sources are the base bake's everywhere (the two bakes take the same lights from the same 256 lights). The tile is the
square |r.e_1 / r.l|, |r.e_2 / r.l| < N pitch / 2 in the gnomonic plane of the light's direction l (pitch: the finer
face's texel angle at a face centre, (pi / 2) / face), a shader's projection of r into a source-centred tile. Only
the layers below ``--below`` (their u-blend) take the fine maps: a pair whose roughness blends with a layer at or
above it reads the base. A fifth field ``SOURCE_DIR`` (a bake at the finer block without analytic sources,
``--no-analytic-source``) adds rows whose tile holds the lights themselves: inside it, that bake's maps (the lights'
own texels filtered by each layer's lobe) in place of the fine maps and the analytic sources (lever 3 as a tile).
Prints each cell's nrmse (pairs weighted as bake_accuracy.py) per N, the share inside the
tiles, the split by angle from the nearest source, and the tiles' bytes (lights x layers x N^2 x RGB half).

    PYTHONPATH=src python benchmarks/bake_source_tile.py ENV:PAIRS.npz:BASE_DIR:FINE_DIR [...] [--tiles 16 32 64]

docs/notes/bake.md, "Below 0.15, twenty-third session".
"""

from __future__ import annotations

import argparse

import jax.numpy as jnp
import numpy as np

import homofac as hf
from homofac.light.integrals import material_radiance

ANGLES = (0, 1, 2, 3, 5, 8, 20, 180)  # degrees


def light_directions(bake) -> tuple[np.ndarray, np.ndarray]:
    """One direction per light, the first entry of each core-and-halo pair (entries within 1 degree merged), and
    that entry's minor semi-axis (rad)."""
    out: list[np.ndarray] = []
    minor: list[float] = []
    for s in bake.sources:
        d = np.asarray(s.direction, np.float64)
        if not any(float(d @ o) > np.cos(np.radians(1.0)) for o in out):
            out.append(d)
            a = np.linalg.norm(np.asarray(s.axes, np.float64).reshape(-1, 3), axis=1)
            minor.append(float(a.min()) if len(a) else float(s.radius))
    return np.array(out).reshape(-1, 3), np.array(minor)


def tile_coordinates(r: np.ndarray, ell: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pair, the nearest light's index and r's gnomonic coordinates (N, 2) about it (tan of the angle per axis)."""
    cos = r @ ell.T
    near = np.argmax(cos, 1)
    l = ell[near]
    up = np.where(np.abs(l[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    e1 = np.cross(up, l)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(l, e1)
    rl = np.maximum(np.sum(r * l, 1), 1e-6)
    return near, np.stack([np.sum(r * e1, 1) / rl, np.sum(r * e2, 1) / rl], 1)


def nrmse(a, ref, w) -> float:
    return float(np.sqrt(np.sum(w[:, None] * (a - ref) ** 2) / np.sum(w[:, None] * ref ** 2)))


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("cells", nargs="+", help="ENV:PAIRS.npz:BASE_DIR:FINE_DIR[:SOURCE_DIR]")
    p.add_argument("--tiles", type=int, nargs="*", default=[16, 32, 64], help="tile sides N in fine texels")
    p.add_argument("--face", type=int, default=128, help="the fine maps' face (the tile's density)")
    p.add_argument("--resolved", type=float, nargs="*", default=[],
                   help="with SOURCE_DIR: also tiles holding only the lights whose minor semi-axis is at least this many "
                        "tile texels (the others' pairs read the base)")
    p.add_argument("--below", type=float, default=0.15, help="the tile holds the layers below this roughness")
    args = p.parse_args(argv)
    pitch = (np.pi / 2) / args.face
    for cell in args.cells:
        env, pairs, base_dir, fine_dir, *own = cell.split(":")
        z = np.load(pairs)
        n, v, c, m, rho, w, ref = (np.asarray(z[k]) for k in ("n", "v", "c", "m", "rho", "w", "reference"))
        base, fine = hf.load(base_dir), hf.load(fine_dir)
        t_base = np.asarray(base.terms(n, v, rho))
        t_fine = np.asarray(fine.terms(n, v, rho))
        u = np.asarray(base.layer_coordinate(rho))
        top = max(j for j, r in enumerate(base.roughness) if r < args.below)
        blended = np.ceil(u) <= top  # every layer of the pair's blend is below --below
        r = 2 * np.sum(n * v, 1)[:, None] * n - v
        ell, minor = light_directions(base)
        near, g = tile_coordinates(r, ell)
        ang = np.degrees(np.arccos(np.clip(np.sum(r * ell[near], 1), -1, 1)))
        den = float(np.sum(w * np.sum(ref * ref, 1)))
        layers = top + 1

        def radiance(t):
            return np.asarray(material_radiance(jnp.asarray(t, jnp.float32), jnp.asarray(c, jnp.float32),
                                                jnp.asarray(m, jnp.float32)), np.float64)

        L_base, L_fine = radiance(t_base), radiance(t_fine)
        L_own = radiance(np.asarray(hf.load(own[0]).terms(n, v, rho))) if own else None
        print(f"{env} ({len(w)} pairs, {len(ell)} lights, layers below {args.below}: {layers}): base {nrmse(L_base, ref, w):.4f}"
              f" | fine everywhere {nrmse(np.where(blended[:, None], L_fine, L_base), ref, w):.4f}", flush=True)
        rows = {"base": L_base}
        for N in args.tiles:
            inside = blended & np.all(np.abs(g) < N * pitch / 2, 1) & (np.sum(r * ell[near], 1) > 0)
            L = np.where(inside[:, None], L_fine, L_base)
            rows[f"tile {N}"] = L
            if L_own is not None:
                rows[f"own {N}"] = np.where(inside[:, None], L_own, L_base)
                print(f"  tile {N} holding the lights: {nrmse(rows[f'own {N}'], ref, w):.4f}")
                for t in args.resolved:
                    keep = inside & (minor[near] >= t * pitch)
                    rows[f"res{t:g} {N}"] = np.where(keep[:, None], L_own, L_base)
                    print(f"  tile {N} holding the lights resolved at {t:g} texel ({int(np.sum(minor >= t * pitch))} of "
                          f"{len(minor)}): {nrmse(rows[f'res{t:g} {N}'], ref, w):.4f}")
            kb = len(ell) * layers * N * N * 3 * 2 / 1e3
            print(f"  tile {N} ({N * pitch / 2 * 180 / np.pi:.1f} deg half-side, {kb:.0f} KB): {nrmse(L, ref, w):.4f}, "
                  f"inside {inside.mean():.3f} of pairs, {float(np.sum(w[inside]) / np.sum(w)):.3f} of weight", flush=True)
        by_angle(rows, ang, ref, w, den, share=True)


def by_angle(rows: dict, ang, ref, w, den: float, share: bool = False) -> None:
    """Print each row's weighted squared error (a share of the cell's nrmse^2 denominator ``den``) per band of
    :data:`ANGLES` (degrees from the nearest light), and the reference's own share of L^2 if ``share``."""
    for lo, hi in zip(ANGLES[:-1], ANGLES[1:]):
        sel = (ang >= lo) & (ang < hi)
        parts = " ".join(f"{k} {float(np.sum(w[sel] * np.sum((L - ref)[sel] ** 2, 1)) / den):.4f}" for k, L in rows.items())
        l2 = f"L2 {float(np.sum((w * np.sum(ref * ref, 1))[sel]) / den):.3f} | " if share else ""
        print(f"  {lo}-{hi} deg: {l2}err^2 {parts}")


if __name__ == "__main__":
    main()
