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
from homofac.param import mappers

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


GBUFFER = ("n", "v", "base", "metallic", "roughness")


def known_exact(known: dict | None, out: dict) -> tuple[np.ndarray, dict] | None:
    """The exact lighting of an earlier run (``known``: its saved pixels, :data:`GBUFFER` and ``exact``, and its
    ``reference`` info) when its G-buffer equals this render's bit for bit (same asset, camera and size: the same
    pairs and materials), else None. The reference is deterministic, so this is the value it would compute."""
    if known is None or not all(np.array_equal(np.asarray(known[k]), out[k]) for k in GBUFFER):
        return None
    return np.asarray(known["exact"], np.float64), {**known["reference"], "reused": True}


def render(env_name: str, bake, work: Path, size: int, reference_samples: int = 4096,
           tolerance: float = 0.005, known: dict | None = None) -> dict:
    """Render ``bake`` (saved into ``work``) and three's PMREM of the bundled environment ``env_name``.

    Returns the float radiance of both renders (``pmrem``, ``homofac``: (size, size, 4); ``physical``: homofac's
    drop-in on the materials made MeshPhysicalMaterial), the reader of each bake texture (``lookups``:
    [lookups, {uniform: reader}]), the coverage
    ``mask``, the G-buffer inputs at the covered pixels (``n``, ``v`` in homofac's frame, ``base``,
    ``metallic``, ``roughness``), the bake's own evaluation there (``bake``), the exact lighting
    (``exact``, :func:`exact_lighting` from ``reference_samples`` up; ``reference`` says how it converged),
    the 8-bit canvas of homofac's render at ``exposure``; with ``known`` (:func:`known_exact`) the exact
    lighting is an earlier run's when the G-buffer is the same,
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
    out["exact"], out["reference"] = known_exact(known, out) or exact_lighting(
        latlong, env_name, out["n"], out["v"], out["base"], out["metallic"], out["roughness"],
        samples=reference_samples, tolerance=tolerance)
    return out


def edge_texels(bake, n: np.ndarray, v: np.ndarray, roughness: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each pixel's texture reads fall on the bake's cube faces, in texels of the block read:
    ``(edge (N,), texel (N,))``. ``edge``: the smallest distance, over every cube read of the pixel (each
    specular map of the two layers it blends, at the axis a_j = normalize((1 - s_j) r + s_j n) and at the map's
    block size in its atlas; E_d at n), from the read's continuous texel coordinate to the face's last texel
    centre (< 0: the read is clamped there, inside the last half texel: both the cube-face seams and the atlas
    blocks' edges, since a block's faces are laid side by side). ``texel``: the largest distance of a read's
    coordinate from the nearest texel centre (0.5: on a boundary between texels, where bilinear weights cross
    over), for the read that carries most of the pixel: P_1 of the nearer layer."""
    m = mappers.get("cube")
    n, v = np.asarray(n, np.float64), np.asarray(v, np.float64)
    x = np.sum(n * v, -1, keepdims=True)
    r = 2.0 * x * n - v
    u = np.asarray(bake.layer_coordinate(roughness), np.float64)
    reads = []
    for j, shift in enumerate(bake.shift):
        on = np.abs(u - j) < 1.0
        a = (1.0 - shift) * r + shift * n
        a = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-12)
        for i, atlas in enumerate(bake.atlases):
            reads.append((a, atlas.sizes[j], on, (np.round(u) == j) & (i == 0)))
    if bake.plan.diffuse_basis != "sh9":  # E_d as SH9 constants is no texture read
        reads.append((n, int(np.shape(bake.E)[0]), np.ones(len(n), bool), np.zeros(len(n), bool)))
    edge = np.full(len(n), np.inf)
    texel = np.zeros(len(n))
    for d, size, on, main in reads:
        _, fu, fv = (np.asarray(c, np.float64) for c in m.to_face_uv(d))
        c = np.stack([fu * size - 0.5, fv * size - 0.5], -1)  # continuous texel coordinates in the face
        dist = np.min(np.minimum(c, size - 1 - c), -1)
        frac = np.max(np.abs(c - np.round(c)), -1)
        edge = np.where(on, np.minimum(edge, dist), edge)
        texel = np.where(main, frac, texel)
    return edge, texel


def seams(out: dict, bake) -> dict:
    """The rendered image's error at the pixels whose reads lie on the bake's face and block seams (``edge`` <
    0.5: within a texel of a face's edge, :func:`edge_texels`) and on boundaries between texels (``texel`` >
    0.4), against the interior (``edge`` >= 1.5) and texel centres (``texel`` < 0.1): nrmse of the render
    against the CPU's ``bake.evaluate`` (``gpu_cpu``) and of both against the exact lighting (``gpu_exact``,
    ``cpu_exact``), and each class's pixel count."""
    edge, texel = edge_texels(bake, out["n"], out["v"], out["roughness"])
    got, cpu, exact = out["homofac"][out["mask"]][:, :3], out["bake"], out["exact"]

    def err(a, e, sel):
        return float(np.linalg.norm(a[sel] - e[sel]) / max(np.linalg.norm(e[sel]), 1e-30)) if sel.any() else float("nan")

    classes = {"face_edge": edge < 0.5, "interior": edge >= 1.5, "texel_boundary": texel > 0.4, "texel_centre": texel < 0.1}
    return {k: {"pixels": int(sel.sum()), "gpu_cpu": err(got, cpu, sel), "gpu_exact": err(got, exact, sel),
                "cpu_exact": err(cpu, exact, sel)} for k, sel in classes.items()}


def nrmse(out: dict, kind: str, select=None) -> float:
    """nrmse of render ``kind`` ('pmrem', 'homofac') against the exact lighting at the covered pixels."""
    a, e = out[kind][out["mask"]][:, :3], out["exact"]
    if select is not None:
        a, e = a[select], e[select]
    return float(np.linalg.norm(a - e) / np.linalg.norm(e))
