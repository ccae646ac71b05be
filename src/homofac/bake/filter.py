"""Isotropic filtering of an environment by tabulated kernels (the matmul form of every bake texel).

``F_j(d) = sum_k L_k dw_k kappa_j(q(d.l_k))`` with q = sqrt((1 - d.l) / 2) and kappa_j tabulated uniformly
in sqrt(q) (:mod:`.kernels`): cosines as one (B, 3) @ (3, L) matmul per chunk, the J tables read by linear
interpolation at a shared index, the sums as (B, L) @ (L, 3) matmuls, or, for many tables, the lights' power
binned at the table nodes and the sums as (J, G) @ (G, 3) matmuls; directions go through ``lax.map`` in
chunks, so memory stays B x L per table, never directions x lights x 3.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..compiling import jit
from ..light import Environment
from ..light.cubemap import cube_nearest
from ..param import mappers
from . import kernels as kn

#: Directions per lax.map step.
CHUNK = 128

#: :func:`prefilter` filters more than this many chunks of directions in calls of this many (the last padded):
#: the program then does not depend on the direction count (a bake's first process compiled one per count).
BLOCK_CHUNKS = 3


#: The kernel tables of one filter call are padded to a multiple of this (zero tables, never read): calls with
#: 2 to 40 tables run one compiled program per direction and light count.
TABLES = 40


#: A filter call with more tables than this reads them binned (:func:`_binned`), with at most this many table
#: by table (:func:`_gathered`): binning a light costs about as much as reading 3-6 tables (docs/notes/bake.md,
#: "Bake time, nineteenth session"). A bake's data calls have 9-40 tables (binned), its maps K + 1 = 2-6 (the
#: sharp block's and fast's 2 gathered), its irradiance maps D = 1-2 (gathered).
GATHER_TABLES = 2

#: Directions per scatter-add in :func:`_binned` (their bins, BIN_ROWS x G x 4 floats, stay in the cache:
#: 2.5x faster than 128 at 6144 lights).
BIN_ROWS = 16


def _gathered(tables, count, i0, f, power):
    """``sum_l ((1 - f) K_j[i0] + f K_j[i0 + 1])[b, l] power[l]`` for the first ``count`` tables j (a traced
    count; the rest 0): (B, J, 4). A loop over the tables: the program's size (and XLA's compile time) does not
    grow with J, one (B, L) gather at a time is live, and a call with fewer tables runs the same program
    (docs/notes/bake.md, "The first bake of a process")."""
    def one(j, out):
        t = jax.lax.dynamic_index_in_dim(tables, j, keepdims=False)
        return out.at[:, j].set(((1.0 - f) * t[i0] + f * t[i0 + 1]) @ power)

    return jax.lax.fori_loop(0, count, one, jnp.zeros((i0.shape[0], tables.shape[0], power.shape[1]), power.dtype))


def _binned(tables, i0, f, power):
    """The sums of :func:`_gathered` for every table as ``sum_g K_j[g] H[b, g]``, ``H[b, g] = sum_l ((1 - f)
    [g = i0] + f [g = i0 + 1])[b, l] power[l]``: the lights' power binned at the table nodes by the same
    linear interpolation weights (one scatter-add per :data:`BIN_ROWS` directions), then one (J, G) @ (G, 4)
    matmul per direction. The same terms summed in another order; its cost is B L once, not B L per table
    (the padding tables are zeros and read 0)."""
    rows = BIN_ROWS if i0.shape[0] % BIN_ROWS == 0 else i0.shape[0]

    def one(args):
        i, w = args
        b = jnp.broadcast_to(jnp.arange(rows)[:, None], i.shape)
        h = jnp.zeros((rows, tables.shape[1], power.shape[1]), power.dtype)
        return h.at[b, i].add((1.0 - w)[..., None] * power[None]).at[b, i + 1].add(w[..., None] * power[None])

    h = jax.lax.map(one, (i0.reshape(-1, rows, i0.shape[1]), f.reshape(-1, rows, f.shape[1])))
    return jnp.einsum("jg,bgc->bjc", tables, h.reshape(i0.shape[0], tables.shape[1], power.shape[1]))


def _read(tables, count, i0, f, power, binned: bool):
    """(B, J, 4): the first ``count`` tables read at the lights' interpolation indices ``i0`` and weights ``f``
    (B, L), times their power (L, 4) and summed: :func:`_binned` if ``binned`` else :func:`_gathered`."""
    return _binned(tables, i0, f, power) if binned else _gathered(tables, count, i0, f, power)


def _padded(tables: np.ndarray) -> tuple[np.ndarray, np.int32]:
    """The tables (J, G) padded with zero rows to a multiple of :data:`TABLES`, and J."""
    j = tables.shape[0]
    pad = (-j) % TABLES
    return np.concatenate([np.asarray(tables, np.float32), np.zeros((pad, tables.shape[1]), np.float32)]), np.int32(j)


@jit(kind="filter", filter=True)
def _filter(tables, count, dirs, light_dirs, power, chunk: int, binned: bool):
    j_count, g = tables.shape
    n = dirs.shape[0]
    pad = (-n) % chunk
    d = jnp.concatenate([dirs, jnp.broadcast_to(dirs[:1], (pad, 3))]) if pad else dirs

    def one(block):
        c = block @ light_dirs.T  # (B, L)
        pos = jnp.sqrt(jnp.sqrt(jnp.clip((1.0 - c) * 0.5, 0.0, 1.0))) * (g - 1)
        i0 = jnp.minimum(jnp.floor(pos).astype(jnp.int32), g - 2)
        f = pos - i0
        return _read(tables, count, i0, f, power, binned)  # (B, J, 4)

    out = jax.lax.map(one, d.reshape(-1, chunk, 3))
    return out.reshape(-1, j_count, power.shape[1])[:n]


def _power(env: Environment) -> np.ndarray:
    """``(L, 4)`` float32: the lights' power L_k dw_k (RGB) and solid angle dw_k (computed in numpy: eager JAX
    operations each compile a program on a process's first bake)."""
    sa = np.asarray(env.solid_angle, np.float32)
    return np.concatenate([np.asarray(env.radiance, np.float32) * sa[:, None], sa[:, None]], axis=1)


