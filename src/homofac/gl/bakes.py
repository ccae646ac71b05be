"""The preview of a bake on a textured asset: the bake's shader (GL) beside the exact lighting and split-sum's.

:func:`render_bake` draws an :class:`~homofac.gl.asset.Asset` headless with the bake's generated GLSL
(:func:`homofac.bake.shader.source`, the code an engine gets): per pixel the fragment shader reads the
material from the asset's textures (base colour decoded from sRGB, metallic and roughness, times the
material's factors; nearest texels, as the bundled asset's sampler says) and writes
``homofac_ibl(n, v, base_color, metallic, roughness)`` and, in three more float targets, the inputs it used.
The CPU then evaluates at exactly those inputs (:func:`preview_bake`)::

    [ bake (GL) | exact | split-sum | bake's error | split-sum's error + colour bar ]

* exact: :func:`homofac.light.integrals.integrals` of the environment (the pinned light sum, brute force)
  and :func:`~homofac.light.integrals.material_radiance`;
* split-sum: :func:`homofac.baselines.split_sum.gltf_parts` (idealized: Karis' prefilter at each pixel's own
  roughness, exact irradiance and DFG terms), the same material formula.

One exposure and the sRGB curve for the three pictures; the error is the preview's per-pixel relative error
(:func:`homofac.gl.picture.relative_error`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Bool, Float

from ..bake import Bake
from ..bake import shader as bake_shader
from ..baselines.split_sum import gltf_parts
from ..errors import HomofacError
from ..light import Environment, load_environment
from ..light.integrals import integrals, material_radiance
from . import device
from .asset import Asset, load_asset
from .engine import GLSL_VERSION, Camera, camera_uniforms
from .picture import BACKGROUND, _nice, auto_exposure, colormap, compose, relative_error, to_display

VERTEX = f"""{GLSL_VERSION}
uniform mat4 u_mvp;
in vec3 in_position;
in vec3 in_normal;
in vec2 in_uv;
out vec3 v_pos;
out vec3 v_normal;
out vec2 v_uv;
void main() {{
    v_pos = in_position;
    v_normal = in_normal;
    v_uv = in_uv;
    gl_Position = u_mvp * vec4(in_position, 1.0);
}}
"""

#: The material of a pixel (glTF 2.0 pbrMetallicRoughness) and homofac_ibl; shared with the WebGL2 page.
MATERIAL = """
uniform sampler2D u_base_color;      // sRGB, 8-bit
uniform sampler2D u_metal_rough;     // linear: G roughness, B metallic
uniform vec4 u_base_factor;
uniform float u_metallic_factor;
uniform float u_roughness_factor;
vec3 hf_srgb_decode(vec3 c) {
    return mix(c / 12.92, pow((c + 0.055) / 1.055, vec3(2.4)), step(vec3(0.04045), c));
}
void hfb_material(vec2 uv, out vec3 c, out float m, out float rho) {
    c = hf_srgb_decode(texture(u_base_color, uv).rgb) * u_base_factor.rgb;
    vec4 mr = texture(u_metal_rough, uv);
    m = clamp(mr.b * u_metallic_factor, 0.0, 1.0);
    rho = clamp(mr.g * u_roughness_factor, 0.0, 1.0);
}
"""

FRAGMENT_MAIN = MATERIAL + """
uniform vec3 u_eye;
in vec3 v_pos;
in vec3 v_normal;
in vec2 v_uv;
layout(location = 0) out vec4 o_value;
layout(location = 1) out vec4 o_n;      // n, metallic
layout(location = 2) out vec4 o_v;      // v, roughness
layout(location = 3) out vec4 o_base;   // base colour (linear), 1
void main() {
    vec3 n = normalize(v_normal);
    vec3 v = normalize(u_eye - v_pos);
    vec3 c; float m; float rho;
    hfb_material(v_uv, c, m, rho);
    o_value = vec4(homofac_ibl(n, v, c, m, rho), 1.0);
    o_n = vec4(n, m);
    o_v = vec4(v, rho);
    o_base = vec4(c, 1.0);
}
"""


class BakeFrame(NamedTuple):
    """What one render of a bake reads back, rows top to bottom: the linear value, the inputs of
    ``homofac_ibl`` per pixel (``n``, ``v`` world +z up; ``base_color`` linear; ``metallic``, ``roughness``)
    and the coverage ``mask``."""

    value: Float[np.ndarray, "H W 3"]
    n: Float[np.ndarray, "H W 3"]
    v: Float[np.ndarray, "H W 3"]
    base_color: Float[np.ndarray, "H W 3"]
    metallic: Float[np.ndarray, "H W"]
    roughness: Float[np.ndarray, "H W"]
    mask: Bool[np.ndarray, "H W"]


def material_textures(asset: Asset) -> list[tuple]:
    """The asset's material textures as the GL device binds them (8-bit, nearest)."""
    return [("u_base_color", asset.base_color, "f1", "nearest"), ("u_metal_rough", asset.metallic_roughness, "f1", "nearest")]


