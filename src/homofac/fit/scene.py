"""Scene-aware sampling (issue 15, part 3): the (n, v) pairs that a mesh seen by cameras produces.

A fit samples every valid (n, v) pair evenly; a scene only ever shows the pairs its meshes and cameras
produce. ``sampling: {kind: scene, mesh: FILE, cameras: [...]}`` renders each camera (a pinhole,
:class:`~homofac.fit.options.CameraOptions`) of the mesh and draws the training pairs from the pixels it
covers, every covered pixel of every camera with the same probability (so a camera, or an object,
counts by how many pixels it covers); the validation pairs likewise with seed ``seed + 1``. The
lighting target evaluates them like any other pairs, so products, sums and baselines all apply.

**Rendering.** Rays through the pixel centres are intersected with the triangles (Moller-Trumbore) by
a vectorised rasterizer in NumPy: each triangle is projected to the image, its bounding box of pixels
is expanded into (triangle, pixel) candidates (chunked, bounded memory), the rays of those candidates
are intersected and a z-buffer keeps the nearest hit per pixel. No Python loop runs over pixels or
triangles. Per covered pixel: the shading normal n (the mesh's vertex normals interpolated
barycentrically, flipped when the triangle is seen from its back) and the view v = normalize(camera -
hit). Directions are in homofac's world frame (+z up, docs/conventions.md); the lighting is distant, so
only directions matter, not positions or units.

**Covered pixels** (what the scene metrics count): pixels whose centre ray hits a triangle and whose
shading normal faces the camera, n . v > 1e-4 (:data:`~homofac.fit.sampling.MIN_COS`; the interpolated
normal can turn away from the view at a silhouette although its triangle faces the camera; those few
pixels are not covered). Background pixels are not covered.

**Scene metrics.** :meth:`Scene.metrics` compares the factorization with the exact lighting at every
covered pixel of every camera (each pixel once), with the pinned metric functions of the validation
set (:func:`homofac.fit.metrics.metrics`), for the float and the 8-bit textures;
:func:`homofac.fit.factorize` records them as ``metrics["scene"]`` and ``counts["scene_pixels"]``.

**Nothing on disk is trusted.** A mesh file must be a regular file (not a directory, FIFO, device or
socket) and is read once, at most :data:`MAX_MESH_BYTES`; trimesh parses those bytes. Its vertices and
triangles are counted in them as trimesh will build them (OBJ polygons fanned to triangles however long
the line, an ASCII PLY cut to the rows its header declares, glTF meshes times the node paths that
instance them) and refused above :data:`MAX_VERTICES` / :data:`MAX_FACES` before trimesh parses them, and
again after; the files a glTF names must be regular files beside it, read through a checked resolver;
materials and images are not loaded. Every refusal is one line. trimesh (``pip install homofac[scene]``) is imported only
when a mesh is loaded. Bundled scenes (:data:`BUNDLED`, ``mesh: demo``) live in ``homofac/data/scenes``
with their cameras (``<name>.json``), which are the default when ``cameras`` is not given.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import io
import json
import os
import re
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from ..errors import HomofacError
from ..io.files import check_regular, one_line, read_bounded
from ..options import validate
from . import sampling
from .metrics import metrics as metric_values
from .options import CameraOptions, SamplingOptions
from .samples import evaluate_grouped

#: Mesh files larger than this are not read.
MAX_MESH_BYTES = 64 << 20
#: Most vertices and triangles of a scene mesh.
MAX_VERTICES, MAX_FACES = 1_000_000, 1_000_000
#: Most (triangle, pixel) candidates the rasterizer tests (the triangles' pixel bounding boxes summed
#: over all cameras): a bound on the work of a render.
MAX_CANDIDATES = 400_000_000
#: Candidates tested per chunk (bounded memory: about 60 bytes each).
CHUNK = 1 << 20
#: Mesh file types read (by extension).
FORMATS = {".obj": "obj", ".ply": "ply", ".gltf": "gltf", ".glb": "glb"}
#: Bundled scenes (homofac/data/scenes/<name>.obj and <name>.json).
BUNDLED = ("demo",)


def scenes_dir() -> Path:
    """``homofac/data/scenes``: the bundled scenes."""
    return Path(__file__).resolve().parent.parent / "data" / "scenes"


def bundled_path(name: str) -> Path | None:
    """The mesh of a bundled scene name (``demo``, ``demo.obj``), or None."""
    stem = name[:-4] if name.endswith(".obj") else name
    return scenes_dir() / f"{stem}.obj" if stem in BUNDLED and "/" not in name else None


def bundled_cameras(name: str) -> list[CameraOptions]:
    """The cameras of a bundled scene (its ``<name>.json``: ``{"cameras": [...]}``)."""
    stem = name[:-4] if name.endswith(".obj") else name
    doc = json.loads((scenes_dir() / f"{stem}.json").read_text())
    return [validate(CameraOptions, c, "cameras") for c in doc["cameras"]]


def mesh_path(name: str) -> Path:
    """The file a ``sampling.mesh`` names: an existing file, else a bundled scene name."""
    p = Path(name).expanduser()
    if p.exists():
        return p
    b = bundled_path(name)
    if b is not None:
        return b
    raise HomofacError(f"sampling.mesh: {name}: no such file (bundled scenes: {', '.join(BUNDLED)})")


# ------------------------------------------------------------------------------------------------
# loading (checked before trimesh reads anything)


def _refuse_counts(path: Path, vertices: int, faces: int) -> None:
    if vertices > MAX_VERTICES:
        raise HomofacError(f"{path}: the mesh has {vertices} vertices, more than {MAX_VERTICES}")
    if faces > MAX_FACES:
        raise HomofacError(f"{path}: the mesh has {faces} faces, more than {MAX_FACES}")


def read_mesh_file(path: Path) -> bytes:
    """The bytes of a mesh file: a regular file (not a directory, FIFO, device or socket) of at most
    :data:`MAX_MESH_BYTES`, read once (what is checked is what is parsed)."""
    st = check_regular(path, "a mesh")
    if st.st_size > MAX_MESH_BYTES:
        raise HomofacError(f"{path}: the mesh file has {st.st_size} bytes, more than {MAX_MESH_BYTES >> 20} MiB")
    return read_bounded(path, "a mesh", MAX_MESH_BYTES)


def _gltf_json(path: Path, data: bytes) -> dict:
    if path.suffix.lower() == ".glb":
        if len(data) < 20 or data[:4] != b"glTF":
            raise HomofacError(f"{path}: not a binary glTF file (no glTF magic)")
        n = int.from_bytes(data[12:16], "little")
        if data[16:20] != b"JSON" or n > len(data) - 20:
            raise HomofacError(f"{path}: the binary glTF's first chunk is not a JSON chunk of its declared size")
        data = data[20:20 + n]
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as e:
        raise HomofacError(f"{path}: the glTF JSON does not parse ({one_line(e)})") from None
    if not isinstance(doc, dict):
        raise HomofacError(f"{path}: the glTF document is not a JSON object")
    return doc


def obj_text(path: Path, data: bytes) -> str:
    r"""The text of an OBJ file as trimesh's OBJ reader sees it (UTF-8 only; ``\r\n`` -> ``\n``,
    backslash line continuations joined)."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise HomofacError(f"{path}: not a readable obj mesh (not UTF-8 text: bad byte at {e.start})") from None
    return "\n{}\n".format(text.strip().replace("\r\n", "\n")).replace("\\\n", "")


