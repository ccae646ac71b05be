"""The self-contained WebGL2 viewer: one HTML file with the textures, meshes and exact images embedded.

:func:`viewer_html` (and :func:`write_viewer`, ``python -m homofac.view OUT_DIR --html viewer.html``)
writes a page that needs nothing but a browser with WebGL2 -- no server, no network, no library:

* three panels: the factorization rendered live in WebGL2 on a sphere or a torus under an orbit camera
  (drag to orbit, +z up; wheel to zoom), the exact lighting of the reference view (an image
  precomputed by :func:`homofac.gl.picture.preview` from the exact target, rebuilt from the recorded
  config), and the relative-error heat map of the live factorization against it (computed per pixel in
  the shader, at the reference view; ``Reset view`` returns the live panel to it);
* controls: the mesh, float or 8-bit textures, per-term toggles (``homofac_term(k, a, b)`` of the
  generated source), exposure (in stops) and the error scale of the heat map;
* the fragment shader is the generated GLSL ES 3.00 library (``shader_es.glsl``, or its 8-bit twin)
  with a ``main`` that mirrors the OpenGL preview's (:data:`homofac.gl.engine.FRAGMENT_MAIN`), so the
  page shows what the preview PNG shows (the browser test compares them pixel by pixel).

Float textures are uploaded as RGBA32F with linear filtering when the browser has
``OES_texture_float_linear`` (SwiftShader and desktop GPUs do), else as RGBA16F (always filterable in
WebGL2; about 3 decimal digits); the page says which. 8-bit textures are the RGBA8 texels of the PNG
files, uploaded as raw bytes (no browser image decoding, so no premultiplied alpha or colour management).
The page exposes ``window.homofac`` (state, ``set(...)``, ``readPanel(i)``) for tests and scripts.
"""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

import numpy as np

from .._version import __version__
from ..bake import shader as bake_shader
from ..errors import HomofacError
from ..gl.asset import Asset, load_asset
from ..gl.bakes import CONVERGED_FROM, MATERIAL, VERTEX, material_textures, material_uniforms, preview_bake
from ..gl.engine import GLSL_VERSION, Camera, Light, load_mesh
from ..gl.picture import BACKGROUND, _VIRIDIS, check_finite, preview, relative_error
from ..io.files import write_atomically

#: Meshes the page offers (the first is shown first).
MESHES = ("sphere", "torus")


def _b64(a: np.ndarray, dtype) -> str:
    return base64.b64encode(np.ascontiguousarray(a, dtype).tobytes()).decode("ascii")


def _rgba(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, np.float32)
    if x.shape[-1] == 4:
        return x
    return np.concatenate([x[..., :3], np.ones(x.shape[:-1] + (1,), np.float32)], axis=-1)


def _term_label(term) -> str:
    return f"{term.kind}: " + " \u00d7 ".join(f"{f.texture}({f.projection})" for f in term.factors)


def viewer_data(fac, target=None, *, size: int = 256, camera: Camera = Camera(), light: Light = Light(),
                exposure: float | None = None, error_scale: float | None = None,
                meshes: tuple[str, ...] = MESHES) -> dict:
    """Everything the page embeds, as a JSON-friendly dict (see the module docstring).

    Also returns, under ``"_previews"`` (not embedded), the moderngl preview pictures of the reference
    view per mesh (``uint8 (H, W, 3)``, :func:`homofac.gl.picture.preview`): what the page must match.
    """
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or not 16 <= size <= 1024:
        raise HomofacError(f"viewer size must be an int in 16 ... 1024, got {size!r}")
    check_finite(fac)
    if target is None:
        target = getattr(fac, "target", None)
    model = fac.model
    q = fac.encoded()
    data: dict = {
        "homofac_version": __version__,
        "name": fac.parametrization or model.name,
        "kind": model.kind,
        "quantity": model.quantity,
        "size": int(size),
        "background": BACKGROUND,
        "viridis": _VIRIDIS.tolist(),
        "camera": {"azimuth": camera.azimuth, "elevation": camera.elevation, "distance": camera.distance,
                   "fov": camera.fov},
        "light": {"direction": [float(c) for c in light.unit],
                  "irradiance": [float(c) for c in np.broadcast_to(light.irradiance, (3,))]},
        "times_cos": fac.quantity == "brdf",
        "terms": [_term_label(t) for t in model.terms],
        "textures": [{"name": t.name, "mapper": t.mapper, "size": t.size, "width": int(t.shape[1]),
                      "height": int(t.shape[0]), "float": _b64(_rgba(t.data), np.float32),
                      "rgba8": _b64(np.asarray(q.rgba[k], np.uint8), np.uint8)}
                     for k, t in enumerate(model.textures)],
        "shaders": {"float": fac.shader("glsl_es"), "8bit": fac.shader("glsl_es", quantized=True)},
        "meshes": {},
        "exact": target is not None,
    }
    previews = {}
    for name in meshes:
        mesh = load_mesh(name)
        entry = {"positions": _b64(mesh.positions, np.float32), "normals": _b64(mesh.normals, np.float32),
                 "indices": _b64(mesh.faces.reshape(-1), np.uint32), "count": int(mesh.faces.size)}
        img, info = preview(fac, target, mesh=mesh, size=size, camera=camera, light=light, exposure=exposure,
                            error_scale=error_scale, return_data=True)
        previews[name] = img
        if exposure is None:  # one exposure and error scale for every mesh: those of the first
            exposure = float(info["exposure"])
        if target is not None:
            frame = info["frame"]
            ex = np.zeros(frame.value.shape[:2] + (4,), np.float32)
            ex[frame.mask, :3] = info["exact"]
            ex[frame.mask, 3] = 1.0
            e = info["exact"]
            entry["exact"] = _b64(ex, np.float32)
            entry["tau"] = max(1e-3 * float(np.mean(e)) if e.size else 0.0, 1e-12)
            entry["nrmse"] = info["nrmse"]
            if error_scale is None:
                error_scale = float(info["error_scale"])
        data["meshes"][name] = entry
    data["exposure"] = float(exposure)
    data["error_scale"] = float(error_scale) if error_scale is not None else 0.1
    data["_previews"] = previews
    return data


