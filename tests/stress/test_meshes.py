"""Hostile mesh files: only regular files are read, with bounded reads, and the mesh is bounded by what
trimesh would build (triangulated polygons, glTF instances, ASCII PLY rows), not by a pre-count of lines.

Each case reproduces a fault of issue 40: a FIFO or a device as the mesh (a hang, or /dev/zero read
without end by the scene's fingerprint), a FIFO as a glTF image or buffer, a directory as the mesh
(IsADirectoryError, exit 1), one long OBJ ``f`` line, glTF nodes instancing one mesh many times, an
ASCII PLY with a small header and millions of junk lines. A fuzz of random bytes, truncations and
FIFOs asserts each file loads within the limits or is refused with a one-line HomofacError.
"""

from __future__ import annotations

import base64
import json
import os
import signal
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from homofac.app import config as cfgmod
from homofac.app.cli import fit_main as main
from homofac.brdf.measured import load_merl
from homofac.light import load_environment
from homofac.output import load
from homofac.errors import HomofacError
from homofac.fit import scene
from homofac.fit.options import SamplingOptions
from homofac.options import validate

trimesh = pytest.importorskip("trimesh")

PY = sys.executable
TRIANGLE_OBJ = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\n"


@contextmanager
def within(seconds: float):
    """Fail (TimeoutError) instead of hanging: a blocked open or read is interrupted by SIGALRM."""

    def alarm(*_):
        raise TimeoutError(f"still running after {seconds} s")

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def _one_line_refusal(fn, *needles):
    with within(10), pytest.raises(HomofacError) as e:
        fn()
    msg = str(e.value)
    assert "\n" not in msg
    for n in needles:
        assert n in msg, msg
    return msg


def _gltf(path: Path, triangles: int, nodes: int, image: str | None = None, buffer: str | None = None) -> Path:
    """A glTF of one mesh of ``triangles`` triangles (indices into 3 vertices) instanced by ``nodes`` nodes."""
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32).tobytes()
    idx = np.tile(np.arange(3, dtype=np.uint32), triangles).tobytes()
    blob = pos + idx
    uri = buffer or "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": list(range(nodes))}],
        "nodes": [{"mesh": 0, "translation": [0, 0, float(k)]} for k in range(nodes)],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"byteLength": len(blob), "uri": uri}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(pos)},
                        {"buffer": 0, "byteOffset": len(pos), "byteLength": len(idx)}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0, 0, 0], "max": [1, 1, 0]},
                      {"bufferView": 1, "componentType": 5125, "count": 3 * triangles, "type": "SCALAR"}],
    }
    if image is not None:
        doc["images"] = [{"uri": image}]
        doc["textures"] = [{"source": 0}]
        doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
        doc["meshes"][0]["primitives"][0]["material"] = 0
    path.write_text(json.dumps(doc))
    return path


# --------------------------------------------------------------------------------------------------
# only regular files


