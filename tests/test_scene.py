"""Scene-aware sampling (issue 15, part 3): the rasterizer against analytic values, coverage-weighted
and seeded pair draws, image-space scene metrics, the bundled demo scene, one-line refusals."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import homofac as hf
from homofac.errors import HomofacError
from homofac.fit import scene
from homofac.fit.draw import draw_pairs
from homofac.fit.metrics import NAMES, metrics
from homofac.fit.options import CameraOptions, SamplingOptions
from homofac.options import validate

trimesh = pytest.importorskip("trimesh")

ROOT = Path(__file__).resolve().parents[1]


def _cam(**kw) -> CameraOptions:
    return validate(CameraOptions, kw, "camera")


@pytest.fixture(scope="module")
def sphere_file(tmp_path_factory):
    """A unit icosphere (5120 triangles) centred at (0.3, -0.2, 0.1), as an OBJ file."""
    p = tmp_path_factory.mktemp("mesh") / "sphere.obj"
    m = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    m.apply_translation([0.3, -0.2, 0.1])
    m.export(p)
    return p


@pytest.fixture(scope="module")
def target():
    env = hf.light.load_environment("forest", resolution=8)
    brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    return hf.light.lighting_target(brdf, env)


# --------------------------------------------------------------------------------------------------
# the rasterizer


def test_sphere_normals_views_and_silhouette_match_the_analytic_sphere(sphere_file):
    centre, radius = np.array([0.3, -0.2, 0.1]), 1.0
    v, f, n = scene.load_mesh(sphere_file)
    D, fov, H, W = 4.0, 40.0, 120, 160
    pos = centre + np.array([0.0, -D, 0.0])
    cam = _cam(position=pos.tolist(), look_at=centre.tolist(), fov=fov, width=W, height=H)
    r = scene.render(v, f, n, cam)
    # silhouette: a disk of angular radius asin(r / D), projected through the pinhole
    expected = np.pi * (np.tan(np.arcsin(radius / D)) / np.tan(np.radians(fov) / 2) * H / 2) ** 2
    assert abs(r.hit.sum() / expected - 1) < 0.02, (r.hit.sum(), expected)
    assert len(r.pixel) >= 0.97 * r.hit.sum()  # silhouette pixels with n.v <= 1e-4 are the only ones dropped
    # normals: the sphere's (hit - centre) / radius up to the tessellation (edges of about 4 degrees)
    analytic = (r.point - centre) / radius
    assert np.all(np.abs(np.linalg.norm(r.point - centre, axis=1) - radius) < 3e-3)
    cos = np.sum(r.normal * analytic / np.linalg.norm(analytic, axis=1, keepdims=True), axis=1)
    assert cos.min() > 0.999 and np.allclose(np.linalg.norm(r.normal, axis=1), 1, atol=1e-6)
    # views: unit vectors from the hit to the camera, facing the normals
    want = (pos - r.point) / np.linalg.norm(pos - r.point, axis=1, keepdims=True)
    np.testing.assert_allclose(r.view, want, atol=1e-9)
    assert np.all(np.sum(r.normal * r.view, axis=1) > 1e-4)
    # the centre pixel looks straight at the sphere: n = v = -y
    rows, cols = np.divmod(r.pixel, W)
    mid = np.argmin((rows - (H - 1) / 2) ** 2 + (cols - (W - 1) / 2) ** 2)
    np.testing.assert_allclose(r.normal[mid], [0, -1, 0], atol=0.02)
    np.testing.assert_allclose(r.view[mid], [0, -1, 0], atol=0.01)


def test_image_orientation_up_is_row_zero_and_right_is_plus_x(sphere_file):
    """A camera on -y looking at +y, up +z: the sphere shifted right (+x) and up (+z) appears in the
    right columns and top rows (the pinhole's image is not mirrored)."""
    v, f, n = scene.load_mesh(sphere_file)
    cam = _cam(position=[0.3 - 1.2, -6.0, 0.1 - 0.9], look_at=[0.3 - 1.2, 0.0, 0.1 - 0.9], width=80, height=60)
    r = scene.render(v, f, n, cam)
    rows, cols = np.divmod(r.pixel, 80)
    assert cols.mean() > 45 and rows.mean() < 25


def test_backfaces_are_flipped_to_face_the_camera(tmp_path):
    """A single triangle seen from behind: two-sided, its normal flipped towards the camera."""
    p = tmp_path / "tri.obj"
    p.write_text("v -1 -1 0\nv 1 -1 0\nv 0 1 0\nf 1 2 3\n")  # counter-clockwise from +z: normal +z
    v, f, n = scene.load_mesh(p)
    below = scene.render(v, f, n, _cam(position=[0, 0, -3], look_at=[0, 0, 0], up=[0, 1, 0], width=20, height=20))
    above = scene.render(v, f, n, _cam(position=[0, 0, 3], look_at=[0, 0, 0], up=[0, 1, 0], width=20, height=20))
    assert len(below.pixel) == len(above.pixel) > 20
    np.testing.assert_allclose(below.normal, np.tile([0, 0, -1.0], (len(below.pixel), 1)), atol=1e-9)
    np.testing.assert_allclose(above.normal, np.tile([0, 0, 1.0], (len(above.pixel), 1)), atol=1e-9)


def test_nearest_hit_wins_and_chunking_changes_nothing(sphere_file, monkeypatch):
    v, f, n = scene.load_mesh(sphere_file)
    cam = _cam(position=[0.3, -4.2, 0.1], look_at=[0.3, -0.2, 0.1], width=64, height=48)
    whole = scene.render(v, f, n, cam)
    assert np.all(whole.point[:, 1] < -0.2 + 1e-9)  # the front half only (the z-buffer keeps the nearest)
    monkeypatch.setattr(scene, "CHUNK", 997)
    chunked = scene.render(v, f, n, cam)
    np.testing.assert_array_equal(whole.pixel, chunked.pixel)
    np.testing.assert_allclose(whole.normal, chunked.normal, atol=1e-12)


def test_the_demo_scene_is_bundled_small_and_seen_by_both_cameras():
    path = scene.mesh_path("demo")
    assert path.parent == scene.scenes_dir() and path.stat().st_size < 64_000
    cams = scene.bundled_cameras("demo")
    assert len(cams) == 2
    sc = scene.load({"kind": "scene", "mesh": "demo"})
    assert len(sc) == sum(sc.covered) and all(c > 0.4 * 160 * 120 for c in sc.covered)
    np.testing.assert_allclose(np.linalg.norm(sc.normals, axis=1), 1, atol=1e-5)
    assert np.all(np.sum(sc.normals * sc.views, axis=1) > 1e-4)
    # the ground plane's pixels: normal +z
    assert np.mean(sc.normals[:, 2] > 0.9999) > 0.3


def test_the_demo_generator_reproduces_the_bundled_files(tmp_path):
    subprocess.run([sys.executable, str(ROOT / "tools" / "make_demo_scene.py"), str(tmp_path)], check=True,
                   capture_output=True, timeout=60)
    for name in ("demo.obj", "demo.json"):
        assert (tmp_path / name).read_bytes() == (scene.scenes_dir() / name).read_bytes()


# --------------------------------------------------------------------------------------------------
# drawing pairs


def test_pairs_are_drawn_by_coverage_and_reproducible_from_the_seed():
    sc = scene.load({"kind": "scene", "mesh": "demo"})
    share = np.array(sc.covered) / len(sc)
    idx = sc.draw(200_000, 3)  # more than the covered pixels: with replacement
    drawn = np.bincount(sc.camera[idx], minlength=2) / len(idx)
    np.testing.assert_allclose(drawn, share, atol=0.01)
    # every covered pixel equally likely: counts per pixel are Poisson-like around the mean
    hits = np.bincount(idx, minlength=len(sc))
    assert abs(hits.var() / hits.mean() - 1) < 0.1  # multinomial with equal probabilities: variance ~ mean
    assert abs(np.mean(hits == 0) - np.exp(-hits.mean())) < 1e-3
    few = sc.draw(5000, 3)
    assert len(np.unique(few)) == 5000  # without replacement up to the pixel count
    np.testing.assert_array_equal(few, sc.draw(5000, 3))
    assert not np.array_equal(few, sc.draw(5000, 4))
    np.testing.assert_array_equal(sc.draw(0, 7), np.arange(len(sc)))  # count 0: every pixel once


def test_draw_pairs_train_and_validation_come_from_the_scene_with_their_seeds():
    s = validate(SamplingOptions, {"kind": "scene", "mesh": "demo", "count": 3000, "validation": 1000, "seed": 5},
                 "sampling")
    train, val, groups, vgroups = draw_pairs("lighting", "NR", s)
    assert len(train) == 3000 and len(val) == 1000 and groups.normals.shape == (3000, 3)
    sc = scene.load(s)
    np.testing.assert_array_equal(train.a, sc.normals[sc.draw(3000, 5)])
    np.testing.assert_array_equal(train.b, sc.views[sc.draw(3000, 5)])
    np.testing.assert_array_equal(val.a, sc.normals[sc.draw(1000, 6)])
    again = draw_pairs("lighting", "NR", s)
    np.testing.assert_array_equal(again[0].a, train.a)
    with pytest.raises(HomofacError, match="lighting targets"):
        draw_pairs("brdf", "IV", s)


# --------------------------------------------------------------------------------------------------
# the pipeline: scene metrics, saved record, refit


@pytest.fixture(scope="module")
def fac(target):
    return hf.fit.factorize(target, "NR", texture_size=8, solver={"max_iterations": 20},
                            sampling={"kind": "scene", "mesh": "demo", "validation": 2000, "cache": False})


@pytest.mark.xla_optimized  # its fit and exact values run on every covered pixel: at -O0, 18 s CPU against 11.5 s
def test_scene_metrics_are_present_and_equal_the_metrics_of_every_covered_pixel(fac, target):
    sc = scene.load({"kind": "scene", "mesh": "demo"})
    m = fac.metrics["scene"]
    assert set(m) == {"float", "quantized"} and set(m["float"]) == set(NAMES)
    assert fac.counts["scene_pixels"] == len(sc) and fac.counts["train"] == len(sc)
    exact = np.asarray(hf.fit.evaluate_grouped(target, sc.grouped()))
    approx = np.asarray(fac.evaluate(sc.normals, sc.views))
    want = metrics(approx, exact)
    for k in NAMES:
        assert m["float"][k] == pytest.approx(want[k], rel=1e-5, abs=1e-7)
    # count 0 trains on every covered pixel once, so the training metrics are the scene's
    for k in NAMES:
        assert fac.metrics["train"]["float"][k] == pytest.approx(m["float"][k], rel=1e-4, abs=1e-7)
    assert 0 < m["float"]["nrmse"] < 1 and m["quantized"]["nrmse"] >= 0.9 * m["float"]["nrmse"]
    imgs = sc.images(approx)
    assert [i.shape for i in imgs] == [(120, 160, 3)] * 2


def test_scene_metrics_are_saved_with_the_run(fac, tmp_path):
    out = tmp_path / "out"
    fac.save(out)
    doc = json.loads((out / "factorization.json").read_text())
    assert doc["metrics"]["scene"]["float"]["nrmse"] == pytest.approx(fac.metrics["scene"]["float"]["nrmse"])
    back = hf.output.load(out)
    assert back.metrics["scene"]["quantized"]["rms"] == pytest.approx(fac.metrics["scene"]["quantized"]["rms"])


@pytest.mark.slow
def test_a_refit_of_a_scene_sampled_fit_measures_the_scene_too(target):
    s = {"kind": "scene", "mesh": "demo", "count": 3000, "validation": 500, "cache": False}
    first = hf.fit.factorize(target, "NR", texture_size=8, sampling=s)
    env = hf.light.load_environment("city", resolution=8)
    r = hf.fit.refit(first, environment=env)
    full = hf.fit.factorize(hf.light.lighting_target(target.fn.brdf, env), "NR", texture_size=8, sampling=s)
    assert r.counts["scene_pixels"] == full.counts["scene_pixels"] == len(scene.load(s))
    for split in ("validation", "scene"):
        a, b = r.metrics[split]["float"]["nrmse"], full.metrics[split]["float"]["nrmse"]
        assert abs(a / b - 1) < 0.01, (split, a, b)
    assert r.metrics["scene"] != first.metrics["scene"]  # measured for the new environment


@pytest.mark.slow
def test_sums_of_products_take_scene_samples(target):
    fac = hf.fit.factorize(target, "NR", texture_size=8, terms=1, diffuse="exact",
                           advanced={"linear": {"method": "levenberg_marquardt", "iterations": 3,
                                                "inner_iterations": 20}},
                           sampling={"kind": "scene", "mesh": "demo", "count": 4000, "validation": 500,
                                     "cache": False})
    assert fac.counts["train"] == 4000 and np.isfinite(fac.metrics["scene"]["float"]["nrmse"])
    assert fac.metrics["scene"]["float"]["nrmse"] < 1


def test_a_scene_config_validates_like_the_python_api():
    cfg = hf.app.config.parse({"target": {"kind": "lighting", "brdf": {"model": "lambert"},
                                          "environment": {"file": "forest"}},
                               "sampling": {"kind": "scene", "mesh": "demo", "count": 1000,
                                            "cameras": [{"position": [0, -3, 1], "width": 32, "height": 24}]}})
    assert cfg.sampling.cameras[0].look_at == [0.0, 0.0, 0.0] and cfg.sampling.cameras[0].fov == 40.0


# --------------------------------------------------------------------------------------------------
# refusals: one line each


@pytest.mark.parametrize("sampling, match", [
    ({"kind": "scene"}, "needs a mesh"),
    ({"kind": "texels", "mesh": "demo"}, "for kind: scene"),
    ({"kind": "scene", "mesh": "demo", "cameras": []}, "cameras"),
    ({"kind": "scene", "mesh": "demo", "cameras": [{"position": [1, 2, 3], "look_at": [1, 2, 3]}]}, "look_at equals"),
    ({"kind": "scene", "mesh": "demo", "cameras": [{"position": [0, 0, 3]}]}, "parallel"),
    ({"kind": "scene", "mesh": "demo", "cameras": [{"position": [0, -3, 1], "width": 0}]}, "width"),
    ({"kind": "scene", "mesh": "demo", "cameras": [{"position": [0, -3, 1], "width": 4096}]}, "width"),
    ({"kind": "scene", "mesh": "demo", "cameras": [{"position": [0, -3, 1], "fov": 180}]}, "fov"),
    ({"kind": "scene", "mesh": "demo", "cameras": [{"position": [0, -3, float("nan")]}]}, "position"),
    ({"kind": "scene", "mesh": "demo", "cameras": [{"position": [0, -3]}]}, "position"),
    ({"kind": "scene", "mesh": "demo", "cameras": [{"position": [0, -3, 1], "width": 2048, "height": 2048}] * 2},
     "pixels together"),
    ({"kind": "scene", "mesh": "demo", "cameras": [{"position": [0, -3, 1], "zoom": 2}]}, "zoom"),
])
def test_bad_scene_options_are_refused_in_one_line(target, sampling, match):
    with pytest.raises(HomofacError, match=match) as e:
        hf.fit.factorize(target, "NR", texture_size=8, sampling=sampling)
    assert "\n" not in str(e.value)


def _refused(path, match, **kw):
    with pytest.raises(HomofacError, match=match) as e:
        scene.load_mesh(path, **kw)
    assert "\n" not in str(e.value) and str(path) in str(e.value)


def test_bad_mesh_files_are_refused_in_one_line(tmp_path, monkeypatch, sphere_file):
    _refused(tmp_path / "missing.obj", "no such mesh file")
    (tmp_path / "m.stl").write_text("solid x\n")
    _refused(tmp_path / "m.stl", r"\.obj, \.ply")
    (tmp_path / "garbage.obj").write_bytes(b"\x00\xff not a mesh \n" * 10)
    _refused(tmp_path / "garbage.obj", "no triangles|not a readable")
    (tmp_path / "bad.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
                                       b"property float x\nend_header\n\x00\x01")
    _refused(tmp_path / "bad.ply", "not a readable|no triangles")
    (tmp_path / "noheader.ply").write_bytes(b"hello")
    _refused(tmp_path / "noheader.ply", "not a PLY file")
    (tmp_path / "nan.obj").write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    _refused(tmp_path / "nan.obj", "non-finite")
    (tmp_path / "index.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    with pytest.raises(HomofacError) as e:  # trimesh may drop the face or fail: either is one line
        scene.load_mesh(tmp_path / "index.obj")
    assert "\n" not in str(e.value)
    (tmp_path / "bad.gltf").write_text('{"buffers": [{"uri": "../../etc/passwd", "byteLength": 4}]}')
    _refused(tmp_path / "bad.gltf", "not a file beside it")
    (tmp_path / "bad.glb").write_bytes(b"glTF" + b"\x00" * 30)
    _refused(tmp_path / "bad.glb", "JSON chunk")


def test_caps_are_checked_before_trimesh_reads_the_file(tmp_path, monkeypatch, sphere_file):
    def boom(*a, **k):
        raise AssertionError("trimesh.load must not be called")

    monkeypatch.setattr(trimesh, "load", boom)
    monkeypatch.setattr(scene, "MAX_VERTICES", 1000)
    _refused(sphere_file, "2562 vertices, more than 1000")
    monkeypatch.setattr(scene, "MAX_VERTICES", 10**6)
    monkeypatch.setattr(scene, "MAX_FACES", 100)
    _refused(sphere_file, "5120 faces, more than 100")
    ply = tmp_path / "big.ply"  # a small file declaring a huge mesh in its header
    ply.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 900000000\nproperty float x\nend_header\n")
    monkeypatch.setattr(scene, "MAX_FACES", 10**6)
    _refused(ply, "900000000 vertices")
    monkeypatch.setattr(scene, "MAX_MESH_BYTES", 1000)
    _refused(sphere_file, "bytes, more than")


def test_a_glb_with_y_up_is_turned_to_z_up(tmp_path):
    m = trimesh.creation.box(extents=[1.0, 2.0, 3.0])
    p = tmp_path / "box.glb"
    m.export(p)
    v, f, n = scene.load_mesh(p, up="y")
    np.testing.assert_allclose(v.max(axis=0) - v.min(axis=0), [1.0, 3.0, 2.0], atol=1e-6)
    assert len(f) == 12 and np.allclose(np.linalg.norm(n, axis=1), 1)


def test_scenes_no_camera_sees_and_too_much_work_are_refused(sphere_file, monkeypatch):
    v, f, n = scene.load_mesh(sphere_file)
    away = _cam(position=[0.3, -4.0, 0.1], look_at=[0.3, -8.0, 0.1], width=16, height=12)
    with pytest.raises(HomofacError, match="no camera sees the mesh"):
        scene.build(v, f, n, [away])
    monkeypatch.setattr(scene, "MAX_CANDIDATES", 1000)
    with pytest.raises(HomofacError, match="candidates"):
        scene.build(v, f, n, [_cam(position=[0.3, -4.0, 0.1], look_at=[0.3, 0, 0.1])])


@pytest.mark.slow
def test_the_cli_refuses_a_bad_mesh_in_one_line(tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "c.yaml").write_text(
        "target: {kind: lighting, brdf: {model: lambert}, environment: {file: forest, resolution: 4}}\n"
        "texture_size: 8\nsampling: {kind: scene, mesh: m.obj, cameras: [{position: [0, 0, 3], up: [0, 1, 0]}]}\n"
        f"output: {{dir: {tmp_path / 'out'}}}\n")
    r = subprocess.run([sys.executable, "-m", "homofac.fit", str(tmp_path / "c.yaml")], capture_output=True,
                       text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 2, r.stderr[-2000:]
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert lines[-1].startswith("homofac: error: ") and "m.obj" in lines[-1] and "non-finite" in lines[-1]


def test_the_documented_scene_config_is_valid(tmp_path):
    text = (ROOT / "docs" / "config.md").read_text().split("## Scene-aware sampling", 1)[1]
    block = text.split("```yaml\n", 1)[1].split("```", 1)[0]
    (tmp_path / "scene.yaml").write_text(block)
    cfg, base = hf.app.config.load(tmp_path / "scene.yaml")
    assert cfg.sampling.kind == "scene" and cfg.sampling.mesh == "demo" and len(cfg.sampling.cameras) == 2
    assert cfg.sampling.cameras == scene.bundled_cameras("demo")  # the example spells out the demo's cameras
    (tmp_path / "scene.yaml").write_text(block.replace("mesh: demo ", "mesh: m.obj "))
    (tmp_path / "m.obj").write_text("v 0 0 0\n")
    assert hf.app.config.load(tmp_path / "scene.yaml")[0].sampling.mesh == str(tmp_path / "m.obj")


@pytest.mark.slow
def test_a_material_library_on_scene_samples_measures_each_member_on_the_scene(fac, target):
    other = hf.light.lighting_target(hf.brdf.ggx(kd=0.2, ks=0.8, roughness=0.6, f0=(0.04, 0.04, 0.04)), target.fn.env)
    lib = hf.fit.factorize_many([target, other], "NR", texture_size=8,
                                sampling={"kind": "scene", "mesh": "demo", "validation": 2000, "cache": False})
    assert [r.counts["scene_pixels"] for r in lib] == [fac.counts["scene_pixels"]] * 2
    a, b = lib[0].metrics["scene"]["float"]["nrmse"], fac.metrics["scene"]["float"]["nrmse"]
    assert abs(a / b - 1) < 0.01, (a, b)
    sc = scene.load({"kind": "scene", "mesh": "demo"})
    assert lib[1].metrics["scene"] == sc.metrics(lib[1], other)


def test_scene_samples_are_cached_by_mesh_content(target, tmp_path, monkeypatch, sphere_file):
    monkeypatch.setenv("HOMOFAC_CACHE_DIR", str(tmp_path / "cache"))
    mesh = tmp_path / "s.obj"
    mesh.write_bytes(sphere_file.read_bytes())
    s = {"kind": "scene", "mesh": str(mesh), "count": 300, "validation": 50,
         "cameras": [{"position": [0.3, -4.0, 0.1], "look_at": [0.3, -0.2, 0.1], "width": 32, "height": 24}]}
    logs = []
    first = hf.fit.draw_samples(target, "NR", s, log=logs.append)
    again = hf.fit.draw_samples(target, "NR", s, log=logs.append)
    assert any("from cache" in m for m in logs) and np.array_equal(first.y, again.y)
    mesh.write_text(mesh.read_text() + "\n# changed\n")  # same geometry, new content: a new key
    logs.clear()
    hf.fit.draw_samples(target, "NR", s, log=logs.append)
    assert not any("from cache" in m for m in logs)


def test_scene_samples_hold_the_exact_values_of_the_pairs_draw_pairs_gives(target):
    s = validate(SamplingOptions, {"kind": "scene", "mesh": "demo", "count": 700, "validation": 300, "seed": 2,
                                   "cache": False}, "sampling")
    smp = hf.fit.draw_samples(target, "NR", s)
    train, val, _, _ = draw_pairs("lighting", "NR", s)
    np.testing.assert_array_equal(smp.a, train.a)
    np.testing.assert_array_equal(smp.val_b, val.b)
    direct = np.asarray(hf.fit.evaluate(target, smp.a, smp.b))
    np.testing.assert_allclose(smp.y, direct, rtol=2e-4, atol=1e-6)


@pytest.mark.slow
def test_a_saved_scene_fit_refits_from_disk_with_its_scene(target, tmp_path):
    opts = {"parametrization": "NR", "texture_size": 8,
            "sampling": {"kind": "scene", "mesh": "demo", "count": 2000, "validation": 300, "cache": False}}
    first = hf.fit.factorize(target, **opts, config=opts)
    first.save(tmp_path / "out")
    back = hf.fit.prepare_refit(hf.output.load(tmp_path / "out"))
    assert back.state.scene is scene.load(opts["sampling"])  # rebuilt from the recorded config
    np.testing.assert_array_equal(back.state.train.a, first.state.train.a)
    env = hf.light.load_environment("city", resolution=8)
    r = hf.fit.refit(back, target=hf.light.lighting_target(target.fn.brdf, env))
    live = hf.fit.refit(first, environment=env)
    assert r.metrics["scene"]["float"]["nrmse"] == pytest.approx(live.metrics["scene"]["float"]["nrmse"], rel=1e-3)


@pytest.mark.slow
def test_the_cli_keeps_and_prints_the_scene_error_with_a_custom_encoding(tmp_path, capsys):
    """A custom 8-bit encoding re-measures the written textures: the scene's image-space error is
    measured again with them (not dropped), saved, and printed in the run summary. One product (NR): the
    re-measure (app/run.py ``write_result``) reads any fitted model, and a preset's chooser would add minutes."""
    from homofac.app.cli import fit_main

    (tmp_path / "c.yaml").write_text(
        "target: {kind: lighting, brdf: {model: cook_torrance}, environment: {file: forest, resolution: 4}}\n"
        "parametrization: NR\ntexture_size: 8\nsampling: {kind: scene, mesh: demo, count: 2000, validation: 500}\n"
        f"output: {{dir: {tmp_path / 'out'}, alpha: false, preview: false}}\n")
    assert fit_main([str(tmp_path / "c.yaml"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "scene (image space, " in out and "covered pixels): nrmse " in out
    saved = json.loads((tmp_path / "out" / "factorization.json").read_text())
    sc = saved["metrics"]["scene"]
    assert set(sc) == {"float", "quantized"} and np.isfinite(sc["quantized"]["nrmse"])