#: The bake page's toggles: the three parts of L (docs/format.md, "The bake directory").
BAKE_TERMS = ("diffuse: (1 - m) 0.96 c I_d", "specular: f0 I_A", "specular: I_B")


def bake_viewer_data(bake, environment=None, *, asset="material_sphere", size: int = 256, camera: Camera = Camera(),
                     resolution: int = 32, exposure: float | None = None, error_scale: float | None = None) -> dict:
    """What the page of a bake embeds: the bake's GLSL ES and float textures, the textured asset (uvs and its
    material textures, read in the shader as :data:`homofac.gl.bakes.MATERIAL` does), and the reference view's
    exact lighting, split-sum's and split-sum's error (:func:`homofac.gl.bakes.preview_bake`). The live panel
    is the bake; its error heat map is computed in the shader against the exact image.

    ``"_preview"`` (not embedded) holds the moderngl preview picture of the reference view."""
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or not 16 <= size <= 1024:
        raise HomofacError(f"viewer size must be an int in 16 ... 1024, got {size!r}")
    asset = load_asset(asset) if not isinstance(asset, Asset) else asset
    img, info = preview_bake(bake, environment, asset=asset, size=size, camera=camera, resolution=resolution,
                             exposure=exposure, error_scale=error_scale, return_data=True)
    frame = info["frame"]
    m = frame.mask

    def image(values) -> str:
        out = np.zeros(m.shape + (4,), np.float32)
        out[m, :3] = values
        out[m, 3] = 1.0
        return _b64(out, np.float32)

    e = info["exact"]
    tau = max(1e-3 * float(np.mean(e)) if e.size else 0.0, 1e-12)
    split_err = np.zeros(e.shape, np.float32)
    split_err[:, 0] = relative_error(info["split_sum"], e)
    material = [{"uniform": u, "width": int(a.shape[1]), "height": int(a.shape[0]), "rgba8": _b64(a, np.uint8)}
                for u, a, _, _ in material_textures(asset)]
    textures = [{"name": u[3:], "width": int(a.shape[1]), "height": int(a.shape[0]), "float": _b64(_rgba(a), np.float32)}
                for u, a in bake_shader.texture_arrays(bake)]
    return {
        "homofac_version": __version__,
        "name": f"bake {bake.plan.preset} on {asset.name}",
        "kind": "bake",
        "size": int(size),
        "background": BACKGROUND,
        "viridis": _VIRIDIS.tolist(),
        "camera": {"azimuth": camera.azimuth, "elevation": camera.elevation, "distance": camera.distance,
                   "fov": camera.fov},
        "terms": list(BAKE_TERMS),
        "lookups": int(bake.lookups),
        "converged_from": CONVERGED_FROM,
        "textures": textures,
        "material": material,
        "material_uniforms": material_uniforms(asset),
        "material_glsl": MATERIAL,
        "shaders": {"float": bake_shader.source(bake, "glsl_es")},
        "meshes": {asset.name: {"positions": _b64(asset.positions, np.float32), "normals": _b64(asset.normals, np.float32),
                                "uvs": _b64(asset.uv, np.float32), "indices": _b64(asset.faces.reshape(-1), np.uint32),
                                "count": int(asset.faces.size), "exact": image(e), "split_sum": image(info["split_sum"]),
                                "split_sum_error": image(split_err), "tau": tau,
                                "nrmse": info["nrmse_converged"]["bake"],
                                "split_sum_nrmse": info["nrmse_converged"]["split_sum"]}},
        "exact": True,
        "exposure": float(info["exposure"]),
        "error_scale": float(info["error_scale"]),
        "_preview": img,
    }


