"""homofac inside the real three.js (npm package ``three``, headless Chromium, WebGL2 on SwiftShader).

A bundled glTF asset (``data/assets/material_sphere.glb``: base colour, metallic and roughness textures) is
rendered with three's MeshStandardMaterial twice: with three's own PMREM of the environment, and with
homofac's drop-in (``js/homofac-three.js``: ``loadBake``, ``applyBake``) reading a bake of the same
environment. The G-buffer of the same view (world normal, view direction, base colour, metallic and the
roughness three shades with) is read back, so Python evaluates at every covered pixel:

* the bake itself (``hf.load(dir).evaluate``): homofac's 8-bit render equals it within 2/255;
* the exact lighting of the pinned glTF BRDF (``homofac.light.integrals``, a fine light resolution):
  PMREM's and homofac's nrmse against it are reported, homofac's lower.

three's world is y-up: its direction (x, y, z) is homofac's (x, -z, y) (``HOMOFAC_Y_UP``), and the
equirect three is given is homofac's lat-long permuted to match (:func:`three_equirect`).
"""

from __future__ import annotations

import base64
import json
import shutil
import time
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

import homofac as hf
from browser import chromium, console_problems, missing, serve
from homofac.light.integrals import integrals, material_radiance
from homofac.light.sources import bundled

ROOT = Path(__file__).resolve().parents[1]
ASSET = ROOT / "src" / "homofac" / "data" / "assets" / "material_sphere.glb"
SIZE = 64
ENV = "forest"
#: Light resolution of the exact lighting (cube face size).
EXACT_RESOLUTION = 48

pytestmark = pytest.mark.slow