def test_fifos_devices_and_directories_are_refused_in_one_line_without_hanging(tmp_path):
    fifo = tmp_path / "mesh.obj"
    os.mkfifo(fifo)
    _one_line_refusal(lambda: scene.load_mesh(fifo), str(fifo), "FIFO")
    s = validate(SamplingOptions, {"kind": "scene", "mesh": str(fifo), "cameras": [{"position": [0, 0, 3], "up": [0, 1, 0]}]},
                 "sampling")
    _one_line_refusal(lambda: scene.fingerprint(s), "FIFO")
    _one_line_refusal(lambda: scene.load(s), "FIFO")
    # /dev/zero: the fingerprint read it without end (4.5 GB in 5 s) before any check
    z = validate(SamplingOptions, {"kind": "scene", "mesh": "/dev/zero", "cameras": [{"position": [0, 0, 3], "up": [0, 1, 0]}]},
                 "sampling")
    _one_line_refusal(lambda: scene.fingerprint(z), "/dev/zero", "character device")
    d = tmp_path / "dir.obj"
    d.mkdir()
    _one_line_refusal(lambda: scene.load_mesh(d), "directory")
    # a FIFO named by a glTF, as its image (trimesh's resolver blocked on it) or as its buffer
    fifo_png = tmp_path / "tex.png"
    os.mkfifo(fifo_png)
    _one_line_refusal(lambda: scene.load_mesh(_gltf(tmp_path / "img.gltf", 1, 1, image="tex.png")), "FIFO")
    fifo_bin = tmp_path / "buf.bin"
    os.mkfifo(fifo_bin)
    _one_line_refusal(lambda: scene.load_mesh(_gltf(tmp_path / "buf.gltf", 1, 1, buffer="buf.bin")), "FIFO")
    os.mkfifo(tmp_path / "m.mtl")  # an OBJ's material library as a FIFO: materials are not read
    (tmp_path / "mtl.obj").write_bytes(b"mtllib m.mtl\nusemtl x\n" + TRIANGLE_OBJ)
    with within(10):
        assert len(scene.load_mesh(tmp_path / "mtl.obj")[1]) == 1
    # the same glTF with a real image beside it loads (materials are not read)
    (tmp_path / "real.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 32)
    v, f, _ = scene.load_mesh(_gltf(tmp_path / "ok.gltf", 2, 2, image="real.png"))
    assert len(f) == 4


def test_a_directory_or_a_fifo_as_the_mesh_exits_2_with_one_line(tmp_path, capsys):
    (tmp_path / "dir.obj").mkdir()
    os.mkfifo(tmp_path / "fifo.obj")
    for mesh, what in (("dir.obj", "directory"), ("fifo.obj", "FIFO")):
        cfg = {"target": {"kind": "lighting", "brdf": {"model": "lambert"},
                          "environment": {"file": "forest", "resolution": 4}},
               "texture_size": 8, "sampling": {"kind": "scene", "mesh": mesh, "cameras": [{"position": [0, 0, 3], "up": [0, 1, 0]}]},
               "output": {"dir": str(tmp_path / "out"), "preview": False}}
        (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
        with within(60):
            code = main([str(tmp_path / "c.yaml"), "--quiet"])
        err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
        assert code == 2, err
        assert len(err) == 1 and err[0].startswith("homofac: error: ") and mesh in err[0] and what in err[0], err
        assert not (tmp_path / "out").exists()
    os.mkfifo(tmp_path / "env.exr")  # a FIFO as the environment hung in the header read
    cfg = {"target": {"kind": "lighting", "brdf": {"model": "lambert"}, "environment": {"file": "env.exr", "resolution": 4}},
           "texture_size": 8, "output": {"dir": str(tmp_path / "out"), "preview": False}}
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    with within(60):
        code = main([str(tmp_path / "c.yaml"), "--quiet"])
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert code == 2 and len(err) == 1 and "env.exr" in err[0] and "FIFO" in err[0], err


def test_fifos_as_environment_merl_config_and_output_files_are_refused(tmp_path):
    for name in ("env.exr", "env.hdr", "m.binary", "c.yaml"):
        os.mkfifo(tmp_path / name)
    _one_line_refusal(lambda: load_environment(str(tmp_path / "env.exr"), resolution=4), "FIFO")
    _one_line_refusal(lambda: load_environment(str(tmp_path / "env.hdr"), resolution=4), "FIFO")
    _one_line_refusal(lambda: load_merl(tmp_path / "m.binary"), "FIFO")
    _one_line_refusal(lambda: cfgmod.load(tmp_path / "c.yaml"), "FIFO")
    out = tmp_path / "out"
    out.mkdir()
    os.mkfifo(out / "factorization.json")
    _one_line_refusal(lambda: load(out), "FIFO")


# --------------------------------------------------------------------------------------------------
# bounded by what is parsed

ATTACKS = r"""
import json, resource, sys
import trimesh
from homofac.errors import HomofacError
from homofac.fit import scene
def hwm():
    return next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM:")) * 1024
def vm():
    return next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmSize:")) * 1024
# an address-space cap 2 GiB above what is mapped now: an unbounded parse fails (MemoryError) instead of
# taking the shared machine's memory
resource.setrlimit(resource.RLIMIT_AS, (vm() + (2 << 30), resource.RLIM_INFINITY))
base = hwm()
out = {}
for path in sys.argv[1:]:
    try:
        v, f, n = scene.load_mesh(path)
        out[path] = f"loaded {len(f)}"
    except HomofacError as e:
        out[path] = "refused: " + str(e)
    except BaseException as e:
        out[path] = f"{type(e).__name__}: {e}"
print(json.dumps({"results": out, "grew": hwm() - base}))
"""


def test_meshes_are_bounded_by_what_trimesh_would_build(tmp_path):
    """One long OBJ face line (3 M corners, 6 MB: 190 bytes of memory per file byte), a glTF mesh of
    200 k triangles instanced by 60 nodes (12 M triangles), an ASCII PLY whose small header is followed
    by 8 M junk lines: each is refused before trimesh parses it, and the process grows by little."""
    obj = tmp_path / "long.obj"
    obj.write_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf " + b"1 2 3 " * 1_000_000 + b"\n")
    gltf = _gltf(tmp_path / "nodes.gltf", 200_000, 60)
    ply = tmp_path / "junk.ply"
    ply.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                    b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n" + b"\n" * 8_000_000)
    r = subprocess.run([PY, "-c", ATTACKS, str(obj), str(gltf), str(ply)], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    res = out["results"]
    assert res[str(obj)].startswith("refused:") and "2999998 faces" in res[str(obj)], res
    assert res[str(gltf)].startswith("refused:") and "faces, more than" in res[str(gltf)], res
    assert res[str(ply)] == "loaded 1", res  # the junk beyond the declared rows is never parsed
    assert out["grew"] < 300 << 20, out  # unbounded: gigabytes (or MemoryError under the cap)


def test_counts_follow_triangulation_instancing_and_declared_rows(tmp_path):
    quads = tmp_path / "q.obj"
    quads.write_bytes(b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\nf 1 2 3 4 1 2\n")
    assert scene.precount(quads, quads.read_bytes()) == (4, 2 + 4)
    assert len(scene.load_mesh(quads)[1]) == 6  # trimesh fans them the same way
    g = _gltf(tmp_path / "g.gltf", 5, 3)
    assert scene.precount(g, g.read_bytes()) == (9, 15)
    assert len(scene.load_mesh(g)[1]) == 15
    doc = json.loads(g.read_text())  # a node tree: root -> 2 children -> each the mesh node twice
    doc["nodes"] = [{"children": [1, 2]}, {"children": [3]}, {"children": [3]}, {"mesh": 0}]
    doc["scenes"] = [{"nodes": [0]}]
    g.write_text(json.dumps(doc))
    assert scene.precount(g, g.read_bytes())[1] == 2 * 5
    b = tmp_path / "b.ply"  # a binary PLY of triangles: counted exactly from its corner counts
    trimesh.creation.icosphere(subdivisions=3).export(b, encoding="binary")
    assert scene.precount(b, b.read_bytes()) == (642, 1280)
    doc["nodes"][3]["children"] = [0]  # a cycle
    g.write_text(json.dumps(doc))
    _one_line_refusal(lambda: scene.load_mesh(g), "cycle")


# --------------------------------------------------------------------------------------------------
# fuzz: random bytes, truncations of valid files, FIFOs


def _valid_files(d: Path) -> dict[str, bytes]:
    m = trimesh.creation.icosphere(subdivisions=1)
    out = {}
    for ext, kw in ((".obj", {}), (".ply", {"encoding": "ascii"}), (".glb", {})):
        p = d / f"valid{ext}"
        m.export(p, **kw)
        out[ext] = p.read_bytes()
    p = d / "binary.ply"
    m.export(p, encoding="binary")
    out["binary.ply"] = p.read_bytes()
    out[".gltf"] = _gltf(d / "v.gltf", 4, 2).read_bytes()
    return out


@pytest.fixture(scope="module")
def valid(tmp_path_factory):
    return _valid_files(tmp_path_factory.mktemp("valid"))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(kind=st.sampled_from([".obj", ".ply", ".glb", ".gltf", "binary.ply"]),
       how=st.sampled_from(["random", "truncate", "flip", "fifo"]),
       cut=st.floats(0, 1), noise=st.binary(max_size=64), seed=st.integers(0, 2**31))
def test_fuzz_mesh_files_load_within_limits_or_are_refused(valid, tmp_path_factory, kind, how, cut, noise, seed):
    d = tmp_path_factory.mktemp("fuzz")
    ext = ".ply" if kind == "binary.ply" else kind
    p = d / f"m{ext}"
    data = valid[kind]
    if how == "random":
        p.write_bytes(noise)
    elif how == "truncate":
        p.write_bytes(data[: int(cut * len(data))])
    elif how == "flip":
        b = bytearray(data)
        rng = np.random.default_rng(seed)
        for i in rng.integers(0, len(b), 8):
            b[i] = int(rng.integers(0, 256))
        p.write_bytes(bytes(b))
    else:
        os.mkfifo(p)
    try:
        with within(20):
            v, f, n = scene.load_mesh(p)
    except HomofacError as e:
        assert "\n" not in str(e) and str(p) in str(e)
        return
    assert 0 < len(f) <= scene.MAX_FACES and len(v) <= scene.MAX_VERTICES
    assert np.all(np.isfinite(v)) and f.min() >= 0 and f.max() < len(v)
    assert n.shape == v.shape


def test_the_preview_mesh_goes_through_the_same_checks(tmp_path):
    """``homofac.preview --mesh`` / the viewer loaded any path with trimesh, unchecked."""
    from homofac.gl.engine import load_mesh

    os.mkfifo(tmp_path / "fifo.obj")
    _one_line_refusal(lambda: load_mesh(str(tmp_path / "fifo.obj")), "FIFO")
    obj = tmp_path / "long.obj"
    obj.write_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf " + b"1 2 3 " * 400_000 + b"\n")
    _one_line_refusal(lambda: load_mesh(str(obj)), "faces, more than")
    tet = tmp_path / "tet.obj"
    tet.write_text("v 0 0 1\nv 1 0 -0.5\nv -0.5 0.8 -0.5\nv -0.5 -0.8 -0.5\nf 1 2 3\nf 1 3 4\nf 1 4 2\nf 2 4 3\n")
    m = load_mesh(str(tet))
    assert len(m.faces) == 4 and np.allclose(np.linalg.norm(m.normals, axis=1), 1, atol=1e-5)