def write_bake_viewer(bake, path, environment=None, **kwargs) -> Path:
    """The page of a bake (:func:`bake_viewer_data`) written atomically to ``path`` (returns it)."""
    data = bake_viewer_data(bake, environment, **kwargs)
    data.pop("_preview")
    text = page(data)
    path = Path(path)
    write_atomically(path, "HTML", lambda tmp: Path(tmp).write_text(text, encoding="utf-8"), suffix=".tmp.html")
    return path


def viewer_html(fac, target=None, **kwargs) -> str:
    """The viewer page of ``fac`` as one HTML string (arguments as :func:`viewer_data`)."""
    data = viewer_data(fac, target, **kwargs)
    data.pop("_previews")
    return page(data)


#: What the data script's JSON escapes: ``<`` (so no ``</script>``, ``<!--`` or ``<script`` can end or nest the
#: script), ``>``, ``&`` and the JavaScript line terminators U+2028 / U+2029.
_SCRIPT_ESCAPES = {"<": "\\u003c", ">": "\\u003e", "&": "\\u0026", "\u2028": "\\u2028", "\u2029": "\\u2029"}
_SCRIPT_TABLE = str.maketrans(_SCRIPT_ESCAPES)


def script_json(blob: str) -> str:
    """JSON text ``blob`` made safe inside ``<script type="application/json">``: the characters that could
    end or change the script element are written as JSON ``\\uXXXX`` escapes (they only occur in strings),
    which ``JSON.parse`` reads back as the same string."""
    return blob.translate(_SCRIPT_TABLE)


def page(data: dict) -> str:
    """The HTML of embedded ``data`` (:func:`viewer_data` without ``_previews``)."""
    try:
        blob = json.dumps(data, separators=(",", ":"), allow_nan=False)
    except ValueError as e:  # NaN or Inf somewhere in the data
        raise HomofacError(f"viewer data: {e} (non-finite values cannot be shown)") from None
    title = f"homofac viewer: {data['name']}"
    return (TEMPLATE.replace("__HF_TITLE__", html.escape(title)).replace("__HF_DATA__", script_json(blob))
            .replace("__HF_SCRIPT__", SCRIPT))


def write_viewer(fac, path, target=None, **kwargs) -> Path:
    """:func:`viewer_html` written atomically to ``path`` (returns it)."""
    path = Path(path)
    text = viewer_html(fac, target, **kwargs)
    write_atomically(path, "HTML", lambda tmp: Path(tmp).write_text(text, encoding="utf-8"), suffix=".tmp.html")
    return path


TEMPLATE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>__HF_TITLE__</title>
<style>
  body { background: #202020; color: #e6e6e6; font: 14px/1.4 system-ui, sans-serif; margin: 16px; }
  #hf-titles { display: flex; }
  #hf-titles div { flex: none; padding: 2px 4px; }
  canvas { display: block; cursor: grab; image-rendering: pixelated; }
  #hf-controls { margin-top: 10px; display: grid; grid-template-columns: max-content auto; gap: 4px 12px;
                 align-items: center; }
  #hf-bar { display: inline-block; width: 160px; height: 10px; vertical-align: middle; }
  #hf-status { color: #aaa; margin-top: 8px; }
  label { margin-right: 12px; }
</style>
</head>
<body>
<h3 id="hf-heading"></h3>
<div id="hf-titles"></div>
<canvas id="hf-canvas"></canvas>
<div id="hf-controls">
  <span>mesh</span><span id="hf-mesh"></span>
  <span>textures</span><span><label><input type="radio" name="hf-textures" value="float" checked> float (EXR)</label>
    <label><input type="radio" name="hf-textures" value="8bit"> 8-bit (PNG)</label></span>
  <span>terms</span><span id="hf-terms"></span>
  <span>exposure</span><span><input id="hf-exposure" type="range" min="-8" max="8" step="0.05" value="0">
    <span id="hf-exposure-value"></span></span>
  <span>error scale</span><span><input id="hf-error-scale" type="range" min="-4" max="1" step="0.05">
    <span id="hf-bar"></span> 0 &hellip; <span id="hf-error-value"></span> (relative error)</span>
  <span>view</span><span><button id="hf-reset">Reset view</button> drag to orbit (+z up), wheel to zoom</span>
