"""Packing of a P_k's roughness layers into one 2D texture (what the shaders read).

Layer j is a cube-mapper block of (S_j, 6 S_j) texels (the pinned ``cube`` layout, docs/conventions.md). Two
packers place the blocks: :func:`pack` on shelves left to right, each shelf as high as its first block, in the
order given (sizes non-increasing, so the shelves fill; schemas 1-4 of bake.json), and :func:`bottom_left`, each
block at the lowest free position (a skyline: a small block may sit beside a shorter block of a full row, where
the shelf leaves a gap). A shader reads layer j at atlas texel ``(x0_j + col, y0_j + row)`` with the per-face
clamped coordinates of the cube mapper: the hardware's bilinear filter then never reads outside the face,
exactly as :func:`homofac.param.mappers.lookup` does.

A map's block may be smaller than its layer's face (S_j / s_j texels of the layer per block texel and side):
it holds the layer's map box-averaged per face (:func:`down`, a mip level of it), and :func:`up` replicates it
back to the layer's face, whose box average is the block again, exactly.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Atlas(NamedTuple):
    """``width`` x ``height`` texels; ``offsets[j] = (x0, y0)`` of layer j; ``sizes[j] = S_j``."""

    width: int
    height: int
    offsets: tuple[tuple[int, int], ...]
    sizes: tuple[int, ...]


def pack(sizes, blocks=None) -> Atlas:
    """Shelf packing of blocks (S_j, 6 S_j), sizes non-increasing. ``blocks[j]`` (optional): the layer whose
    block layer j shares (``blocks[j] <= j``, same size; a layer that shares is not packed again)."""
    sizes = tuple(int(s) for s in sizes)
    blocks = tuple(range(len(sizes))) if blocks is None else tuple(int(b) for b in blocks)
    if len(blocks) != len(sizes) or any(not 0 <= b <= j or sizes[b] != sizes[j] or blocks[b] != b for j, b in enumerate(blocks)):
        raise ValueError("each layer shares the block of an earlier layer of its size that has its own block")
    width = 6 * max(sizes)
    offsets, x, y, shelf = [], 0, 0, 0
    for j, s in enumerate(sizes):
        if blocks[j] != j:
            offsets.append(offsets[blocks[j]])
            continue
        if x + 6 * s > width:
            x, y, shelf = 0, y + shelf, 0
        offsets.append((x, y))
        shelf = max(shelf, s)
        x += 6 * s
    return Atlas(width, y + shelf, tuple(offsets), sizes)


def bottom_left(sizes, blocks=None) -> Atlas:
    """Skyline packing of blocks (S_j, 6 S_j) (powers of two, any order): the atlas is 6 max(S) wide; the own
    blocks, largest first (then in layer order), each go to the lowest free position above the blocks placed
    before it, the leftmost of equal height, on columns of 6 min(S) texels. ``blocks[j]`` (optional): the layer
    whose block layer j shares (``blocks[j] <= j``, same block size; :func:`pack`'s rule)."""
    sizes = tuple(int(s) for s in sizes)
    blocks = tuple(range(len(sizes))) if blocks is None else tuple(int(b) for b in blocks)
    if len(blocks) != len(sizes) or any(not 0 <= b <= j or sizes[b] != sizes[j] or blocks[b] != b for j, b in enumerate(blocks)):
        raise ValueError("each layer shares the block of an earlier layer of its size that has its own block")
    own = sorted((j for j in range(len(sizes)) if blocks[j] == j), key=lambda j: (-sizes[j], j))
    unit = 6 * min(sizes)
    sky = np.zeros(6 * max(sizes) // unit, np.int64)
    at: dict[int, tuple[int, int]] = {}
    for j in own:
        w = 6 * sizes[j] // unit
        tops = np.array([sky[i:i + w].max() for i in range(len(sky) - w + 1)])
        x = int(np.argmin(tops))  # the lowest, then the leftmost
        at[j] = (x * unit, int(tops[x]))
        sky[x:x + w] = tops[x] + sizes[j]
    return Atlas(6 * max(sizes), int(sky.max()), tuple(at[b] for b in blocks), sizes)


def down(texture, factor: int) -> np.ndarray:
    """A cube-layout texture (S, 6 S, ...) box-averaged ``factor`` x ``factor`` within each face: (S / f, 6 S / f, ...)
    (a block of a map stored at 1 / f of its layer's face)."""
    t = np.asarray(texture, np.float32)
    if factor == 1:
        return t
    s = t.shape[0]
    return t.reshape(s // factor, factor, 6 * s // factor, factor, *t.shape[2:]).mean(axis=(1, 3))


def up(texture, factor: int) -> np.ndarray:
    """A cube-layout texture (s, 6 s, ...) with every texel repeated ``factor`` x ``factor``: (f s, 6 f s, ...); its
    :func:`down` by ``factor`` is ``texture`` exactly."""
    t = np.asarray(texture, np.float32)
    return t if factor == 1 else np.repeat(np.repeat(t, factor, 0), factor, 1)


def blocks_of(offsets, sizes) -> tuple[int, ...]:
    """The ``blocks`` of :func:`pack` read back from layer offsets: a layer at an earlier layer's offset shares it."""
    first: dict = {}
    return tuple(first.setdefault((tuple(o), int(s)), j) for j, (o, s) in enumerate(zip(offsets, sizes)))


def check_layout(atlas: Atlas) -> tuple[int, ...]:
    """Check a layout read from a file (any packer's): every block (S_j, 6 S_j) inside the ``width`` x ``height``
    image, two blocks either the same (x, y, S) (shared: the later layer reads the earlier one's block) or
    disjoint. Returns the layers' ``blocks`` (:func:`blocks_of`); raises ValueError naming the first bad layer."""
    if len(atlas.offsets) != len(atlas.sizes):
        raise ValueError("one block per layer")
    boxes = np.array([(x, y, x + 6 * s, y + s) for (x, y), s in zip(atlas.offsets, atlas.sizes)], np.int64).reshape(-1, 4)
    for j, (x0, y0, x1, y1) in enumerate(boxes):
        if min(x0, y0) < 0 or x1 > atlas.width or y1 > atlas.height or atlas.sizes[j] < 1:
            raise ValueError(f"layer {j}'s block ({x0}, {y0}, size {atlas.sizes[j]}) lies outside the "
                             f"{atlas.width} x {atlas.height} atlas")
    same = np.all(boxes[:, None] == boxes[None], axis=-1)
    apart = ((boxes[:, None, 2] <= boxes[None, :, 0]) | (boxes[None, :, 2] <= boxes[:, None, 0])
             | (boxes[:, None, 3] <= boxes[None, :, 1]) | (boxes[None, :, 3] <= boxes[:, None, 1]))
    bad = np.argwhere(~same & ~apart)
    if len(bad):
        i, j = sorted(bad[0])
        raise ValueError(f"the blocks of layers {i} and {j} overlap")
    return blocks_of(atlas.offsets, atlas.sizes)


def assemble(atlas: Atlas, layers, channels: int) -> np.ndarray:
    """The (height, width, channels) atlas image of ``layers`` (each (S_j, 6 S_j, channels)); unused texels 0."""
    out = np.zeros((atlas.height, atlas.width, channels), np.float32)
    for (x0, y0), s, layer in zip(atlas.offsets, atlas.sizes, layers):
        out[y0:y0 + s, x0:x0 + 6 * s] = np.asarray(layer, np.float32).reshape(s, 6 * s, channels)
    return out


def split(atlas: Atlas, image: np.ndarray) -> list[np.ndarray]:
    """The layers of an atlas image (the inverse of :func:`assemble`)."""
    return [np.asarray(image[y0:y0 + s, x0:x0 + 6 * s]) for (x0, y0), s in zip(atlas.offsets, atlas.sizes)]


__all__ = ["Atlas", "assemble", "blocks_of", "bottom_left", "check_layout", "down", "pack", "split", "up"]
