"""A textured glTF asset for the previews of a bake: one primitive, its glTF metallic-roughness material.

:func:`load_asset` reads a ``.glb`` / ``.gltf`` file (or the bundled ``material_sphere``, written by
tools/make_asset.py: base colour, metallic and roughness vary over the surface) into an :class:`Asset`:

* geometry in homofac's +z-up frame (glTF is y-up: its ``(x, y, z)`` is homofac's ``(x, -z, y)``, the
  ``HOMOFAC_Y_UP`` convention), centred on its bounding box and scaled into the unit sphere;
* ``uv`` in glTF's convention (``v`` runs down from the image's first row), so a texture uploaded with its
  rows in file order is read at ``uv`` as it is;
* the material (glTF 2.0 ``pbrMetallicRoughness``): the base colour texture (sRGB, 8-bit RGBA), the
  metallic-roughness texture (linear, roughness in G, metallic in B) and the factors that multiply them;
  a missing texture is a 1 x 1 white one, so that its factor alone counts.

The file is read as the scene meshes are (:mod:`homofac.fit.scene`: a regular file of bounded size, vertices
and triangles counted before trimesh parses them, buffers and images only from files beside it).
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
from jaxtyping import Float, Int, UInt8

from ..errors import HomofacError
from ..fit import scene

#: Bundled assets (``homofac/data/assets/<name>.glb``).
ASSETS = ("material_sphere",)
#: Largest material texture side accepted.
MAX_TEXTURE = 4096
#: glTF (x, y, z) -> homofac (x, -z, y).
_FROM_Y_UP = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])


class Asset(NamedTuple):
    """A triangle mesh with uvs and one glTF metallic-roughness material (see the module docstring)."""

    name: str
    positions: Float[np.ndarray, "V 3"]
    normals: Float[np.ndarray, "V 3"]
    uv: Float[np.ndarray, "V 2"]
    faces: Int[np.ndarray, "F 3"]
    base_color: UInt8[np.ndarray, "H W 4"]
    metallic_roughness: UInt8[np.ndarray, "H2 W2 4"]
    base_color_factor: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    metallic_factor: float = 1.0
    roughness_factor: float = 1.0


def asset_path(name: str) -> Path:
    """Path of a bundled asset (one of :data:`ASSETS`)."""
    return Path(__file__).resolve().parents[1] / "data" / "assets" / f"{name}.glb"


def _rgba(image, what: str, path) -> np.ndarray:
    if image is None:
        return np.full((1, 1, 4), 255, np.uint8)
    w, h = image.size
    if not (0 < w <= MAX_TEXTURE and 0 < h <= MAX_TEXTURE):
        raise HomofacError(f"{path}: the {what} texture is {w} x {h}; at most {MAX_TEXTURE} per side is accepted")
    return np.ascontiguousarray(np.asarray(image.convert("RGBA"), np.uint8))


def load_asset(source: str | os.PathLike = "material_sphere") -> Asset:
    """An :class:`Asset` from a bundled name or a ``.glb`` / ``.gltf`` file (one textured primitive)."""
    name = str(source)
    p = asset_path(name) if name in ASSETS else Path(name).expanduser()
    if p.suffix.lower() not in (".glb", ".gltf"):
        raise HomofacError(f"asset {name!r}: a glTF file (.glb or .gltf) or a bundled asset ({', '.join(ASSETS)})")
    if not p.exists():
        raise HomofacError(f"asset {name!r}: no such file (bundled assets: {', '.join(ASSETS)})")
    data = scene.read_mesh_file(p)
    nv, nf, data = scene._prepare(p, data)
    scene._refuse_counts(p, nv, nf)
    try:
        import trimesh
    except ImportError as e:
        raise HomofacError(f"the asset preview needs trimesh (pip install 'homofac[gl]'): {e}") from None
    try:
        loaded = trimesh.load(io.BytesIO(data), file_type=p.suffix.lower()[1:], process=False,
                              resolver=scene._Resolver(p.parent))
        geoms = loaded.dump() if isinstance(loaded, trimesh.Scene) else [loaded]
    except HomofacError:
        raise
    except Exception as e:  # noqa: BLE001 - trimesh raises many kinds on bad files
        raise HomofacError(f"{p}: cannot read the glTF asset ({' '.join(str(e).split())[:200]})") from None
    geoms = [g for g in geoms if isinstance(g, trimesh.Trimesh) and len(g.faces)]
    if len(geoms) != 1:
        raise HomofacError(f"{p}: the asset preview shows one textured primitive; this file has {len(geoms)}")
    g = geoms[0]
    uv = getattr(g.visual, "uv", None)
    mat = getattr(g.visual, "material", None)
    if uv is None or mat is None or len(uv) != len(g.vertices):
        raise HomofacError(f"{p}: the primitive has no texture coordinates or no material")
    v = np.asarray(g.vertices, np.float64) @ _FROM_Y_UP.T
    n = np.asarray(g.vertex_normals, np.float64) @ _FROM_Y_UP.T
    v = v - (v.min(0) + v.max(0)) / 2
    r = np.sqrt((v * v).sum(-1)).max()
    if not np.isfinite(r) or r <= 0 or not np.all(np.isfinite(n)):
        raise HomofacError(f"{p}: degenerate asset (zero size or non-finite vertices)")
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    uv = np.asarray(uv, np.float64)
    uv = np.stack([uv[:, 0], 1.0 - uv[:, 1]], -1)  # trimesh flips v to OpenGL's convention; back to glTF's
    factor = getattr(mat, "baseColorFactor", None)
    factor = (1.0, 1.0, 1.0, 1.0) if factor is None else tuple(float(x) / 255.0 for x in np.asarray(factor).reshape(-1)[:4])

    def num(x) -> float:
        return 1.0 if x is None else float(np.clip(float(x), 0.0, 1.0))

    return Asset(p.stem, (v / r).astype(np.float32), n.astype(np.float32), uv.astype(np.float32),
                 np.asarray(g.faces, np.int32), _rgba(getattr(mat, "baseColorTexture", None), "base colour", p),
                 _rgba(getattr(mat, "metallicRoughnessTexture", None), "metallic-roughness", p), factor,
                 num(getattr(mat, "metallicFactor", None)), num(getattr(mat, "roughnessFactor", None)))


__all__ = ["ASSETS", "Asset", "asset_path", "load_asset"]
