"""One view of the bundled material asset in the real three.js (headless Chromium): three's PMREM and
homofac's drop-in, the G-buffer, and Python's evaluation of the bake and of the exact lighting at every
covered pixel. Used by tests/test_threejs.py and benchmarks/threejs.py.

The exact lighting is :func:`homofac.light.reference.reference_integrals` (the pinned glTF BRDF integrated
against the source lat-long map read bilinearly, multiple importance sampling, float64): three's equirect
DataTexture is that same map with linear filtering, so both renders are scored against the environment they
were given, converged at every roughness (:func:`exact_lighting` doubles the samples until the image moves
by less than ``tolerance``).

three's world is y-up: its direction (x, y, z) is homofac's (x, -z, y) (``HOMOFAC_Y_UP``), and the equirect
three is given is homofac's lat-long permuted to match (:func:`three_equirect`).
"""

from __future__ import annotations

import base64
import shutil
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import OpenEXR

import homofac as hf
from browser import chromium, serve
from homofac.light.integrals import material_radiance
from homofac.light.reference import reference_integrals, source_map
from homofac.light.sources import bundled

ROOT = Path(__file__).resolve().parents[2]
ASSET = ROOT / "src" / "homofac" / "data" / "assets" / "material_sphere.glb"
CAMERA = [0.0, 1.2, 4.2]


