"""A bake shown on a textured asset (the bundled material_sphere.glb: base colour, metallic and roughness vary):
the headless GL preview equals ``Bake.evaluate`` at the pixels' own inputs, beside the exact lighting and
split-sum's; the CLIs; the WebGL2 page in headless Chromium."""

from __future__ import annotations

import base64
import json
import re

import numpy as np
import pytest

import homofac as hf
from homofac.app.cli import preview_main, view_main
from homofac.gl import picture
from homofac.gl.asset import load_asset
from homofac.gl.bakes import preview_bake, render_bake
from homofac.gl.engine import Camera
from homofac.light.integrals import integrals, material_radiance
from helpers import made_up_bake

SIZE = 40
CAMERA = Camera(azimuth=35.0, elevation=25.0)


@pytest.fixture(scope="module")
def bake():
    pytest.importorskip("moderngl")
    return made_up_bake("balanced")


def test_asset_is_textured_and_z_up():
    a = load_asset("material_sphere")
    assert a.positions.shape == a.normals.shape and a.uv.shape == (len(a.positions), 2)
    assert np.allclose(np.linalg.norm(a.positions, axis=1).max(), 1.0, atol=1e-5)
    top = a.positions[:, 2].argmax()
    assert a.uv[top, 1] < 1e-6  # glTF's v = 0 row is the top (+y in glTF, +z here)
    mr = a.metallic_roughness
    assert len(np.unique(mr[..., 1])) >= 8 and len(np.unique(mr[..., 2])) == 3  # roughness, metallic vary
    assert len(np.unique(a.base_color[..., :3].reshape(-1, 3), axis=0)) >= 8


def test_gl_render_equals_bake_evaluate(bake):
    """GPU == CPU: the preview's values equal ``Bake.evaluate`` at the inputs each pixel used, within 8-bit
    display rounding, with roughness 0.045 ... 1 and metallic 0, 0.5, 1 on screen."""
    f = render_bake(bake, "material_sphere", size=SIZE, camera=CAMERA)
    m = f.mask
    assert m.sum() > 0.3 * SIZE * SIZE
    cpu = np.asarray(bake.evaluate(f.n[m], f.v[m], f.base_color[m], f.metallic[m], f.roughness[m]))
    gpu = f.value[m]
    assert np.abs(gpu - cpu).max() <= 1e-4 * np.abs(cpu).max()
    exposure = picture.auto_exposure(cpu)
    shown = lambda x: np.round(picture.srgb(x * exposure) * 255)  # noqa: E731
    assert np.abs(shown(gpu) - shown(cpu)).max() <= 1
    assert f.roughness[m].min() < 0.05 and f.roughness[m].max() > 0.99
    assert set(np.round(f.metallic[m], 2)) == {0.0, 0.5, 1.0}
    # the base colour is the sRGB texture decoded: every value on screen is one of the texture's colours
    tex = load_asset().base_color[..., :3].reshape(-1, 3) / 255.0
    dec = np.where(tex <= 0.04045, tex / 12.92, ((tex + 0.055) / 1.055) ** 2.4)
    d = np.abs(f.base_color[m][:, None, :] - np.unique(dec, axis=0)[None]).max(-1).min(-1)
    assert d.max() < 1e-5


def test_preview_beside_exact_and_split_sum(bake):
    """The picture holds five panels; its exact values are the brute-force integrals at the pixels' inputs; under a
    constant environment split-sum equals the exact lighting (both are the albedo times the radiance)."""
    img, data = preview_bake(bake, "forest", size=SIZE, camera=CAMERA, resolution=4, return_data=True)
    assert img.shape[1] > 5 * SIZE and set(data["nrmse"]) == {"bake", "split_sum"}
    assert sum(b["pixels"] for b in data["bands"].values()) == data["frame"].mask.sum() and len(data["bands"]) == 4
    f = data["frame"]
    m = f.mask
    env = hf.light.load_environment("forest", 4)
    k = int(m.sum())
    pad = lambda a: np.concatenate([a, np.repeat(a[:1], 1024 - k, axis=0)])  # noqa: E731 - the preview's compiled shape
    parts = integrals(env, pad(f.n[m]), pad(f.v[m]), pad(f.roughness[m]))[:k]
    exact = np.asarray(material_radiance(parts, f.base_color[m], f.metallic[m]))
    np.testing.assert_allclose(data["exact"], exact, rtol=1e-5, atol=1e-6)
    assert 0 < data["nrmse"]["split_sum"] < 1
    _, u = preview_bake(bake, hf.light.uniform(2.0, 4), size=24, camera=CAMERA, return_data=True)
    np.testing.assert_allclose(u["split_sum"], u["exact"], rtol=2e-4, atol=1e-6)