def prefilter(tables: np.ndarray, dirs: np.ndarray, env: Environment, chunk: int = CHUNK) -> tuple[np.ndarray, np.ndarray]:
    """The J kernels ``tables`` (J, G) applied to ``env`` at directions ``dirs`` (N, 3): ``(N, J, 3)``, and the
    discrete masses ``sum_k dw_k kappa_j`` (N, J) of the same sums (the quadrature check of :func:`normalized`)."""
    padded, j = _padded(tables)
    d = np.asarray(dirs, np.float32)
    block = BLOCK_CHUNKS * chunk
    if len(d) > block:  # fixed blocks of directions: one program per light count and table count, whatever N
        d = np.concatenate([d, np.broadcast_to(d[:1], ((-len(d)) % block, 3))])
    else:
        chunk = int(min(chunk, max(1, len(d))))
    lights, power = np.asarray(env.directions, np.float32), _power(env)
    out = np.concatenate([np.asarray(_filter(padded, j, d[i:i + block], lights, power, chunk, bool(j > GATHER_TABLES)), np.float64)
                          for i in range(0, len(d), block)])[:len(dirs), :len(tables)]
    return out[..., :3], out[..., 3]


def normalized(values: np.ndarray, discrete: np.ndarray, exact) -> np.ndarray:
    """Filtered values scaled by ``exact mass / discrete mass`` (Karis' normalized prefilter): the texel sum of
    a kernel a few light texels wide then reads a constant environment exactly wherever its axis falls
    between texel centres. ``discrete`` (N,) or (N, J), ``exact`` scalar or (J,)."""
    d = np.asarray(discrete, np.float64)
    e = np.broadcast_to(np.asarray(exact, np.float64), d.shape[-1:] if d.ndim > 1 else ())
    scale = np.where(np.abs(d) > 1e-30, e / np.where(np.abs(d) > 1e-30, d, 1.0), 0.0)
    return values * (scale[..., None] if d.ndim == values.ndim - 1 else scale[:, None, None])




