"""Write the bundled demo scene of scene-aware sampling (``sampling: {kind: scene, mesh: demo}``).

    .venv/bin/python tools/make_demo_scene.py [src/homofac/data/scenes]

``demo.obj``: a sphere (radius 0.5), a torus (radii 0.45 and 0.15) lying on a ground plane (4 x 4,
z = 0), in homofac's +z-up frame, counter-clockwise faces seen from outside; no normals in the file
(homofac interpolates area-weighted vertex normals). ``demo.json``: two 160 x 120 cameras. Coordinates
are written with 4 decimals so the files stay small (about 30 KB); the output is deterministic.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

CAMERAS = [
    {"position": [0.0, -3.4, 1.5], "look_at": [0.0, 0.0, 0.35], "up": [0.0, 0.0, 1.0], "fov": 40.0,
     "width": 160, "height": 120},
    {"position": [2.8, 2.0, 2.3], "look_at": [0.0, 0.0, 0.3], "up": [0.0, 0.0, 1.0], "fov": 40.0,
     "width": 160, "height": 120},
]


def grid_faces(rows: int, cols: int, wrap_cols: bool, offset: int) -> np.ndarray:
    """Two triangles per cell of a (rows x cols) vertex grid (columns wrapped when ``wrap_cols``)."""
    out = []
    ncell = cols if wrap_cols else cols - 1
    for i in range(rows - 1):
        for j in range(ncell):
            a, b = i * cols + j, i * cols + (j + 1) % cols
            c, d = a + cols, b + cols
            out += [(a, b, d), (a, d, c)]
    return np.asarray(out) + offset


def sphere(centre, radius, n_lon=28, n_lat=14):
    """UV sphere: poles as single vertices, faces counter-clockwise seen from outside."""
    theta = np.linspace(0, np.pi, n_lat + 1)[1:-1]
    phi = np.arange(n_lon) * 2 * np.pi / n_lon
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    v = np.concatenate([[[0, 0, 1]], ring, [[0, 0, -1]]]) * radius + centre
    f = [grid_faces(n_lat - 1, n_lon, True, 1)]
    top = [(0, 1 + (j + 1) % n_lon, 1 + j) for j in range(n_lon)]
    last = 1 + (n_lat - 2) * n_lon
    bottom = [(len(v) - 1, last + j, last + (j + 1) % n_lon) for j in range(n_lon)]
    faces = np.concatenate([np.asarray(top)] + [x[:, [0, 2, 1]] for x in f] + [np.asarray(bottom)])
    return v, faces


def torus(centre, major, minor, n_major=32, n_minor=12):
    """Torus around +z; faces counter-clockwise seen from outside."""
    u = np.arange(n_major) * 2 * np.pi / n_major
    w = np.arange(n_minor) * 2 * np.pi / n_minor
    uu, ww = np.meshgrid(u, w, indexing="ij")  # rows: major angle
    r = major + minor * np.cos(ww)
    v = np.stack([r * np.cos(uu), r * np.sin(uu), minor * np.sin(ww)], -1).reshape(-1, 3) + centre
    faces = []
    for i in range(n_major):
        for j in range(n_minor):
            a = i * n_minor + j
            b = i * n_minor + (j + 1) % n_minor
            c = ((i + 1) % n_major) * n_minor + j
            d = ((i + 1) % n_major) * n_minor + (j + 1) % n_minor
            faces += [(a, c, d), (a, d, b)]
    return v, np.asarray(faces)


def plane(half: float, cells: int = 4):
    x = np.linspace(-half, half, cells + 1)
    xx, yy = np.meshgrid(x, x, indexing="ij")
    v = np.stack([xx, yy, np.zeros_like(xx)], -1).reshape(-1, 3)
    return v, grid_faces(cells + 1, cells + 1, False, 0)[:, [0, 2, 1]]


def orient_outwards(v, f, centre):
    """Flip faces whose geometric normal points towards ``centre`` (a check of the windings above)."""
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    inward = np.sum(n * (tri.mean(axis=1) - centre), axis=1) < 0
    f = f.copy()
    f[inward] = f[inward][:, [0, 2, 1]]
    return f


def main(argv=None) -> None:
    out = Path((argv or sys.argv[1:] or [str(Path(__file__).resolve().parents[1] / "src/homofac/data/scenes")])[0])
    out.mkdir(parents=True, exist_ok=True)
    parts = []
    sc = np.array([-0.65, -0.1, 0.5])
    v, f = sphere(sc, 0.5)
    parts.append(("sphere", v, orient_outwards(v, f, sc)))
    tc = np.array([0.7, 0.3, 0.15])
    v, f = torus(tc, 0.45, 0.15)
    # outwards from the tube's centre circle, not from the torus' centre
    ring = tc + 0.45 * np.stack([np.cos(np.arctan2(v[:, 1] - tc[1], v[:, 0] - tc[0])),
                                 np.sin(np.arctan2(v[:, 1] - tc[1], v[:, 0] - tc[0])), np.zeros(len(v))], -1)
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    inward = np.sum(n * (tri.mean(axis=1) - ring[f].mean(axis=1)), axis=1) < 0
    f[inward] = f[inward][:, [0, 2, 1]]
    parts.append(("torus", v, f))
    v, f = plane(2.0)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(n[:, 2] > 0), "the ground plane faces +z"
    parts.append(("ground", v, f))
    lines = ["# homofac demo scene (tools/make_demo_scene.py): sphere, torus, ground plane; +z up"]
    base = 1
    for name, v, f in parts:
        lines.append(f"o {name}")
        lines += [f"v {x:.4f} {y:.4f} {z:.4f}".replace("-0.0000", "0.0000") for x, y, z in v]
        lines += [f"f {a + base} {b + base} {c + base}" for a, b, c in f]
        base += len(v)
    (out / "demo.obj").write_text("\n".join(lines) + "\n")
    (out / "demo.json").write_text(json.dumps({"cameras": CAMERAS}, indent=1) + "\n")
    print(f"wrote {out / 'demo.obj'} ({(out / 'demo.obj').stat().st_size} bytes) and {out / 'demo.json'}")


if __name__ == "__main__":
    main()