def three_equirect(latlong: np.ndarray) -> np.ndarray:
    """homofac's lat-long (H, W, 3) as the equirect three.js reads from a DataTexture (row 0 at the bottom),
    so that three's direction (x, y, z) reads homofac's (x, -z, y): rows reversed, column i <- (W/2 - 1 - i) mod W."""
    h, w = latlong.shape[:2]
    out = latlong[::-1][:, (w // 2 - 1 - np.arange(w)) % w]
    return np.concatenate([out, np.ones((h, w, 1), out.dtype)], -1).astype(np.float32)


def y_up(d: np.ndarray) -> np.ndarray:
    """three's y-up world direction -> homofac's +z-up one (HOMOFAC_Y_UP)."""
    return np.stack([d[..., 0], -d[..., 2], d[..., 1]], -1)


def _floats(b64: str) -> np.ndarray:
    return np.frombuffer(base64.b64decode(b64), np.float32).reshape(SIZE, SIZE, 4)[::-1]


def _bytes(b64: str) -> np.ndarray:
    return np.frombuffer(base64.b64decode(b64), np.uint8).reshape(SIZE, SIZE, 4)[::-1]


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """Both renders, the G-buffer and the bake of one view of the asset."""
    if not (ROOT / "js" / "node_modules" / "three").is_dir():
        missing("js/node_modules/three is missing (make js-packages)")
    data = tmp_path_factory.mktemp("three")
    bake = hf.bake(ENV, preset="fast", max_size=32, diffuse_size=16, data_resolution=8, samples=256)
    bake.save(data / "bake", ktx2=True)
    latlong = OpenEXR.File(str(bundled(ENV))).channels()["RGB"].pixels.astype(np.float32)
    (data / "env.bin").write_bytes(three_equirect(latlong).tobytes())
    shutil.copy(ASSET, data / "asset.glb")
    with serve({"/data": data, "/": ROOT}) as url, chromium() as browser:
        browser.get(f"{url}/tests/threejs/harness.html")
        for _ in range(200):
            if browser.execute_script("return window.hfTest && window.hfTest.ready"):
                break
            time.sleep(0.05)
        run = ("const cb = arguments[arguments.length - 1]; const a = arguments[0];"
               "window.hfTest[a.fn](...a.args).then(cb, (e) => cb('error: ' + e));")
        setup = {"asset": "/data/asset.glb", "env": "/data/env.bin", "envWidth": latlong.shape[1],
                 "envHeight": latlong.shape[0], "size": SIZE, "cameraPosition": [0.0, 1.2, 4.2]}
        assert browser.execute_async_script(run, {"fn": "setup", "args": [setup]}) is True
        lookups = browser.execute_async_script(run, {"fn": "loadBake", "args": ["/data/bake/"]})
        assert lookups == bake.lookups, lookups
        g = {k: _floats(browser.execute_script(f"return window.hfTest.gbuffer('{k}')")) for k in ("normal", "view", "base")}
        pmrem = _floats(browser.execute_script("return window.hfTest.radiance('pmrem')"))
        homofac = _floats(browser.execute_script("return window.hfTest.radiance('homofac')"))
        log = browser.get_log("browser")
        out = {"g": g, "pmrem": pmrem, "homofac": homofac, "log": log, "bake_dir": data / "bake",
               "run": lambda fn, *args: browser.execute_async_script(run, {"fn": fn, "args": list(args)}),
               "script": browser.execute_script}
        mask = g["base"][..., 3] > 0.5
        n3, v3 = g["normal"][mask][:, :3], g["view"][mask][:, :3]
        out.update(mask=mask, n=y_up(n3), v=y_up(v3), metallic=g["normal"][mask][:, 3],
                   roughness=g["view"][mask][:, 3], base=g["base"][mask][:, :3])
        loaded = hf.load(data / "bake")
        out["bake"] = np.asarray(loaded.evaluate(out["n"], out["v"], out["base"], out["metallic"], out["roughness"]))
        exposure = 0.8 / float(np.percentile(out["bake"], 99.5))
        out["exposure"] = exposure
        out["canvas"] = _bytes(browser.execute_script(f"return window.hfTest.canvas('homofac', {exposure})"))
        out["log"] += browser.get_log("browser")
    env = hf.light.load_environment(ENV, resolution=EXACT_RESOLUTION)
    parts = integrals(env, out["n"], out["v"], out["roughness"])
    out["exact"] = np.asarray(material_radiance(parts, out["base"], out["metallic"]), np.float64)
    return out


def test_the_page_renders_without_console_errors(rendered):
    assert not console_problems(rendered["log"]), console_problems(rendered["log"])
    assert rendered["mask"].sum() > 0.4 * SIZE * SIZE * np.pi / 4 * 0.5  # the sphere covers the view's centre
    # every roughness band and both metallic extremes are on screen
    r, m = rendered["roughness"], rendered["metallic"]
    assert r.min() < 0.15 and r.max() > 0.6 and m.min() < 0.01 and m.max() > 0.99


def test_homofac_in_three_equals_bake_evaluate(rendered):
    """The drop-in's 8-bit output equals the bake's own evaluation at the G-buffer's inputs within 2/255."""
    mask = rendered["mask"]
    want = np.clip(rendered["bake"] * rendered["exposure"], 0, 1) * 255
    got = rendered["canvas"][mask][:, :3].astype(np.float64)
    diff = np.abs(got - want)
    assert np.percentile(diff, 99.9) <= 2.0 + 0.5, np.percentile(diff, [50, 99, 99.9, 100])
    # and in float: the render's radiance equals the bake's
    flo = rendered["homofac"][mask][:, :3]
    np.testing.assert_allclose(flo, rendered["bake"], rtol=2e-2, atol=2e-3 * float(rendered["bake"].mean()))


def test_homofac_beats_three_pmrem_against_the_exact_lighting(rendered):
    exact = rendered["exact"]
    mask = rendered["mask"]
    nrmse = {k: float(np.linalg.norm(rendered[k][mask][:, :3] - exact) / np.linalg.norm(exact))
             for k in ("pmrem", "homofac")}
    print(json.dumps(nrmse))
    assert nrmse["homofac"] < nrmse["pmrem"], nrmse