def _tokens_per_line(text: str) -> np.ndarray:
    r"""Whitespace-separated tokens on each ``\n``-separated line of ``text`` (an upper bound of
    ``str.split()``: any byte outside printable ASCII separates)."""
    b = np.frombuffer(text.encode("utf-8"), np.uint8)
    word = (b > 32) & (b < 127)
    start = word & ~np.concatenate([[False], word[:-1]])
    line = np.cumsum(b == 10)
    return np.bincount(line[start], minlength=int(line[-1]) + 1 if len(line) else 1)


def _obj_counts(path: Path, data: bytes) -> tuple[int, int]:
    """(vertices, triangles) trimesh makes of an OBJ: every line starting with ``f`` is a polygon of
    n corners, fanned into max(n - 2, 1) triangles, however long the line."""
    text = obj_text(path, data)
    faces = "\n".join(m.group(1) for m in re.finditer(r"^f([^\n]*)", text, re.M))
    triangles = int(np.maximum(_tokens_per_line(faces) - 2, 1).sum()) if faces else 0
    return len(re.findall(r"^v[ \t]", text, re.M)), triangles


_BREAK = re.compile("\r\n|[\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029]")
_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
          "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


def _binary_ply_triangles(head: str, data: bytes, body_at: int, faces: int) -> int:
    """Triangles a binary PLY's face rows make, bounded from its bytes: exact when every face has the same
    corner count n (the common case: F max(n - 2, 1)), else the corner entries its face bytes can hold."""
    elems: list[list] = []  # [name, count, fixed bytes a row, [(count type, item type)]]
    for line in head.splitlines():
        t = line.split()
        if t[:1] == ["element"] and len(t) >= 3 and t[2].isdigit():
            elems.append([t[1], int(t[2]), 0, []])
        elif t[:1] == ["property"] and elems:
            if len(t) >= 5 and t[1] == "list":
                elems[-1][3].append((_SIZES.get(t[2], 4), _SIZES.get(t[3], 4)))
            elif len(t) >= 3:
                elems[-1][2] += _SIZES.get(t[1], 8)
    body = len(data) - body_at
    crude = body  # every body byte a corner: an upper bound
    at = body_at
    for name, count, fixed, lists in elems:
        if name == "face" and len(lists) == 1 and fixed == 0 and at < len(data):
            cs, isz = lists[0]
            kind = {1: "<u1", 2: "<u2", 4: "<u4"}.get(cs)
            if kind is None or at + cs > len(data):
                return crude
            n0 = int(np.frombuffer(data, kind, 1, at)[0])
            stride = cs + n0 * isz
            if count and at + stride * count <= len(data):
                firsts = np.ndarray((count,), np.dtype(kind), data, at, (stride,))
                if np.all(firsts == n0):
                    return count * max(n0 - 2, 1)
            return min(crude, (body - sum(c * f for _, c, f, _ in elems)) // max(isz, 1))
        if lists:
            return crude
        at += count * fixed
    return crude if faces else 0


def _ply_counts(path: Path, data: bytes) -> tuple[int, int, bytes]:
    """(vertices, triangles bound, the bytes to parse) of a PLY file. An ASCII body is cut after the rows
    its header declares (junk lines beyond them are never parsed) and its face rows are counted as
    fanned polygons; a binary body's faces are bounded by the index entries its bytes can hold."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise HomofacError(f"{path}: not a PLY file (no ply header)")
    head = data[:end].decode("ascii", "replace")
    elements = [(k, int(n)) for k, n in re.findall(r"^element\s+(\w+)\s+(\d+)", head, re.M)]
    counts = dict(elements)
    vertices, faces = int(counts.get("vertex", 0)), int(counts.get("face", 0))
    _refuse_counts(path, vertices, faces)
    if sum(n for _, n in elements) > MAX_VERTICES + MAX_FACES:
        raise HomofacError(f"{path}: the PLY header declares {sum(n for _, n in elements)} rows, more than "
                           f"{MAX_VERTICES + MAX_FACES}")
    body_at = data.find(b"\n", end) + 1 if data.find(b"\n", end) >= 0 else len(data)
    if "format ascii" not in head:
        return vertices, _binary_ply_triangles(head, data, body_at, faces), data
    rows = sum(n for _, n in elements)
    try:
        body = data[body_at:].decode("utf-8")
    except UnicodeDecodeError as e:
        raise HomofacError(f"{path}: not a readable ply mesh (not UTF-8 text: bad byte at {body_at + e.start})") from None
    cut = 0  # the end of the last declared row (line breaks as str.splitlines, which trimesh uses)
    for k, m in enumerate(_BREAK.finditer(body)):
        if k == rows:
            break
        cut = m.end()
    else:
        cut = len(body)
    lines = body[:cut].splitlines(keepends=True)
    kept = "".join(lines)
    triangles = 0
    start = 0
    for name, n in elements:  # the face rows: first token is the corner count
        if name == "face":
            firsts = [ln.split(None, 1)[0] if ln.split() else "0" for ln in lines[start:start + n]]
            try:
                corners = np.array([int(float(c)) for c in firsts], np.int64)
            except ValueError:
                raise HomofacError(f"{path}: a PLY face row does not start with its corner count") from None
            triangles += int(np.maximum(corners - 2, 1).sum()) if len(corners) else 0
        start += n
    return vertices, triangles, data[:body_at] + kept.encode("utf-8")


def _gltf_counts(path: Path, doc: dict) -> tuple[int, int]:
    """(vertices, triangles) of a glTF's scene: each mesh's primitives (strips and fans: n - 2 triangles
    per n indices, else n / 3) times the number of node paths that instance it (a node graph with a
    cycle is refused)."""
    acc = doc.get("accessors") or []
    meshes = doc.get("meshes") or []
    nodes = doc.get("nodes") or []
    if not isinstance(acc, list) or not isinstance(meshes, list) or not isinstance(nodes, list):
        raise HomofacError(f"{path}: the glTF's accessors, meshes and nodes must be lists")
    per_mesh = []
    for mesh in meshes:
        nv = nf = 0
        for prim in (mesh or {}).get("primitives") or [] if isinstance(mesh, dict) else []:
            try:
                pos = int(prim["attributes"]["POSITION"])
                v = int(acc[pos]["count"])
                n = int(acc[int(prim["indices"])]["count"]) if "indices" in prim else v
                mode = int(prim.get("mode", 4))
            except (KeyError, IndexError, TypeError, ValueError, AttributeError):
                raise HomofacError(f"{path}: a glTF primitive has no readable POSITION accessor") from None
            if v < 0 or n < 0:
                raise HomofacError(f"{path}: a glTF accessor has a negative count")
            nv, nf = nv + v, nf + (max(n - 2, 0) if mode in (5, 6) else n // 3)
        per_mesh.append((nv, nf))
    children: list[list[int]] = []
    for node in nodes:
        try:
            children.append([int(c) for c in (node.get("children") or [])] if isinstance(node, dict) else [])
        except (TypeError, ValueError):
            raise HomofacError(f"{path}: a glTF node's children are not node indices") from None
    if any(c < 0 or c >= len(nodes) for cs in children for c in cs):
        raise HomofacError(f"{path}: a glTF node's child is not a node")
    paths = [0] * len(nodes)  # instances of each node: paths from the scene roots (a DAG)
    state = [0] * len(nodes)
    order: list[int] = []
    for root in range(len(nodes)):  # topological order, iteratively (no recursion on hostile depths)
        if state[root]:
            continue
        stack = [(root, 0)]
        while stack:
            k, i = stack.pop()
            if i == 0:
                if state[k] == 1:
                    raise HomofacError(f"{path}: the glTF node graph has a cycle")
                if state[k] == 2:
                    continue
                state[k] = 1
            if i < len(children[k]):
                stack.append((k, i + 1))
                c = children[k][i]
                if state[c] == 1:
                    raise HomofacError(f"{path}: the glTF node graph has a cycle")
                if state[c] == 0:
                    stack.append((c, 0))
            else:
                state[k] = 2
                order.append(k)
    roots: list[int] = []  # every scene's root nodes (trimesh may load any scene), else the parentless nodes
    for sc in doc.get("scenes") or [] if isinstance(doc.get("scenes"), list) else []:
        try:
            roots += [int(k) for k in (sc.get("nodes") or [])] if isinstance(sc, dict) else []
        except (TypeError, ValueError):
            raise HomofacError(f"{path}: a glTF scene's nodes are not node indices") from None
    if not roots:
        is_child = {c for cs in children for c in cs}
        roots = [k for k in range(len(nodes)) if k not in is_child]
    for k in roots:
        if 0 <= k < len(nodes):
            paths[k] += 1
    for k in reversed(order):  # parents before children
        for c in children[k]:
            paths[c] += paths[k]
    used = {node.get("mesh") for node in nodes if isinstance(node, dict)}
    unused = [vf for m, vf in enumerate(per_mesh) if m not in used]  # meshes of no node: counted once
    vertices, triangles = sum(v for v, _ in unused), sum(f for _, f in unused)
    for k, node in enumerate(nodes):
        m = node.get("mesh") if isinstance(node, dict) else None
        if m is None:
            continue
        try:
            v, f = per_mesh[int(m)]
        except (IndexError, TypeError, ValueError):
            raise HomofacError(f"{path}: a glTF node names a mesh that does not exist") from None
        vertices, triangles = vertices + paths[k] * v, triangles + paths[k] * f
        if vertices > MAX_VERTICES or triangles > MAX_FACES:
            break
    return vertices, triangles


def _gltf_uris(path: Path, doc: dict) -> None:
    """Every file a glTF names (buffers, images) must be a regular file beside it, of at most
    :data:`MAX_MESH_BYTES`."""
    for key in ("buffers", "images"):
        items = doc.get(key) or []
        for item in items if isinstance(items, list) else []:
            uri = item.get("uri") if isinstance(item, dict) else None
            if uri is None or str(uri).startswith("data:"):
                continue
            u = str(uri)
            if "://" in u or u.startswith(("/", "\\")) or ".." in Path(u).parts or "\\" in u or ":" in u:
                raise HomofacError(f"{path}: the glTF {key[:-1]} {u!r} is not a file beside it")
            q = path.parent / u
            if not q.exists():
                raise HomofacError(f"{path}: the glTF {key[:-1]} {u} is missing")
            st = check_regular(q, f"a glTF {key[:-1]}")
            if st.st_size > MAX_MESH_BYTES:
                raise HomofacError(f"{path}: the glTF {key[:-1]} {u} is larger than {MAX_MESH_BYTES >> 20} MiB")


def precount(path: Path, data: bytes) -> tuple[int, int]:
    """(vertices, triangles) a mesh file makes, counted in the bytes trimesh will parse: OBJ polygons
    fanned to triangles, PLY face rows (an ASCII body cut to its declared rows), glTF meshes times their
    node instances. Refused above :data:`MAX_VERTICES` / :data:`MAX_FACES` before trimesh runs."""
    return _prepare(path, data)[:2]


def _prepare(path: Path, data: bytes) -> tuple[int, int, bytes]:
    """(vertices, triangles, the bytes to hand trimesh) of a mesh file (see :func:`precount`)."""
    kind = FORMATS[path.suffix.lower()]
    if kind == "obj":
        return (*_obj_counts(path, data), data)
    if kind == "ply":
        return _ply_counts(path, data)
    doc = _gltf_json(path, data)
    _gltf_uris(path, doc)
    return (*_gltf_counts(path, doc), data)


class _Resolver:
    """trimesh resolver of the files beside a glTF: read through :func:`read_bounded` (regular files of at
    most :data:`MAX_MESH_BYTES`), plain relative names only."""

    def __init__(self, root: Path):
        self.root = root

    def get(self, name: str) -> bytes:
        u = str(name).strip()
        if "://" in u or u.startswith(("/", "\\")) or ".." in Path(u).parts or "\\" in u:
            raise HomofacError(f"{self.root / u}: not a file beside the mesh")
        return read_bounded(self.root / u, "a mesh resource", MAX_MESH_BYTES)

    __getitem__ = get

    def get_base(self) -> bytes:
        raise HomofacError(f"{self.root}: a mesh resource has no base")

    def namespaced(self, namespace: str) -> "_Resolver":
        return _Resolver(self.root / namespace)

    def keys(self):
        return iter(())

    def write(self, name, data):
        raise HomofacError("a mesh resource cannot be written")


def load_mesh(path: str | os.PathLike, up: str = "z") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(vertices (V, 3) float64, faces (F, 3) int64, vertex normals (V, 3))`` of an OBJ / PLY / glTF
    mesh (every object of the file, concatenated), in homofac's +z-up frame (``up="y"`` turns a y-up
    file, glTF's convention, into it).

    The file is read once (a regular file of at most :data:`MAX_MESH_BYTES`), its vertices and
    triangles are counted in those bytes as trimesh will build them (:func:`precount`) and refused
    above the limits before trimesh parses them; trimesh reads from those bytes, materials are skipped
    and a glTF's buffers come through a checked resolver (regular files beside it)."""
    p = Path(path)
    kind = FORMATS.get(p.suffix.lower())
    if kind is None:
        raise HomofacError(f"{p}: a scene mesh must be an .obj, .ply, .gltf or .glb file")
    if not p.exists():
        raise HomofacError(f"{p}: no such mesh file")
    data = read_mesh_file(p)
    nv, nf, data = _prepare(p, data)
    _refuse_counts(p, nv, nf)
    try:
        import trimesh  # optional heavy dependency (homofac[scene]), imported when a mesh is loaded
    except ImportError:
        raise HomofacError("sampling.kind: scene needs trimesh (pip install 'homofac[scene]')") from None
    try:
        mesh = trimesh.load(io.BytesIO(data), file_type=kind, force="mesh", process=False,
                            resolver=_Resolver(p.parent), skip_materials=True)
        vertices = np.asarray(mesh.vertices, np.float64)
        faces = np.asarray(mesh.faces, np.int64)
        normals = np.asarray(mesh.vertex_normals, np.float64) if len(faces) else None  # the file's, or computed
    except HomofacError:
        raise
    except Exception as e:  # trimesh raises many kinds on bad files: one line naming the file
        raise HomofacError(f"{p}: not a readable {kind} mesh ({one_line(e)[:200]})") from None
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise HomofacError(f"{p}: the mesh has no triangles")
    _refuse_counts(p, len(vertices), len(faces))
    if not np.all(np.isfinite(vertices)) or np.abs(vertices).max() > 1e6:
        raise HomofacError(f"{p}: the mesh has non-finite vertices or coordinates beyond 1e6")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise HomofacError(f"{p}: the mesh's faces index missing vertices")
    if normals is None or normals.shape != vertices.shape or not np.all(np.isfinite(normals)):
        normals = vertex_normals(vertices, faces)
    if up == "y":  # y-up to z-up: a rotation of +90 degrees about x, (x, y, z) -> (x, -z, y)
        rot = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
        vertices, normals = vertices @ rot.T, normals @ rot.T
    return vertices, faces, normals


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (the sum of the adjacent faces' cross products, normalised); a
    vertex of degenerate faces only gets +z."""
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(n, faces[:, k], cross)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(length > 1e-30, n / np.maximum(length, 1e-30), np.array([0.0, 0.0, 1.0]))


# ------------------------------------------------------------------------------------------------
# rendering


def camera_frame(cam: CameraOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(position, forward, right, up)`` of a camera, an orthonormal right-handed frame."""
    pos = np.asarray(cam.position, np.float64)
    f = np.asarray(cam.look_at, np.float64) - pos
    f /= np.linalg.norm(f)
    r = np.cross(f, np.asarray(cam.up, np.float64))
    r /= np.linalg.norm(r)
    return pos, f, r, np.cross(r, f)


def camera_rays(cam: CameraOptions) -> np.ndarray:
    """Directions (H, W, 3) (unnormalised, unit component along the view axis) through the pixel
    centres; row 0 is the top of the image."""
    _, f, r, u = camera_frame(cam)
    t = np.tan(np.radians(cam.fov) / 2)
    x = (2 * (np.arange(cam.width) + 0.5) / cam.width - 1) * t * cam.width / cam.height
    y = (1 - 2 * (np.arange(cam.height) + 0.5) / cam.height) * t
    return f + x[None, :, None] * r + y[:, None, None] * u


@dataclasses.dataclass(frozen=True)
class Render:
    """What one camera sees: per covered pixel (flat index ``row * width + col``) the shading normal,
    the view, the hit point and the triangle; ``hit`` marks every pixel whose ray hits the mesh."""

    width: int
    height: int
    pixel: np.ndarray  # (P,) int64, covered pixels
    normal: np.ndarray  # (P, 3)
    view: np.ndarray  # (P, 3)
    point: np.ndarray  # (P, 3)
    face: np.ndarray  # (P,)
    hit: np.ndarray  # (H * W,) bool


def _boxes(vertices, faces, cam):
    """Pixel bounding boxes (c0, c1, r0, r1 inclusive) of the triangles' projections, and which are kept."""
    pos, f, r, u = camera_frame(cam)
    d = vertices - pos
    z = d @ f
    t = np.tan(np.radians(cam.fov) / 2)
    W, H = cam.width, cam.height
    zs = np.maximum(z, 1e-12)
    col = ((d @ r) / (zs * t * W / H) + 1) / 2 * W - 0.5
    row = (1 - (d @ u) / (zs * t)) / 2 * H - 0.5
    zf, cf, rf = z[faces], col[faces], row[faces]
    near = 1e-9
    front = zf.max(axis=1) > near  # some part in front of the camera
    straddle = zf.min(axis=1) <= near  # the projection is unbounded: test the whole image
    c0 = np.where(straddle, 0, np.floor(cf.min(axis=1)) - 1)
    c1 = np.where(straddle, W - 1, np.ceil(cf.max(axis=1)) + 1)
    r0 = np.where(straddle, 0, np.floor(rf.min(axis=1)) - 1)
    r1 = np.where(straddle, H - 1, np.ceil(rf.max(axis=1)) + 1)
    c0, c1 = np.clip(c0, 0, W - 1).astype(np.int64), np.clip(c1, -1, W - 1).astype(np.int64)
    r0, r1 = np.clip(r0, 0, H - 1).astype(np.int64), np.clip(r1, -1, H - 1).astype(np.int64)
    wide, tall = c1 - c0 + 1, r1 - r0 + 1
    keep = front & (wide > 0) & (tall > 0) & (c1 >= 0) & (r1 >= 0)
    return c0, r0, np.where(keep, wide, 0), np.where(keep, tall, 0)


def candidates(vertices: np.ndarray, faces: np.ndarray, cameras) -> int:
    """The rasterizer's work for these cameras: (triangle, pixel) candidates summed over the cameras."""
    return int(sum(int(np.sum(w * h)) for _, _, w, h in (_boxes(vertices, faces, c) for c in cameras)))


def render(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray, cam: CameraOptions) -> Render:
    """Ray cast one camera: the nearest hit per pixel, its shading normal and view (see the module doc)."""
    pos, *_ = camera_frame(cam)
    W, H = cam.width, cam.height
    rays = camera_rays(cam).reshape(-1, 3)
    c0, r0, wide, tall = _boxes(vertices, faces, cam)
    area = wide * tall
    fids = np.nonzero(area)[0]
    v0 = vertices[faces[:, 0]]
    e1 = vertices[faces[:, 1]] - v0
    e2 = vertices[faces[:, 2]] - v0
    depth = np.full(W * H, np.inf)
    best_face = np.full(W * H, -1, np.int64)
    best_uv = np.zeros((W * H, 2))
    # chunks of whole triangles whose candidates sum to about CHUNK
    ends = np.cumsum(area[fids])
    cuts = np.searchsorted(ends, np.arange(CHUNK, int(ends[-1]) if len(ends) else 0, CHUNK), side="right")
    for sel in np.split(fids, np.unique(cuts)):  # a loop over chunks of candidates, never over pixels
        if len(sel) == 0:
            continue
        a = area[sel]
        face = np.repeat(sel, a)
        local = np.arange(int(a.sum())) - np.repeat(np.cumsum(a) - a, a)
        pix = (r0[face] + local // wide[face]) * W + c0[face] + local % wide[face]
        d = rays[pix]
        p = np.cross(d, e2[face])
        det = np.einsum("ij,ij->i", e1[face], p)
        ok = np.abs(det) > 1e-14
        inv = 1.0 / np.where(ok, det, 1.0)
        s = pos - v0[face]
        bu = np.einsum("ij,ij->i", s, p) * inv
        q = np.cross(s, e1[face])
        bv = np.einsum("ij,ij->i", d, q) * inv
        t = np.einsum("ij,ij->i", e2[face], q) * inv
        ok &= (bu >= 0) & (bv >= 0) & (bu + bv <= 1) & (t > 1e-9)
        pix, t, face, bu, bv = pix[ok], t[ok], face[ok], bu[ok], bv[ok]
        order = np.lexsort((t, pix))  # nearest first within each pixel
        pix, t, face, bu, bv = pix[order], t[order], face[order], bu[order], bv[order]
        first = np.concatenate([[True], pix[1:] != pix[:-1]]) if len(pix) else np.zeros(0, bool)
        pix, t, face, bu, bv = pix[first], t[first], face[first], bu[first], bv[first]
        nearer = t < depth[pix]
        pix = pix[nearer]
        depth[pix] = t[nearer]
        best_face[pix] = face[nearer]
        best_uv[pix] = np.stack([bu[nearer], bv[nearer]], -1)
    hit = best_face >= 0
    pix = np.nonzero(hit)[0]
    face = best_face[pix]
    bu, bv = best_uv[pix, 0:1], best_uv[pix, 1:2]
    point = pos + depth[pix, None] * rays[pix]
    tri = faces[face]
    n = (1 - bu - bv) * normals[tri[:, 0]] + bu * normals[tri[:, 1]] + bv * normals[tri[:, 2]]
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    view = pos - point
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    geometric = np.cross(e1[face], e2[face])
    back = np.einsum("ij,ij->i", geometric, view) < 0  # the triangle is seen from its back: two-sided
    n = np.where(back[:, None], -n, n)
    covered = np.einsum("ij,ij->i", n, view) > sampling.MIN_COS
    return Render(W, H, pix[covered], n[covered], view[covered], point[covered], face[covered], hit)


# ------------------------------------------------------------------------------------------------
# the scene: covered pixels of every camera, pairs drawn from them, image-space metrics


@dataclasses.dataclass(frozen=True, eq=False)
class Scene:
    """The covered pixels of every camera of a scene (camera-major, then row-major): their normals and
    views, the camera and the flat pixel index of each, and the cameras' image sizes."""

    normals: np.ndarray  # (P, 3) float32
    views: np.ndarray  # (P, 3) float32
    camera: np.ndarray  # (P,) int
    pixel: np.ndarray  # (P,) int, row * width + col
    shapes: tuple  # ((H, W), ...) per camera
    mesh: str = ""
    memo: dict = dataclasses.field(default_factory=dict, repr=False)

    def __len__(self) -> int:
        return int(self.normals.shape[0])

    @property
    def covered(self) -> tuple[int, ...]:
        """Covered pixels per camera."""
        return tuple(int(x) for x in np.bincount(self.camera, minlength=len(self.shapes)))

    def draw(self, count: int, seed: int) -> np.ndarray:
        """Indices of ``count`` covered pixels drawn uniformly over all cameras' covered pixels (without
        replacement up to the number of covered pixels, with it beyond), sorted; 0: every pixel once."""
        if count <= 0:
            return np.arange(len(self))
        rng = np.random.default_rng(seed)
        return np.sort(rng.choice(len(self), size=count, replace=count > len(self)))

    def pairs(self, count: int, seed: int) -> sampling.Grouped:
        """The (n, v) pairs of :meth:`draw`, grouped by normal (one view per normal)."""
        return self.grouped(self.draw(count, seed))

    def grouped(self, index: np.ndarray | None = None) -> sampling.Grouped:
        """The pairs of the pixels ``index`` (default: all covered pixels), as lighting pairs."""
        index = np.arange(len(self)) if index is None else index
        n = self.normals[index]
        return sampling.Grouped(n, self.views[index][:, None, :], np.ones((len(index), 1), bool))

    def exact(self, target) -> np.ndarray:
        """The target's values at every covered pixel (remembered per target object)."""
        key = ("exact", id(target))
        if key not in self.memo or self.memo[key][0] is not target:
            self.memo.clear()  # one target at a time: a refit's new target replaces the old values
            self.memo[key] = (target, np.asarray(evaluate_grouped(target, self.grouped()), np.float32))
        return self.memo[key][1]

    def values(self, result, quantized: bool = False, chunk: int = 65536) -> np.ndarray:
        """The factorization's values at every covered pixel."""
        a, b = jnp.asarray(self.normals), jnp.asarray(self.views)
        parts = [result.evaluate(a[i:i + chunk], b[i:i + chunk], quantized=quantized) for i in range(0, len(self), chunk)]
        return np.asarray(jnp.concatenate(parts, axis=0))

    def metrics(self, result, target, eps: float = 1e-5) -> dict:
        """Image-space metrics ``{float, quantized} -> metric dict`` of the factorization against the exact
        lighting over every covered pixel of every camera (the validation set's metric functions)."""
        if result.quantized is None:
            result = result.replace(quantized=result.encoded())
        a = jnp.asarray(self.normals)
        exact = target.shown(a, jnp.asarray(self.exact(target)))
        return {name: metric_values(target.shown(a, jnp.asarray(self.values(result, quant))), exact, eps)
                for name, quant in (("float", False), ("quantized", True))}

    def images(self, values: np.ndarray, background: float = 0.0) -> list[np.ndarray]:
        """Per-pixel ``values`` (P, 3) laid out as the cameras' images (H, W, 3), ``background`` elsewhere."""
        out = []
        for k, (h, w) in enumerate(self.shapes):
            img = np.full((h * w, 3), background, np.float32)
            sel = self.camera == k
            img[self.pixel[sel]] = values[sel]
            out.append(img.reshape(h, w, 3))
        return out


def build(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray, cameras, mesh: str = "") -> Scene:
    """Render every camera and keep the covered pixels (refuses an empty scene and too much work)."""
    work = candidates(vertices, faces, cameras)
    if work > MAX_CANDIDATES:
        raise HomofacError(f"sampling: the scene's triangles cover {work} (triangle, pixel) candidates in the "
                           f"cameras, more than {MAX_CANDIDATES}; use fewer or smaller cameras or a smaller mesh")
    renders = [render(vertices, faces, normals, c) for c in cameras]
    if not any(len(r.pixel) for r in renders):
        raise HomofacError(f"sampling: no camera sees the mesh {mesh or ''}".rstrip() + " (check position, look_at, fov)")
    return Scene(
        np.concatenate([r.normal for r in renders]).astype(np.float32),
        np.concatenate([r.view for r in renders]).astype(np.float32),
        np.concatenate([np.full(len(r.pixel), k) for k, r in enumerate(renders)]).astype(np.int64),
        np.concatenate([r.pixel for r in renders]).astype(np.int64),
        tuple((c.height, c.width) for c in cameras), mesh,
    )


def resolve_cameras(s: SamplingOptions) -> list[CameraOptions]:
    """The cameras of a scene sampling: its own, else those of its bundled scene."""
    if s.cameras:
        return list(s.cameras)
    if bundled_path(s.mesh) is not None and not Path(s.mesh).expanduser().exists():
        return bundled_cameras(s.mesh)
    raise HomofacError("sampling.cameras: a scene needs cameras (only bundled scenes bring their own)")


def fingerprint(s: SamplingOptions) -> str:
    """The sha256 of the mesh file a scene sampling reads (part of the samples' cache key)."""
    return hashlib.sha256(read_mesh_file(mesh_path(s.mesh))).hexdigest()


@functools.lru_cache(maxsize=8)
def _cached(path: str, mtime: int, size: int, up: str, cameras: str) -> Scene:
    vertices, faces, normals = load_mesh(path, up)
    cams = [validate(CameraOptions, c, "cameras") for c in json.loads(cameras)]
    return build(vertices, faces, normals, cams, path)


def load(s: SamplingOptions | dict) -> Scene:
    """The scene of a ``sampling.kind: scene`` (mesh loaded and cameras rendered once per process and
    file version; later calls with the same settings reuse it)."""
    s = validate(SamplingOptions, s, "sampling")
    if s.kind != "scene":
        raise HomofacError(f"sampling.kind is {s.kind}, not scene")
    p = mesh_path(s.mesh)
    st = check_regular(p, "a mesh")
    cams = json.dumps([c.model_dump() for c in resolve_cameras(s)], sort_keys=True)
    return _cached(str(p.resolve()), st.st_mtime_ns, st.st_size, s.mesh_up, cams)


__all__ = ["BUNDLED", "CHUNK", "FORMATS", "MAX_CANDIDATES", "MAX_FACES", "MAX_MESH_BYTES", "MAX_VERTICES", "Render",
           "Scene", "build", "bundled_cameras", "bundled_path", "camera_frame", "camera_rays", "candidates",
           "fingerprint", "load", "load_mesh", "mesh_path", "precount", "render", "resolve_cameras", "scenes_dir",
           "vertex_normals"]