def test_preview_cli_on_a_bake_directory(bake, tmp_path, capsys):
    d = bake.save(tmp_path / "bake")
    out = tmp_path / "p.png"
    assert preview_main([str(d), "-o", str(out), "--size", "24", "--resolution", "4"]) == 0
    assert "split-sum" in capsys.readouterr().out and out.stat().st_size > 0
    assert preview_main([str(d), "-o", str(tmp_path / "q.png"), "--asset", str(tmp_path / "none.glb")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("homofac: error:") and "\n" not in err and "no such file" in err
    (tmp_path / "bad.glb").write_bytes(b"glTF" + b"\0" * 40)
    assert preview_main([str(d), "-o", str(tmp_path / "q.png"), "--asset", str(tmp_path / "bad.glb")]) == 2
    assert "\n" not in capsys.readouterr().err.strip()
    assert not (tmp_path / "q.png").exists()


def test_viewer_page_of_a_bake_in_chromium(bake, tmp_path):
    """``python -m homofac.view BAKE_DIR`` writes a page that loads in headless Chromium without console errors;
    its live panel equals the moderngl preview of the same view (two rasterizers: a few edge pixels may differ),
    and its exact and split-sum panels show the preview's pictures."""
    from browser import chromium, console_problems

    d = bake.save(tmp_path / "bake")
    html = tmp_path / "bake.html"
    assert view_main([str(d), "--html", str(html), "--size", str(SIZE), "--resolution", "4", "--azimuth",
                      str(CAMERA.azimuth), "--elevation", str(CAMERA.elevation)]) == 0
    data = json.loads(re.search(r'<script id="hf-data" type="application/json">(.*?)</script>', html.read_text(), re.S)
                      .group(1))
    assert data["kind"] == "bake" and data["lookups"] == bake.lookups
    img, info = preview_bake(bake, "forest", size=SIZE, camera=CAMERA, resolution=4, exposure=data["exposure"],
                             error_scale=data["error_scale"], return_data=True)
    fs = max(10, SIZE // 18)
    ref = [img[fs + 8:fs + 8 + SIZE, 6 + i * (SIZE + 6): 6 + i * (SIZE + 6) + SIZE].astype(int) for i in range(5)]
    with chromium() as browser:
        browser.get(html.resolve().as_uri())
        for _ in range(300):
            state = browser.execute_script("return window.homofac ? [window.homofac.ready, window.homofac.error] : null")
            if state and (state[0] or state[1] is not None):
                break
            browser.implicitly_wait(0.05)
        assert state and state[0] and state[1] is None, state
        panels = []
        for i in range(5):
            b64 = browser.execute_script(f"return window.homofac.readPanel({i})")
            panels.append(np.frombuffer(base64.b64decode(b64), np.uint8).reshape(SIZE, SIZE, 4)[..., :3].astype(int))
        assert browser.execute_script("return window.homofac.set({terms: [1, 0, 0]})") is None
        log = browser.get_log("browser")
    assert console_problems(log) == []
    inner = info["frame"].mask
    for k in (1, 2):  # exact and split-sum: the same pictures
        assert np.abs(panels[k] - ref[k]).max() <= 1
    diff = np.abs(panels[0] - ref[0]).max(-1)[inner]
    assert np.mean(diff > 2) < 0.03 and np.median(diff) <= 1