@jit(kind="filter", filter=True)
def _filter_tiles(tables, count, tiles, light_dirs, power, groups, centres, slots: int, binned: bool):
    """:func:`_filter` over tiles of nearby directions (T, B, 3), each with the lights of the ``slots`` light
    groups (:func:`_groups`: ``groups`` (G, M) light indices, ``centres`` (G, 3)) nearest its axis."""
    j_count, g = tables.shape

    def one(tile):
        axis = jnp.sum(tile, axis=0)
        axis = axis / jnp.linalg.norm(axis)
        _, near = jax.lax.top_k(centres @ axis, slots)
        idx = groups[near].reshape(-1)
        ld, pw = light_dirs[idx], power[idx]
        c = tile @ ld.T  # (B, slots M)
        pos = jnp.sqrt(jnp.sqrt(jnp.clip((1.0 - c) * 0.5, 0.0, 1.0))) * (g - 1)
        i0 = jnp.minimum(jnp.floor(pos).astype(jnp.int32), g - 2)
        f = pos - i0
        return _read(tables, count, i0, f, pw, binned)

    return jax.lax.map(one, tiles)


#: Lights per group of :func:`_groups` (about: a cube's lights binned by a face 4x coarser hold 16 each).
GROUP = 16

#: Largest face of the bins of :func:`_groups` (6144 bins: the top_k per tile stays ~0.3 ms; the sharp block's
#: 256^2 x 6 lights then bin 64 to a group).
GROUP_FACE = 32


