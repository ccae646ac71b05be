"""A two-level light tree: the environment's lights grouped into the texels of a coarser cube.

The hierarchical light sum of :meth:`homofac.light.Lighting.grouped` (a two-level form of Lightcuts,
Walter et al. 2005) sums, for every pair, the *coarse* cells of this tree (each the aggregate of its
lights: their summed cosine-weighted radiance at their power-weighted mean direction) and replaces the
``refine`` cells of largest evaluated contribution by their lights. :func:`light_tree` builds the
grouping on the host: every texel light goes to the cube texel of face size ``coarse`` that holds its
direction (a texel's centre lies inside its coarse parent whenever the fine face size is a multiple of
``coarse``, and the refined validation lighting's mixtures of two sizes are both multiples), every delta
light (an extra directional light: no corners) is a cell of its own, so a sun is never averaged with
sky texels. Cells are padded to the largest child count with the index ``L`` (one past the lights),
which the lighting computation reads as a light of weight 0.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Int

from ..param import mappers
from .environment import Environment
from .lights import light_corners


class LightTree(eqx.Module):
    """Coarse cells of an environment's lights: ``children`` (C, M) light indices (``L`` = none), the
    coarse cube face size, how many cells each view refines by their estimated contribution (``refine``)
    and each normal by their power (``bright``: the lamps, whose estimate a sharp or grazing lobe can miss),
    and ``slots``, a static bound on the cells with a light above any horizon (half the coarse cube, its
    straddlers, every delta cell)."""

    children: Int[Array, "C M"]
    coarse: int = eqx.field(static=True)
    refine: int = eqx.field(static=True)
    bright: int = eqx.field(static=True)
    slots: int = eqx.field(static=True)

    @property
    def cells(self) -> int:
        return int(self.children.shape[0])

    @property
    def width(self) -> int:
        """Lights per cell (padded): the BRDF evaluations one refined cell costs."""
        return int(self.children.shape[1])


def cube_texel(directions: np.ndarray, r: int) -> np.ndarray:
    """Index of the cube texel of face size ``r`` holding each direction (pinned layout: row-major over the
    (r, 6r) texture, row ``floor(v r)``, column ``face r + floor(u r)``)."""
    face, u, v = mappers.get("cube").to_face_uv(np.asarray(directions, np.float64))
    col = np.clip(np.floor(np.asarray(u) * r), 0, r - 1).astype(np.int64)
    row = np.clip(np.floor(np.asarray(v) * r), 0, r - 1).astype(np.int64)
    return row * (6 * r) + np.asarray(face, np.int64) * r + col


def light_tree(env: Environment, coarse: int, refine: int) -> LightTree:
    """The two-level tree of ``env``'s lights over the cube texels of face size ``coarse`` (module
    docstring); ``refine`` cells per view (of largest estimate) and ``refine`` more per normal (of largest
    power) are summed over their lights (every cell where ``refine`` is at least the visible cells: the
    full sum)."""
    coarse = int(coarse)
    if coarse < 1 or refine < 1:
        raise ValueError(f"light tree: coarse face size and refined cells must be >= 1, got {coarse}, {refine}")
    L = env.num_lights
    delta = np.all(np.asarray(light_corners(env)) == 0, axis=(-1, -2))
    n_cube = 6 * coarse * coarse
    cell = np.where(delta, n_cube + np.cumsum(delta) - 1, 0)
    cell[~delta] = cube_texel(np.asarray(env.directions)[~delta], coarse)
    n_cells = n_cube + int(delta.sum())
    order = np.argsort(cell, kind="stable")
    counts = np.bincount(cell, minlength=n_cells)
    width = int(max(1, counts.max()))
    rank = np.arange(L) - np.repeat(np.cumsum(counts) - counts, counts)
    children = np.full((n_cells, width), L, np.int32)
    children[cell[order], rank] = order
    slots = min(n_cells, 3 * coarse * coarse + 6 * coarse + int(delta.sum()))
    per_view = int(min(refine, slots))
    return LightTree(jnp.asarray(children), coarse, per_view, int(min(refine, slots - per_view)), int(slots))


def texel_resolution(env: Environment) -> int:
    """The face size of ``env``'s smallest light texels (0: not known), which bounds the texels the horizon
    of a normal can cross (:func:`homofac.light.geometry.light_geometry`): a refined mixture's fine size,
    a block's source's, else the map's own."""
    info = env.info or {}
    return int(info.get("texel_resolution") or (info.get("mixture") or {}).get("fine_resolution")
               or info.get("resolution", 0))


__all__ = ["LightTree", "cube_texel", "light_tree", "texel_resolution"]