</div>
<div id="hf-status"></div>
<script id="hf-data" type="application/json">__HF_DATA__</script>
<script>
__HF_SCRIPT__
</script>
</body>
</html>
"""

SCRIPT = r"""
"use strict";
(function () {
  const data = JSON.parse(document.getElementById("hf-data").textContent);
  const S = data.size, BG = data.background / 255;
  const isBake = data.kind === "bake";
  const panels = isBake ? 5 : (data.exact ? 3 : 1);
  const hf = window.homofac = { ready: false, error: null, data: data, frames: 0 };
  const status = document.getElementById("hf-status");
  function fail(msg) {
    hf.error = String(msg);
    status.textContent = "error: " + hf.error;
    console.error("homofac viewer: " + hf.error);
  }
  function bytes(s) {
    const bin = atob(s), u8 = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; ++i) u8[i] = bin.charCodeAt(i);
    return u8;
  }
  const f32 = (s) => new Float32Array(bytes(s).buffer);

  // ---- camera (as homofac.gl.engine.Camera: orbit around the origin, +z up) ----
  function mvp(c, aspect) {
    const r = Math.PI / 180, az = c.azimuth * r, el = c.elevation * r;
    const eye = [c.distance * Math.cos(el) * Math.cos(az), c.distance * Math.cos(el) * Math.sin(az),
                 c.distance * Math.sin(el)];
    const len = (a) => Math.hypot(a[0], a[1], a[2]);
    const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    const el_ = len(eye), f = eye.map((x) => -x / el_);
    let up = [0, 0, 1];
    if (Math.abs(dot(f, up)) > 0.999) up = [0, 1, 0];
    let s = cross(f, up);
    const sl = len(s);
    s = s.map((x) => x / sl);
    const u = cross(s, f);
    const rows = [s, u, f.map((x) => -x)];
    const view = [0, 1, 2].map((i) => [rows[i][0], rows[i][1], rows[i][2], -dot(rows[i], eye)]);
    view.push([0, 0, 0, 1]);
    const near = 0.1, far = 100.0, t = 1.0 / Math.tan(c.fov * r / 2);
    const proj = [[t / aspect, 0, 0, 0], [0, t, 0, 0], [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)],
                  [0, 0, -1, 0]];
    const m = new Float32Array(16);
    for (let i = 0; i < 4; ++i)
      for (let j = 0; j < 4; ++j) {
        let acc = 0;
        for (let k = 0; k < 4; ++k) acc += proj[i][k] * view[k][j];
        m[j * 4 + i] = acc;  // column-major
      }
    return { matrix: m, eye: eye };
  }

  // ---- WebGL2 ----
  const canvas = document.getElementById("hf-canvas");
  canvas.width = panels * S;
  canvas.height = S;
  canvas.style.width = panels * S + "px";
  canvas.style.height = S + "px";
  const gl = canvas.getContext("webgl2", { antialias: false, preserveDrawingBuffer: true, alpha: false,
                                           premultipliedAlpha: false, depth: true });
  if (!gl) { fail("this browser has no WebGL2"); return; }
  const floatLinear = !!gl.getExtension("OES_texture_float_linear");

  function shader(type, src) {
    const s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error("shader does not compile: " + gl.getShaderInfoLog(s));
    return s;
  }
  function program(vs, fs) {
    const p = gl.createProgram();
    gl.attachShader(p, shader(gl.VERTEX_SHADER, vs));
    gl.attachShader(p, shader(gl.FRAGMENT_SHADER, fs));
    gl.bindAttribLocation(p, 0, "in_position");
    gl.bindAttribLocation(p, 1, "in_normal");
    gl.bindAttribLocation(p, 2, "in_uv");
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error("program does not link: " + gl.getProgramInfoLog(p));
    return p;
  }
  const VERTEX = `__HF_VERTEX__`;
  const viridis = data.viridis.map((c) => `vec3(${c[0].toFixed(6)}, ${c[1].toFixed(6)}, ${c[2].toFixed(6)})`).join(", ");
  // sRGB output and the viridis heat map, shared by the value and the exact panels' shaders
  const TONE = `const vec3 HF_VIRIDIS[9] = vec3[9](${viridis});
vec3 hf_srgb(vec3 x) {
    x = clamp(x, 0.0, 1.0);
    return mix(12.92 * x, 1.055 * pow(x, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), x));
}
vec3 hf_viridis(float x) {
    float t = clamp(x, 0.0, 1.0) * 8.0;
    int i = min(int(floor(t)), 7);
    return mix(HF_VIRIDIS[i], HF_VIRIDIS[i + 1], t - float(i));
}`;
  // The value of a pixel: a factorization (homofac.gl.engine.FRAGMENT_MAIN in GLSL ES, with per-term weights),
  // or a bake on the textured asset (homofac.gl.bakes.FRAGMENT_MAIN, with the three parts of L as toggles).
  const FAC_VALUE = `
uniform int u_mode;          // 0: lighting, a = n, b = v; 1: BRDF under one directional light
uniform vec3 u_light;
uniform vec3 u_light_rgb;
uniform int u_times_cos;
uniform float u_terms[HOMOFAC_TERMS];
vec3 hfb_value() {
    vec3 n = hf_normalize(v_normal);
    vec3 v = hf_normalize(u_eye - v_pos);
    vec3 a = n, b = v;
    bool ok = dot(n, v) > 0.0;
    if (u_mode == 1) {
        a = hf_local(u_light, n);
        b = hf_local(v, n);
        ok = a.z > 0.0 && b.z > 0.0;
    }
    vec3 value = vec3(0.0);
    if (ok) {
        for (int k = 0; k < HOMOFAC_TERMS; ++k) {
            if (u_terms[k] != 0.0) value += u_terms[k] * homofac_term(k, a, b);
        }
    }
    if (u_mode == 1) value *= u_light_rgb * (u_times_cos == 1 ? max(a.z, 0.0) : 1.0);
    return value;
}
`;
  const BAKE_VALUE = (data.material_glsl || "") + `
uniform float u_terms[3];
in vec2 v_uv;
vec3 hfb_value() {
    vec3 n = normalize(v_normal);
    vec3 v = normalize(u_eye - v_pos);
    vec3 c; float m; float rho;
    hfb_material(v_uv, c, m, rho);
    vec3 I_d, I_A, I_B;
    homofac_ibl_terms(n, v, rho, I_d, I_A, I_B);
    vec3 f0 = mix(vec3(0.04), c, m);
    return u_terms[0] * (1.0 - m) * 0.96 * c * I_d + u_terms[1] * f0 * I_A + u_terms[2] * I_B;
}
`;
  const MAIN = `
uniform vec3 u_eye;
uniform float u_exposure;
in vec3 v_pos;
in vec3 v_normal;
${isBake ? BAKE_VALUE : FAC_VALUE}
uniform int u_panel;         // 0: the tone-mapped value; otherwise the relative-error heat map against u_exact
uniform highp sampler2D u_exact;
uniform ivec2 u_origin;
uniform float u_tau;
uniform float u_error_scale;
out vec4 o_color;
${TONE}
void main() {
    vec3 value = hfb_value();
    if (u_panel == 0) { o_color = vec4(hf_srgb(value * u_exposure), 1.0); return; }
    ivec2 p = ivec2(gl_FragCoord.xy) - u_origin;
    vec4 e = texelFetch(u_exact, ivec2(p.x, ${S - 1} - p.y), 0);   // the exact image's rows run top to bottom
    if (e.a < 0.5) { o_color = vec4(vec3(${BG.toFixed(8)}), 1.0); return; }
    float err = (abs(value.r - e.r) + abs(value.g - e.g) + abs(value.b - e.b)) / 3.0
              / max((e.r + e.g + e.b) / 3.0, u_tau);
    o_color = vec4(hf_viridis(err / u_error_scale), 1.0);
}
`;
  const EXACT_VERTEX = `#version 300 es
in vec3 in_position;
void main() { gl_Position = vec4(in_position.xy, 0.0, 1.0); }
`;
  const EXACT_FRAGMENT = `#version 300 es
precision highp float;
uniform highp sampler2D u_exact;
uniform ivec2 u_origin;
uniform float u_exposure;
uniform int u_heat;          // 1: the image holds a relative error (in r), shown as the heat map
uniform float u_error_scale;
out vec4 o_color;
${TONE}
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy) - u_origin;
    vec4 e = texelFetch(u_exact, ivec2(p.x, ${S - 1} - p.y), 0);
    if (e.a < 0.5) { o_color = vec4(vec3(${BG.toFixed(8)}), 1.0); return; }
    o_color = u_heat == 1 ? vec4(hf_viridis(e.r / u_error_scale), 1.0) : vec4(hf_srgb(e.rgb * u_exposure), 1.0);
}
`;

  function half(x) {  // float32 -> IEEE half bits (round to nearest even), for RGBA16F uploads
    const f = new Float32Array(1), u = new Uint32Array(f.buffer);
    const out = new Uint16Array(x.length);
    for (let i = 0; i < x.length; ++i) {
      f[0] = x[i];
      const b = u[0], sign = (b >>> 16) & 0x8000;
      let e = ((b >>> 23) & 0xff) - 127 + 15, m = b & 0x7fffff;
      if (e >= 31) { out[i] = sign | 0x7c00; continue; }
      if (e <= 0) {
        if (e < -10) { out[i] = sign; continue; }
        m = (m | 0x800000) >> (1 - e);
        out[i] = sign | ((m + 0x1000 + ((m >> 13) & 1) - 1) >> 13);
        continue;
      }
      let h = sign | (e << 10) | (m >> 13);
      const rest = m & 0x1fff;
      if (rest > 0x1000 || (rest === 0x1000 && (h & 1))) h += 1;
      out[i] = h;
    }
    return out;
  }
  function texture(w, h, kind, pixels, filter) {
    const t = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, t);
    gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, false);
    gl.pixelStorei(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL, false);
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
    if (kind === "rgba8") gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA8, w, h, 0, gl.RGBA, gl.UNSIGNED_BYTE, pixels);
    else if (kind === "rgba32f") gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, w, h, 0, gl.RGBA, gl.FLOAT, pixels);
    else gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA16F, w, h, 0, gl.RGBA, gl.HALF_FLOAT, half(pixels));
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, filter);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, filter);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
    return t;
  }

  let programs, textures, meshes, exactProgram, quad, materialTextures;
  try {
    programs = {};
    for (const key of Object.keys(data.shaders))
      programs[key] = program(VERTEX, "#version 300 es\nprecision highp float;\nprecision highp int;\n" +
                                      data.shaders[key] + MAIN);
    const floatKind = floatLinear ? "rgba32f" : "rgba16f";
    textures = {"float": data.textures.map((t) => texture(t.width, t.height, floatKind, f32(t.float), gl.LINEAR))};
    if (data.shaders["8bit"])
      textures["8bit"] = data.textures.map((t) => texture(t.width, t.height, "rgba8", bytes(t.rgba8), gl.LINEAR));
    // a bake's material textures (glTF: nearest texels, as the bundled asset's sampler says)
    materialTextures = (data.material || []).map((t) => [t.uniform, texture(t.width, t.height, "rgba8", bytes(t.rgba8), gl.NEAREST)]);
    meshes = {};
    for (const [name, m] of Object.entries(data.meshes)) {
      const vao = gl.createVertexArray();
      gl.bindVertexArray(vao);
      for (const [loc, key, dim] of [[0, "positions", 3], [1, "normals", 3], [2, "uvs", 2]]) {
        if (!m[key]) continue;
        const buf = gl.createBuffer();
        gl.bindBuffer(gl.ARRAY_BUFFER, buf);
        gl.bufferData(gl.ARRAY_BUFFER, f32(m[key]), gl.STATIC_DRAW);
        gl.enableVertexAttribArray(loc);
        gl.vertexAttribPointer(loc, dim, gl.FLOAT, false, 0, 0);
      }
      const ibo = gl.createBuffer();
      gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, ibo);
      gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, new Uint32Array(bytes(m.indices).buffer), gl.STATIC_DRAW);
      gl.bindVertexArray(null);
      const image = (key) => m[key] ? texture(S, S, "rgba32f", f32(m[key]), gl.NEAREST) : null;
      meshes[name] = { vao: vao, count: m.count, exact: image("exact"), split: image("split_sum"),
                       splitError: image("split_sum_error") };
    }
    if (data.exact) {
      exactProgram = program(EXACT_VERTEX, EXACT_FRAGMENT);
      quad = gl.createVertexArray();
      gl.bindVertexArray(quad);
      const buf = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, buf);
      gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 0, 3, -1, 0, -1, 3, 0]), gl.STATIC_DRAW);
      gl.enableVertexAttribArray(0);
      gl.vertexAttribPointer(0, 3, gl.FLOAT, false, 0, 0);
      gl.bindVertexArray(null);
    }
  } catch (e) {
    fail(e.message || e);
    return;
  }

  // ---- state and drawing ----
  const reference = Object.assign({}, data.camera);
  const state = hf.state = {
    mesh: Object.keys(data.meshes)[0], textures: "float", terms: data.terms.map(() => 1.0),
    exposure: data.exposure, errorScale: data.error_scale, camera: Object.assign({}, reference),
  };
  const SETTERS = { i: "uniform1i", f: "uniform1f", fv: "uniform1fv", v3: "uniform3fv", i2: "uniform2iv" };
  function uniforms(p, typed) {  // {i: {name: int}, f: {...}, fv: {name: [floats]}, v3: {...}, i2: {...}}
    for (const [type, values] of Object.entries(typed))
      for (const [name, v] of Object.entries(values)) {
        const loc = gl.getUniformLocation(p, name);
        if (loc !== null) gl[SETTERS[type]](loc, v);  // null: optimised away
      }
  }
  function drawMesh(panel, camera) {
    const p = programs[state.textures], mesh = meshes[state.mesh];
    gl.useProgram(p);
    const texs = textures[state.textures];
    const unit = {};
    data.textures.forEach((t, k) => {
      gl.activeTexture(gl.TEXTURE0 + k);
      gl.bindTexture(gl.TEXTURE_2D, texs[k]);
      unit["hf_" + t.name] = k;
    });
    gl.activeTexture(gl.TEXTURE0 + texs.length);
    gl.bindTexture(gl.TEXTURE_2D, mesh.exact);
    materialTextures.forEach(([name, t], k) => {
      gl.activeTexture(gl.TEXTURE0 + texs.length + 1 + k);
      gl.bindTexture(gl.TEXTURE_2D, t);
      unit[name] = texs.length + 1 + k;
    });
    const mu = data.material_uniforms || {};
    if (isBake) {
      gl.uniform4fv(gl.getUniformLocation(p, "u_base_factor"), mu.u_base_factor);
      gl.uniform1f(gl.getUniformLocation(p, "u_metallic_factor"), mu.u_metallic_factor);
      gl.uniform1f(gl.getUniformLocation(p, "u_roughness_factor"), mu.u_roughness_factor);
    }
    const c = mvp(camera, 1.0);
    gl.uniformMatrix4fv(gl.getUniformLocation(p, "u_mvp"), false, c.matrix);
    uniforms(p, {
      i: Object.assign(unit, { u_mode: data.kind === "brdf" ? 1 : 0, u_times_cos: data.times_cos ? 1 : 0,
                               u_panel: panel, u_exact: texs.length }),
      f: { u_exposure: state.exposure, u_tau: data.meshes[state.mesh].tau || 1e-12, u_error_scale: state.errorScale },
      fv: { u_terms: state.terms },
      v3: Object.assign({ u_eye: c.eye }, data.light ? { u_light: data.light.direction, u_light_rgb: data.light.irradiance } : {}),
      i2: { u_origin: [panel * S, 0] },
    });
    gl.viewport(panel * S, 0, S, S);
    gl.enable(gl.DEPTH_TEST);
    gl.bindVertexArray(mesh.vao);
    gl.drawElements(gl.TRIANGLES, mesh.count, gl.UNSIGNED_INT, 0);
    gl.bindVertexArray(null);
  }
  function draw() {
    gl.disable(gl.SCISSOR_TEST);
    gl.viewport(0, 0, canvas.width, canvas.height);
    gl.clearColor(BG, BG, BG, 1.0);
    gl.clearDepth(1.0);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    drawMesh(0, state.camera);
    function image(panel, tex, heat) {
      gl.disable(gl.DEPTH_TEST);
      gl.useProgram(exactProgram);
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D, tex);
      uniforms(exactProgram, { i: { u_exact: 0, u_heat: heat ? 1 : 0 }, i2: { u_origin: [panel * S, 0] },
                               f: { u_exposure: state.exposure, u_error_scale: state.errorScale } });
      gl.viewport(panel * S, 0, S, S);
      gl.bindVertexArray(quad);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
      gl.bindVertexArray(null);
    }
    if (isBake) {  // bake | exact | split-sum | bake's error | split-sum's error
      const m = meshes[state.mesh];
      image(1, m.exact, false);
      image(2, m.split, false);
      drawMesh(3, reference);
      image(4, m.splitError, true);
    } else if (data.exact) {
      image(1, meshes[state.mesh].exact, false);
      drawMesh(2, reference);
    }
    const err = gl.getError();
    if (err !== gl.NO_ERROR) fail("WebGL error " + err);
    hf.frames += 1;
  }
  let pending = false;
  function redraw() {
    if (pending) return;
    pending = true;
    requestAnimationFrame(() => { pending = false; draw(); });
  }

  // ---- controls ----
  const mesh0 = data.meshes[Object.keys(data.meshes)[0]];
  document.getElementById("hf-heading").textContent = isBake
    ? `homofac ${data.homofac_version}: ${data.name} (${data.lookups} texture lookups per pixel); reference view nrmse at roughness >= ${data.converged_from}: ` +
      `bake ${mesh0.nrmse.toPrecision(3)}, split-sum ${mesh0.split_sum_nrmse.toPrecision(3)}`
    : `homofac ${data.homofac_version}: ${data.name} (${data.kind}, ${data.terms.length} term${data.terms.length > 1 ? "s" : ""})`;
  if (!data.shaders["8bit"]) document.getElementsByName("hf-textures")[1].disabled = true;
  const titles = document.getElementById("hf-titles");
  const names = isBake ? ["bake (WebGL2, live)", "exact (reference view)", "split-sum (reference view)",
                          "bake's relative error", "split-sum's relative error"]
                        : ["factorized (WebGL2, live)", "exact (reference view)", "relative error (reference view)"];
  for (let i = 0; i < panels; ++i) {
    const d = document.createElement("div");
    d.style.width = (S - 8) + "px";
    d.textContent = names[i];
    titles.appendChild(d);
  }
  const meshBox = document.getElementById("hf-mesh");
  for (const name of Object.keys(data.meshes)) {
    const l = document.createElement("label");
    l.innerHTML = `<input type="radio" name="hf-mesh" value="${name}"${name === state.mesh ? " checked" : ""}> ${name}`;
    meshBox.appendChild(l);
  }
  meshBox.addEventListener("change", (e) => { state.mesh = e.target.value; redraw(); });
  for (const r of document.getElementsByName("hf-textures"))
    r.addEventListener("change", (e) => { state.textures = e.target.value; redraw(); });
  const termBox = document.getElementById("hf-terms");
  data.terms.forEach((label, k) => {
    const l = document.createElement("label");
    l.innerHTML = `<input type="checkbox" data-term="${k}" checked> ${k}: `;
    l.appendChild(document.createTextNode(label));
    termBox.appendChild(l);
  });
  termBox.addEventListener("change", (e) => { state.terms[+e.target.dataset.term] = e.target.checked ? 1.0 : 0.0; redraw(); });
  const expo = document.getElementById("hf-exposure"), expoValue = document.getElementById("hf-exposure-value");
  function showExposure() { expoValue.textContent = state.exposure.toPrecision(3) + " (" + (+expo.value).toFixed(2) + " stops)"; }
  expo.addEventListener("input", () => { state.exposure = data.exposure * Math.pow(2, +expo.value); showExposure(); redraw(); });
  const errIn = document.getElementById("hf-error-scale"), errValue = document.getElementById("hf-error-value");
  errIn.value = Math.log10(state.errorScale);
  errValue.textContent = state.errorScale.toPrecision(2);
  errIn.addEventListener("input", () => { state.errorScale = Math.pow(10, +errIn.value); errValue.textContent = state.errorScale.toPrecision(2); redraw(); });
  document.getElementById("hf-bar").style.background =
    "linear-gradient(to right, " + data.viridis.map((c) => `rgb(${c.map((x) => Math.round(x * 255)).join(",")})`).join(", ") + ")";
  document.getElementById("hf-reset").addEventListener("click", () => { state.camera = Object.assign({}, reference); redraw(); });
  let drag = null;
  canvas.addEventListener("pointerdown", (e) => { drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
  canvas.addEventListener("pointerup", () => { drag = null; });
  canvas.addEventListener("pointermove", (e) => {
    if (!drag) return;
    const dx = e.clientX - drag[0], dy = e.clientY - drag[1];
    drag = [e.clientX, e.clientY];
    const c = state.camera;
    c.azimuth -= 0.4 * dx;
    c.elevation = Math.max(-89, Math.min(89, c.elevation + 0.4 * dy));
    redraw();
  });
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    const c = state.camera;
    c.distance = Math.max(1.5, Math.min(50, c.distance * Math.pow(0.9, e.deltaY < 0 ? 1 : -1)));
    redraw();
  }, { passive: false });
  showExposure();
  status.textContent = `WebGL2 on ${gl.getParameter(gl.RENDERER)}; float textures as ` +
    (floatLinear ? "RGBA32F (OES_texture_float_linear)" : "RGBA16F (no OES_texture_float_linear: half precision)") +
    `; exact image and error: reference view (azimuth ${reference.azimuth}, elevation ${reference.elevation}).`;

  // ---- scripting API (tests) ----
  hf.floatLinear = floatLinear;
  hf.set = function (changes) {
    for (const [k, v] of Object.entries(changes || {})) {
      if (k === "camera") Object.assign(state.camera, v);
      else state[k] = v;
    }
    draw();
    return hf.error;
  };
  hf.readPanel = function (i) {  // RGBA rows top to bottom, base64
    draw();
    const px = new Uint8Array(S * S * 4);
    gl.readPixels(i * S, 0, S, S, gl.RGBA, gl.UNSIGNED_BYTE, px);
    const flipped = new Uint8Array(px.length);
    for (let y = 0; y < S; ++y) flipped.set(px.subarray((S - 1 - y) * S * 4, (S - y) * S * 4), y * S * 4);
    let s = "";
    for (let j = 0; j < flipped.length; j += 0x8000) s += String.fromCharCode.apply(null, flipped.subarray(j, j + 0x8000));
    return btoa(s);
  };
  draw();
  hf.ready = hf.error === null;
})();
"""

#: The vertex shader of every viewer program: the GL preview's (:data:`homofac.gl.bakes.VERTEX`) with its
#: version line swapped for GLSL ES 3.00's (and the precision ES needs), so the two draw the same geometry.
WEBGL_VERTEX = VERTEX.replace(GLSL_VERSION, "#version 300 es\nprecision highp float;", 1)
SCRIPT = SCRIPT.replace("__HF_VERTEX__", WEBGL_VERTEX)

__all__ = ["BAKE_TERMS", "MESHES", "bake_viewer_data", "page", "script_json", "viewer_data", "viewer_html", "write_bake_viewer",
           "write_viewer"]
