"""The per-source tile as it would be built (one product per layer): its error on a saved converged cell.

Per light of the base bake (its entries merged within 1 degree, as benchmarks/bake_source_tile.py), an N x N
gnomonic tile (texel ``(pi / 2) / face`` at its centre) about the light's direction l holds, for each layer j below
``--below``, the lights **with every light left in** (the ``source_size`` x 4 = 256 lights of the bake's sharp
block, not the lights the analytic sources were taken from) filtered by the layer's P_1 kernel of the sharp block's
convention (the kernels weighted by the layer's own albedos, normalized by their discrete mass: Karis' normalized
prefilter, :func:`homofac.bake.filter.normalized`), i.e. the layer's normalized prefiltered radiance Lbar_j. Inside
the nearest light's tile (every layer of the pair's u-blend below ``--below``), the specular integrals are

    I_A = (sum_j hat(u - j) Lbar_j(r)) (sum_j hat(u - j) A_j(n.v)),   I_B likewise with B_j

(A_j, B_j the layer's lobe albedos, :func:`homofac.bake.kernels.albedos`: what the block's P_1 with its albedo
weights reads), Lbar_j read bilinearly from the tile's texels at r's gnomonic coordinates ("tile") or computed at r
itself ("exact at r", no tile texels), and no analytic source's I_A, I_B (the tile holds the lights); I_d is the
base bake's. Outside: the base bake. Prints the cell's nrmse per variant and the split by angle.

    PYTHONPATH=src python benchmarks/bake_source_tile_p1.py ENV:PAIRS.npz:BASE_DIR [...] [--tiles 32] [--cap 40]

docs/notes/bake.md, "Below 0.15, twenty-third session".
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import homofac as hf
from homofac.bake import kernels as kn
from homofac.bake.build import _path, source_size, texel_radius
from homofac.bake.filter import normalized, prefilter
from homofac.light import Environment, load_environment
from homofac.light.integrals import material_radiance

sys.path.insert(0, str(Path(__file__).parent))
from bake_source_tile import by_angle, light_directions, nrmse  # noqa: E402


def frame(ell: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tangent axes (e_1, e_2) of the tiles' gnomonic planes (bake_source_tile.tile_coordinates' frame)."""
    up = np.where(np.abs(ell[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    e1 = np.cross(up, ell)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(ell, e1)


def lbar(env: Environment, rows: np.ndarray, dirs: np.ndarray, centre: np.ndarray, cap: float):
    """(N, J, 3): the normalized prefilter of ``rows`` (J, G) at ``dirs`` with the lights within ``cap`` rad of
    ``centre`` (the lobes below 0.15 hold < 0.5 % of their mass beyond the cap's margin)."""
    d = np.asarray(env.directions, np.float64)
    sel = d @ centre > np.cos(cap)
    sub = Environment(env.directions[sel], env.radiance[sel], env.solid_angle[sel], env.info)
    values, den = prefilter(rows, dirs, sub)
    return normalized(values, den, np.ones(len(rows)))  # the weighted mean radiance (a constant one reads itself)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("cells", nargs="+", help="ENV:PAIRS.npz:BASE_DIR")
    p.add_argument("--tiles", type=int, nargs="*", default=[32])
    p.add_argument("--face", type=int, default=128)
    p.add_argument("--below", type=float, default=0.15)
    p.add_argument("--offset", type=float, default=0.0,
                   help="the grid shifted by this many texels (0: the light at a texel corner, 0.5: at a texel centre)")
    p.add_argument("--cap", type=float, default=40.0, help="degrees of lights about each light read by its tile")
    args = p.parse_args(argv)
    pitch = (np.pi / 2) / args.face
    for cell in args.cells:
        env_name, pairs, base_dir = cell.split(":")
        z = np.load(pairs)
        n, v, c, m, rho, w, ref = (np.asarray(z[k]) for k in ("n", "v", "c", "m", "rho", "w", "reference"))
        base = hf.load(base_dir)
        lights = load_environment(_path(env_name), 4 * source_size(env_name))
        layers = [j for j, r in enumerate(base.roughness) if r < args.below]
        x = kn.nv_centres(base.plan.nv_size)
        rows = []
        for j in layers:  # each layer's P_1 kernel in the sharp block's convention: its albedo-weighted kernels
            exact = kn.albedos(base.roughness[j], x)
            k_s, _ = kn.lobe_kernels(base.roughness[j], x)
            k = kn.smooth(kn.calibrate(k_s, exact).reshape(2 * len(x), -1), texel_radius(lights))
            mj = np.concatenate([exact[0], exact[1]])
            rows.append((mj / np.linalg.norm(mj)) @ k)
        rows = np.stack(rows)
        t_base = np.asarray(base.terms(n, v, rho), np.float64)
        u = np.asarray(base.layer_coordinate(rho))
        blended = np.ceil(u) <= layers[-1]
        hats = np.maximum(0.0, 1.0 - np.abs(u[:, None] - np.arange(len(layers))[None]))  # (N, J)
        xv = np.clip(np.sum(n * v, 1), 0.0, 1.0)
        alb = np.stack([kn.albedos(base.roughness[j], np.maximum(xv, 1e-4)) for j in layers], 0)  # (J, 2, N)
        A, B = (np.sum(hats * alb[:, i].T, 1) for i in (0, 1))
        r = 2 * np.sum(n * v, 1)[:, None] * n - v
        ell, _ = light_directions(base)
        e1, e2 = frame(ell)
        near = np.argmax(r @ ell.T, 1)
        rl = np.maximum(np.sum(r * ell[near], 1), 1e-6)
        g = np.stack([np.sum(r * e1[near], 1) / rl, np.sum(r * e2[near], 1) / rl], 1)
        ang = np.degrees(np.arccos(np.clip(np.sum(r * ell[near], 1), -1, 1)))
        den = float(np.sum(w * np.sum(ref * ref, 1)))

        def radiance(t):
            return np.asarray(material_radiance(jnp.asarray(t, jnp.float32), jnp.asarray(c, jnp.float32),
                                                jnp.asarray(m, jnp.float32)), np.float64)

        def inside_terms(lb, inside):
            t = t_base.copy()
            t[inside, 1] = lb[inside] * A[inside, None]
            t[inside, 2] = lb[inside] * B[inside, None]
            t[inside, 0] = t_base[inside, 0]
            return t

        out = {"base": radiance(t_base)}
        print(f"{env_name} ({len(w)} pairs, {len(ell)} lights, tile layers {len(layers)}): base {nrmse(out['base'], ref, w):.4f}", flush=True)
        for N in args.tiles:
            inside = blended & np.all(np.abs(g) < N * pitch / 2, 1) & (np.sum(r * ell[near], 1) > 0)
            exact = np.zeros((len(w), 3))
            grid = np.zeros((len(w), 3))
            cap = np.radians(args.cap)
            ticks = (np.arange(N) + 0.5 - N / 2 - args.offset) * pitch  # texel centres' gnomonic coordinates
            for i, l in enumerate(ell):
                mine = np.flatnonzero(inside & (near == i))
                if not len(mine):
                    continue
                lb = lbar(lights, rows, r[mine], l, cap)  # (M, J, 3)
                exact[mine] = np.sum(hats[mine, :, None] * lb, 1)
                gu, gv = np.meshgrid(ticks, ticks, indexing="ij")
                tdirs = l[None] + gu.reshape(-1, 1) * e1[i][None] + gv.reshape(-1, 1) * e2[i][None]
                tdirs /= np.linalg.norm(tdirs, axis=1, keepdims=True)
                tile = lbar(lights, rows, tdirs, l, cap).reshape(N, N, len(layers), 3)
                # bilinear read at the pairs' gnomonic coordinates (clamped to the texel centres, as a GPU's clamp)
                fu = np.clip(g[mine, 0] / pitch + N / 2 - 0.5 + args.offset, 0, N - 1)
                fv = np.clip(g[mine, 1] / pitch + N / 2 - 0.5 + args.offset, 0, N - 1)
                i0, j0 = np.minimum(np.floor(fu).astype(int), N - 2), np.minimum(np.floor(fv).astype(int), N - 2)
                a, b = (fu - i0)[:, None, None], (fv - j0)[:, None, None]
                val = ((1 - a) * (1 - b) * tile[i0, j0] + a * (1 - b) * tile[i0 + 1, j0]
                       + (1 - a) * b * tile[i0, j0 + 1] + a * b * tile[i0 + 1, j0 + 1])
                grid[mine] = np.sum(hats[mine, :, None] * val, 1)
            out[f"exact {N}"] = radiance(inside_terms(exact, inside))
            out[f"tile {N}"] = radiance(inside_terms(grid, inside))
            print(f"  N {N}: exact at r {nrmse(out[f'exact {N}'], ref, w):.4f} | tile {nrmse(out[f'tile {N}'], ref, w):.4f} "
                  f"| inside {inside.mean():.3f} of pairs", flush=True)
        by_angle(out, ang, ref, w, den)


if __name__ == "__main__":
    main()