def material_uniforms(asset: Asset) -> dict:
    return {"u_base_factor": tuple(float(x) for x in asset.base_color_factor),
            "u_metallic_factor": float(asset.metallic_factor), "u_roughness_factor": float(asset.roughness_factor)}


def fragment_source(bake: Bake) -> str:
    """The preview's fragment shader: the bake's generated GLSL 330 and :data:`FRAGMENT_MAIN`."""
    return "\n".join([GLSL_VERSION, bake_shader.source(bake, "glsl"), FRAGMENT_MAIN])


def attributes(asset: Asset) -> np.ndarray:
    """Interleaved vertex attributes ``position, normal, uv`` (float32)."""
    return np.concatenate([asset.positions, asset.normals, asset.uv], axis=1).astype(np.float32)


def render_bake(bake: Bake, asset: Asset | str = "material_sphere", *, size: int = 256,
                camera: Camera = Camera()) -> BakeFrame:
    """Render ``bake`` on ``asset`` headless (EGL, in the GL device process) into float targets."""
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or not 8 <= size <= 4096:
        raise HomofacError(f"preview size must be an int in 8 ... 4096, got {size!r}")
    asset = load_asset(asset) if not isinstance(asset, Asset) else asset
    textures = [(u, np.asarray(a, np.float32), "f4", "linear") for u, a in bake_shader.texture_arrays(bake)]
    try:
        out = device.call("draw", vertex=VERTEX, fragment=fragment_source(bake), attributes=attributes(asset),
                          layout="3f 3f 2f", names=["in_position", "in_normal", "in_uv"],
                          index=np.ascontiguousarray(asset.faces, np.int32), textures=textures + material_textures(asset),
                          uniforms={**material_uniforms(asset), **camera_uniforms(camera)}, size=(int(size), int(size)),
                          targets=4, depth=True)
    except device.GLSLError as e:
        raise HomofacError(f"the bake's GLSL does not compile: {e}") from None
    value, n, v, base = (np.ascontiguousarray(o[::-1]) for o in out)  # GL reads bottom row first
    return BakeFrame(value[..., :3], n[..., :3], v[..., :3], base[..., :3], n[..., 3], v[..., 3], base[..., 3] > 0.5)


def inputs(frame: BakeFrame) -> tuple[np.ndarray, ...]:
    """``(n, v, base_color, metallic, roughness)`` at the covered pixels."""
    m = frame.mask
    return frame.n[m], frame.v[m], frame.base_color[m], frame.metallic[m], frame.roughness[m]


#: Roughness bands of the per-band nrmse (issue 42's benchmark bands).
BANDS = ((0.0, 0.15), (0.15, 0.3), (0.3, 0.6), (0.6, 1.01))
#: Below this roughness the lobe is narrower than a light texel at preview resolutions: the brute-force sum over
#: texel centres is not converged (the sparkles of the exact picture), and idealized split-sum, whose DFG terms
#: come from the same sum, shares its sampling. The caption's first nrmse counts the pixels from here up.
CONVERGED_FROM = 0.15

#: Pixels are padded to a multiple of this count before the integrals (a few compiled shapes for every size).
_BLOCK = 1024


def _padded(frame: BakeFrame) -> tuple[int, tuple[np.ndarray, ...]]:
    """The covered pixels' count and ``(n, v, roughness)`` padded (with the first pixel) to a multiple of _BLOCK."""
    n, v, _, _, rho = inputs(frame)
    pad = (-len(n)) % _BLOCK
    return len(n), tuple(np.concatenate([a, np.broadcast_to(a[:1], (pad,) + a.shape[1:])]) for a in (n, v, rho))


def exact_values(env: Environment, frame: BakeFrame) -> Float[np.ndarray, "N 3"]:
    """The exact lighting (brute force glTF BRDF integral) at the covered pixels' inputs."""
    count, (n, v, rho) = _padded(frame)
    if count == 0:
        return np.zeros((0, 3), np.float32)
    parts = integrals(env, jnp.asarray(n), jnp.asarray(v), jnp.asarray(rho))[:count]
    _, _, c, m, _ = inputs(frame)
    return np.asarray(material_radiance(parts, c, m), np.float32)


def split_sum_values(env: Environment, frame: BakeFrame) -> Float[np.ndarray, "N 3"]:
    """Split-sum's lighting (:func:`homofac.baselines.split_sum.gltf_parts`) at the covered pixels' inputs."""
    count, (n, v, rho) = _padded(frame)
    if count == 0:
        return np.zeros((0, 3), np.float32)
    _, _, c, m, _ = inputs(frame)
    return np.asarray(material_radiance(jnp.asarray(gltf_parts(env, n, v, rho)[:count]), c, m), np.float32)