def _groups(light_dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The lights binned by the texels of a cube of face ~sqrt(L / (6 GROUP)) (each bin padded with the index
    L, a zero-power light appended by the caller): ``(groups (G, M) int32, centres (G, 3) float32, radius)``,
    ``radius`` the largest angle from a bin's centre (its normalized mean direction) to one of its lights. A
    light within angle c of an axis is in a bin whose centre is within c + radius of it."""
    count = len(light_dirs)
    face = min(GROUP_FACE, max(1, int(round(np.sqrt(count / (6.0 * GROUP))))))
    d = np.asarray(light_dirs, np.float64)
    key = cube_nearest(face, d)
    order = np.argsort(key, kind="stable")
    bins, start, sizes = np.unique(key[order], return_index=True, return_counts=True)
    m = int(sizes.max())
    slot = np.arange(count) - np.repeat(start, sizes)
    groups = np.full((len(bins), m), count, np.int64)
    groups[np.repeat(np.arange(len(bins)), sizes), slot] = order
    sums = np.zeros((len(bins), 3))
    np.add.at(sums, np.repeat(np.arange(len(bins)), sizes), d[order])
    centres = sums / np.maximum(np.linalg.norm(sums, axis=1, keepdims=True), 1e-300)
    cos = np.einsum("gi,gi->g", centres[np.repeat(np.arange(len(bins)), sizes)], d[order])
    radius = float(np.arccos(np.clip(cos.min(), -1.0, 1.0))) + 1e-6
    return groups.astype(np.int32), centres.astype(np.float32), radius


def prefilter_cube(tables: np.ndarray, size: int, env: Environment, support: float, tile: int = 8):
    """:func:`prefilter` at every texel centre of a cube-mapper texture of face size ``size`` (rows of the
    (size, 6 size) layout), skipping the lights farther than ``support`` (radians) from every texel of a
    tile x tile block: each block reads only the lights of the groups (:func:`_groups`) within its own radius
    + ``support`` + a group's radius of its axis (``lax.top_k`` on the groups' centres, a static count), so
    sharp layers cost a few hundred lights per texel instead of all of them. Falls back to :func:`prefilter`
    when the cone holds most lights."""
    dirs = np.asarray(mappers.texel_directions("cube", size), np.float64)  # (S, 6S, 3)
    light_dirs = np.asarray(env.directions, np.float32)
    count = len(light_dirs)
    tile = min(tile, size)
    radius = tile * (np.pi / 2) / size  # a block's half-diagonal is below this (texels subtend <= (pi/2)/S)
    groups, centres, group_radius = _groups(light_dirs)
    cone = min(np.pi, support + radius + group_radius)
    slots = int(min(len(groups), 16 * np.ceil((1.3 * len(groups) * (1.0 - np.cos(cone)) / 2.0 + 8) / 16)))  # steps of 16: fewer compilations
    if slots * groups.shape[1] > count // 3:
        return prefilter(tables, dirs.reshape(-1, 3), env)
    blocks = dirs.reshape(size // tile, tile, 6 * size // tile, tile, 3).transpose(0, 2, 1, 3, 4).reshape(-1, tile * tile, 3)
    padded, j = _padded(tables)
    power = _power(env)
    out = np.asarray(_filter_tiles(padded, j, np.asarray(blocks, np.float32),
                                   np.concatenate([light_dirs, light_dirs[:1]]),
                                   np.concatenate([power, np.zeros((1, power.shape[1]), power.dtype)]),
                                   groups, centres, slots, bool(j > GATHER_TABLES)), np.float64)
    out = out.reshape(size // tile, 6 * size // tile, tile, tile, len(padded), 4).transpose(0, 2, 1, 3, 4, 5)
    out = out.reshape(-1, len(padded), 4)[:, :len(tables)]
    return out[..., :3], out[..., 3]


def taper(nodes: int, near: float) -> np.ndarray:
    """The near part's weight w(gamma) on the kernel table nodes: 1 up to ``near``, a raised cosine down to 0 at
    2 ``near`` (a partition of unity with 1 - w: K = w K + (1 - w) K)."""
    gamma = 2.0 * np.arcsin(kn.q_grid(nodes))
    t = np.clip((gamma - near) / near, 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * t))


#: The near part's radius in coarse light texels (:func:`two_scale`).
NEAR_TEXELS = 2.0


def two_scale(tables: np.ndarray, size: int, fine: Environment, coarse: Environment | None, tile: int = 4,
              support: float = 0.99) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The kernels ``tables`` (J, G) applied at every texel centre of a cube of face ``size`` in two parts,
    ``[(values (T, J, 3), discrete masses (T, J), part tables (J, G)), ...]``: the near part w K (:func:`taper`,
    ``near`` = :data:`NEAR_TEXELS` coarse light texels) with the ``fine`` lights inside its cone
    (:func:`prefilter_cube`), the far part (1 - w) K with the ``coarse`` lights at the texels of a cube of their
    face size, read bilinearly at the ``size`` texels. Summed they are the filter by
    K: beyond ``near`` a lobe is smooth at the coarse texels' scale, so the fine lights are read only where
    the kernel is sharp, and the cost falls by about the cone's share of the sphere (docs/notes/bake.md,
    "Bake time"). The far part is not smoothed further (a box of a coarse texel bends a GGX tail near the
    taper: 1-2 % off the fine filter at roughness 0.18, against 0.03-0.6 % unsmoothed). ``coarse`` None (or
    no coarser than ``fine``): one part, the fine lights within the cone holding ``support`` of every
    kernel's absolute mass."""
    fine_res, coarse_res = int(fine.info.get("resolution", 0)), int(coarse.info.get("resolution", 0)) if coarse is not None else 0
    if coarse is None or coarse_res >= fine_res:
        num, den = prefilter_cube(tables, size, fine, kn.support(tables, support), tile=tile)
        return [(num, den, tables)]
    near = NEAR_TEXELS * (np.pi / 2) / coarse_res
    w = taper(tables.shape[-1], near)
    t_near = tables * w
    t_far = tables * (1.0 - w)
    num_n, den_n = prefilter_cube(t_near, size, fine, 2.0 * near, tile=tile)
    # the far part is smooth at the coarse texels' scale: filtered at a cube of the coarse lights' face size and
    # read bilinearly at the texels (the cube mapper's lookup)
    low = min(size, coarse_res)
    num_f, den_f = prefilter(t_far, np.asarray(mappers.texel_directions("cube", low), np.float64).reshape(-1, 3), coarse)
    if low < size:
        d = np.asarray(mappers.texel_directions("cube", size), np.float64).reshape(-1, 3)
        up = np.concatenate([num_f, den_f[..., None]], -1).reshape(low, 6 * low, -1)
        up = np.asarray(mappers.lookup("cube", up, d), np.float64).reshape(len(d), len(tables), 4)  # numpy: no compilation
        num_f, den_f = up[..., :3], up[..., 3]
    return [(num_n, den_n, t_near), (num_f, den_f, t_far)]


__all__ = ["normalized", "prefilter", "prefilter_cube", "taper", "two_scale"]