def three_equirect(latlong: np.ndarray) -> np.ndarray:
    """homofac's lat-long (H, W, 3) as the equirect three.js reads from a DataTexture (row 0 at the bottom),
    so that three's direction (x, y, z) reads homofac's (x, -z, y): rows reversed, column i <- (W/2 - 1 - i) mod W."""
    h, w = latlong.shape[:2]
    out = latlong[::-1][:, (w // 2 - 1 - np.arange(w)) % w]
    return np.concatenate([out, np.ones((h, w, 1), out.dtype)], -1).astype(np.float32)


def y_up(d: np.ndarray) -> np.ndarray:
    """three's y-up world direction -> homofac's +z-up one (HOMOFAC_Y_UP)."""
    return np.stack([d[..., 0], -d[..., 2], d[..., 1]], -1)


def exact_lighting(latlong: np.ndarray, name: str, n, v, base, metallic, roughness, *, samples: int = 4096,
                   tolerance: float = 0.005, cap: int = 65536) -> tuple[np.ndarray, dict]:
    """The converged outgoing radiance (N, 3) float64 of the glTF BRDF at pairs (n, v) with their materials,
    and how it converged: ``samples`` points per strategy of :func:`reference_integrals`, doubled until one
    doubling moves the image by less than ``tolerance`` (nrmse) or ``cap`` is reached. The finer estimate is
    returned; ``info`` = {samples, last_change, converged}."""
    src = source_map(latlong, name)

    def radiance(s: int) -> np.ndarray:
        parts = reference_integrals(src, n, v, roughness, samples=s)
        with jax.enable_x64(True):  # the float64 reference stays float64
            return np.asarray(material_radiance(jnp.asarray(parts), np.asarray(base, np.float64),
                                                np.asarray(metallic, np.float64)), np.float64)

    old, s = radiance(samples), samples
    while True:
        new, s = radiance(2 * s), 2 * s
        change = float(np.linalg.norm(new - old) / np.linalg.norm(new))
        if change < tolerance or s >= cap:
            return new, {"samples": s, "last_change": change, "converged": change < tolerance}
        old = new


def render(env_name: str, bake, work: Path, size: int, reference_samples: int = 4096,
           tolerance: float = 0.005) -> dict:
    """Render ``bake`` (saved into ``work``) and three's PMREM of the bundled environment ``env_name``.

    Returns the float radiance of both renders (``pmrem``, ``homofac``: (size, size, 4); ``physical``: homofac's
    drop-in on the materials made MeshPhysicalMaterial), the reader of each bake texture (``lookups``:
    [lookups, {uniform: reader}]), the coverage
    ``mask``, the G-buffer inputs at the covered pixels (``n``, ``v`` in homofac's frame, ``base``,
    ``metallic``, ``roughness``), the bake's own evaluation there (``bake``), the exact lighting
    (``exact``, :func:`exact_lighting` from ``reference_samples`` up; ``reference`` says how it converged),
    the 8-bit canvas of homofac's render at ``exposure``,
    the browser console ``log`` and the render time."""
    bake.save(work / "bake", ktx2=True)
    latlong = OpenEXR.File(str(bundled(env_name))).channels()["RGB"].pixels.astype(np.float32)
    (work / "env.bin").write_bytes(three_equirect(latlong).tobytes())
    shutil.copy(ASSET, work / "asset.glb")

    def floats(b64: str) -> np.ndarray:
        return np.frombuffer(base64.b64decode(b64), np.float32).reshape(size, size, 4)[::-1]

    out: dict = {"work": work}
    with serve({"/data": work, "/": ROOT}) as url, chromium() as browser:
        browser.get(f"{url}/tests/threejs/harness.html")
        for _ in range(200):
            if browser.execute_script("return window.hfTest && window.hfTest.ready"):
                break
            time.sleep(0.05)
        run = ("const cb = arguments[arguments.length - 1]; const a = arguments[0];"
               "window.hfTest[a.fn](...a.args).then(cb, (e) => cb('error: ' + e));")
        setup = {"asset": "/data/asset.glb", "env": "/data/env.bin", "envWidth": latlong.shape[1],
                 "envHeight": latlong.shape[0], "size": size, "cameraPosition": CAMERA}
        out["setup"] = browser.execute_async_script(run, {"fn": "setup", "args": [setup]})
        out["lookups"] = browser.execute_async_script(run, {"fn": "loadBake", "args": ["/data/bake/"]})
        out["pmrem_size"], out["pmrem_levels"], out["pmrem_bytes"] = browser.execute_script("return window.hfTest.pmremInfo()")
        g = {k: floats(browser.execute_script(f"return window.hfTest.gbuffer('{k}')")) for k in ("normal", "view", "base")}
        t = time.perf_counter()
        out["pmrem"] = floats(browser.execute_script("return window.hfTest.radiance('pmrem')"))
        out["homofac"] = floats(browser.execute_script("return window.hfTest.radiance('homofac')"))
        out["render_s"] = time.perf_counter() - t
        out["physical"] = floats(browser.execute_script("return window.hfTest.radiance('physical')"))
        mask = g["base"][..., 3] > 0.5
        out.update(mask=mask, n=y_up(g["normal"][mask][:, :3]), v=y_up(g["view"][mask][:, :3]),
                   metallic=g["normal"][mask][:, 3], roughness=g["view"][mask][:, 3], base=g["base"][mask][:, :3])
        loaded = hf.load(work / "bake")
        out["bake"] = np.asarray(loaded.evaluate(out["n"], out["v"], out["base"], out["metallic"], out["roughness"]))
        out["exposure"] = 0.8 / float(np.percentile(out["bake"], 99.5))
        canvas = browser.execute_script(f"return window.hfTest.canvas('homofac', {out['exposure']})")
        out["canvas"] = np.frombuffer(base64.b64decode(canvas), np.uint8).reshape(size, size, 4)[::-1]
        out["log"] = browser.get_log("browser")
    out["exact"], out["reference"] = exact_lighting(latlong, env_name, out["n"], out["v"], out["base"], out["metallic"],
                                                    out["roughness"], samples=reference_samples, tolerance=tolerance)
    return out


def nrmse(out: dict, kind: str, select=None) -> float:
    """nrmse of render ``kind`` ('pmrem', 'homofac') against the exact lighting at the covered pixels."""
    a, e = out[kind][out["mask"]][:, :3], out["exact"]
    if select is not None:
        a, e = a[select], e[select]
    return float(np.linalg.norm(a - e) / np.linalg.norm(e))