def _nrmse(a, e) -> float:
    a, e = np.asarray(a, np.float64), np.asarray(e, np.float64)
    return float(np.linalg.norm(a - e) / max(np.linalg.norm(e), 1e-30)) if e.size else 0.0


def preview_bake(bake: Bake, environment=None, *, asset: Asset | str = "material_sphere", size: int = 256,
                 camera: Camera = Camera(), resolution: int = 32, exposure: float | None = None,
                 error_scale: float | None = None, return_data: bool = False):
    """The preview picture of a bake on a textured asset, beside the exact lighting and split-sum's.

    Args:
        bake: a :class:`~homofac.bake.Bake` (``hf.bake(...)`` or ``hf.load(dir)``).
        environment: what the exact and split-sum panels light the asset with: an :class:`Environment`, a
            file or a bundled name (default: the bake's recorded source, ``bake.info["source"]``).
        asset: a glTF file or a bundled asset (:func:`homofac.gl.asset.load_asset`).
        resolution: light resolution (cube face size) of the exact and split-sum panels.
        exposure: as :func:`homofac.gl.preview`.
        error_scale: as :func:`homofac.gl.preview`.

    Returns:
        ``uint8 (H, W, 3)`` (and, with ``return_data``, a dict: ``frame``, ``exact``, ``split_sum``,
        ``nrmse`` {bake, split_sum} over all pixels, ``nrmse_converged`` over roughness >= :data:`CONVERGED_FROM`,
        ``bands`` {band: {pixels, bake, split_sum}}, ``exposure``, ``error_scale``).
    """
    if environment is None:
        environment = (bake.info or {}).get("source")
        if not environment:
            raise HomofacError("the bake records no source environment: pass environment=")
    env = environment if isinstance(environment, Environment) else load_environment(environment, resolution)
    asset = load_asset(asset) if not isinstance(asset, Asset) else asset
    frame = render_bake(bake, asset, size=size, camera=camera)
    approx = frame.value[frame.mask]
    exact = exact_values(env, frame)
    split = split_sum_values(env, frame)
    if exposure is None:
        exposure = auto_exposure(exact)
    err_b, err_s = relative_error(approx, exact), relative_error(split, exact)
    scale = float(error_scale) if error_scale else _nice(float(np.percentile(err_b, 95)) if err_b.size else 1.0)

    def picture(values) -> np.ndarray:
        full = np.zeros_like(frame.value)
        full[frame.mask] = values
        return to_display(full, frame.mask, exposure)

    def heat(err) -> np.ndarray:
        out = np.full(frame.value.shape, BACKGROUND, np.uint8)
        out[frame.mask] = np.round(colormap(err / scale) * 255).astype(np.uint8)
        return out

    rho = frame.roughness[frame.mask]
    nrmse = {"bake": _nrmse(approx, exact), "split_sum": _nrmse(split, exact)}
    bands = {}
    for lo, hi in BANDS:
        k = (rho >= lo) & (rho < hi)
        if k.any():
            bands[f"{lo:g}-{min(hi, 1.0):g}"] = {"pixels": int(k.sum()), "bake": _nrmse(approx[k], exact[k]),
                                     "split_sum": _nrmse(split[k], exact[k])}
    k = rho >= CONVERGED_FROM
    nrmse_converged = {"bake": _nrmse(approx[k], exact[k]), "split_sum": _nrmse(split[k], exact[k])}
    panels = [("bake (GL)", to_display(frame.value, frame.mask, exposure)), ("exact", picture(exact)),
              ("split-sum", picture(split)), ("bake error", heat(err_b)), ("split-sum error", heat(err_s))]
    caption = (f"bake {bake.plan.preset}, {bake.lookups} lookups, on {asset.name}; pixel nrmse at roughness >= "
               f"{CONVERGED_FROM:g}: bake {nrmse_converged['bake']:.3g}, split-sum {nrmse_converged['split_sum']:.3g} "
               f"(all: {nrmse['bake']:.3g}, {nrmse['split_sum']:.3g})")
    img = compose(panels, caption, colour_bar=(scale, "rel. err."))
    data = {"frame": frame, "exact": exact, "split_sum": split, "nrmse": nrmse, "nrmse_converged": nrmse_converged,
            "bands": bands, "exposure": float(exposure),
            "error_scale": scale, "asset": asset}
    return (img, data) if return_data else img


__all__ = ["BANDS", "CONVERGED_FROM", "BakeFrame", "FRAGMENT_MAIN", "MATERIAL", "VERTEX", "attributes", "exact_values", "fragment_source",
           "inputs", "material_textures", "material_uniforms", "preview_bake", "render_bake", "split_sum_values"]
