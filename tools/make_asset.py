"""Writes src/homofac/data/assets/material_sphere.glb: a UV sphere whose glTF metallic-roughness material
varies over its surface (base colour, metallic and roughness textures), for the engine tests and demos.

Longitude (u) sweeps roughness 0.045 -> 1 in 8 steps twice round the sphere, so that any view of a
hemisphere sees every roughness; latitude (v) holds three metallic bands (0 above, 0.5 in the middle, 1
below); the base colour cycles through eight hues. Run: python tools/make_asset.py.
"""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path

import numpy as np
from PIL import Image

OUT = Path(__file__).resolve().parents[1] / "src" / "homofac" / "data" / "assets" / "material_sphere.glb"
SEG_U, SEG_V, TEX = 64, 32, 64
ROUGHNESS = np.array([0.045, 0.1, 0.2, 0.3, 0.45, 0.6, 0.8, 1.0])
METALLIC = np.array([0.0, 0.5, 1.0])
HUES = np.array([[0.95, 0.64, 0.54], [0.91, 0.92, 0.92], [1.0, 0.78, 0.34], [0.2, 0.5, 0.9],
                 [0.8, 0.1, 0.1], [0.1, 0.7, 0.3], [0.6, 0.6, 0.6], [0.05, 0.05, 0.05]])


def sphere():
    """Positions, normals, uvs (glTF: v down from the top row of the image) and triangle indices."""
    u = np.linspace(0.0, 1.0, SEG_U + 1)
    v = np.linspace(0.0, 1.0, SEG_V + 1)
    uu, vv = np.meshgrid(u, v)
    phi, theta = 2 * np.pi * uu, np.pi * vv
    n = np.stack([np.sin(theta) * np.cos(phi), np.cos(theta), -np.sin(theta) * np.sin(phi)], -1).reshape(-1, 3)
    uv = np.stack([uu, vv], -1).reshape(-1, 2)
    i = np.arange(SEG_V)[:, None] * (SEG_U + 1) + np.arange(SEG_U)[None, :]
    a, b, c, d = i, i + 1, i + SEG_U + 1, i + SEG_U + 2
    tri = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    return n.astype(np.float32), n.astype(np.float32), uv.astype(np.float32), tri.astype(np.uint16)


def textures() -> tuple[bytes, bytes]:
    """Base colour (sRGB PNG) and metallic-roughness (linear PNG: G roughness, B metallic)."""
    x = (np.arange(TEX) + 0.5) / TEX
    ci = np.minimum(((2 * x) % 1.0 * len(ROUGHNESS)).astype(int), len(ROUGHNESS) - 1)
    ri = np.minimum((x * len(METALLIC)).astype(int), len(METALLIC) - 1)
    lin = HUES[(ci[None, :] + ri[:, None]) % len(HUES)]
    srgb = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)
    base = np.round(srgb * 255).astype(np.uint8)
    mr = np.zeros((TEX, TEX, 3), np.uint8)
    mr[..., 1] = np.round(ROUGHNESS[ci][None, :] * 255)
    mr[..., 2] = np.round(METALLIC[ri][:, None] * 255)
    out = []
    for img in (base, mr):
        buf = io.BytesIO()
        Image.fromarray(img, "RGB").save(buf, "PNG", optimize=True)
        out.append(buf.getvalue())
    return out[0], out[1]


def main() -> None:
    pos, nrm, uv, tri = sphere()
    base_png, mr_png = textures()
    blobs = [pos.tobytes(), nrm.tobytes(), uv.tobytes(), tri.tobytes(), base_png, mr_png]
    views, body = [], b""
    for blob in blobs:
        body += b"\0" * (-len(body) % 4)
        views.append({"buffer": 0, "byteOffset": len(body), "byteLength": len(blob)})
        body += blob
    body += b"\0" * (-len(body) % 4)
    for k, target in zip(range(4), (34962, 34962, 34962, 34963)):
        views[k]["target"] = target
    doc = {
        "asset": {"version": "2.0", "generator": "homofac tools/make_asset.py"},
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0, "name": "material_sphere"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2},
                                    "indices": 3, "material": 0}]}],
        "materials": [{"name": "varying", "pbrMetallicRoughness": {
            "baseColorTexture": {"index": 0}, "metallicRoughnessTexture": {"index": 1},
            "metallicFactor": 1.0, "roughnessFactor": 1.0}}],
        "textures": [{"source": 0, "sampler": 0}, {"source": 1, "sampler": 0}],
        "samplers": [{"magFilter": 9728, "minFilter": 9728, "wrapS": 33071, "wrapT": 33071}],
        "images": [{"bufferView": 4, "mimeType": "image/png"}, {"bufferView": 5, "mimeType": "image/png"}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": len(pos), "type": "VEC3",
             "min": pos.min(0).tolist(), "max": pos.max(0).tolist()},
            {"bufferView": 1, "componentType": 5126, "count": len(nrm), "type": "VEC3"},
            {"bufferView": 2, "componentType": 5126, "count": len(uv), "type": "VEC2"},
            {"bufferView": 3, "componentType": 5123, "count": tri.size, "type": "SCALAR"},
        ],
        "bufferViews": views,
        "buffers": [{"byteLength": len(body)}],
    }
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    glb = struct.pack("<III", 0x46546C67, 2, 12 + 8 + len(js) + 8 + len(body))
    glb += struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(body), 0x004E4942) + body
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_bytes(glb)
    print(f"{OUT}: {len(glb)} bytes")


if __name__ == "__main__":
    main()
