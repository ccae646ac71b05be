"""Headless OpenGL (EGL) rendering of a factorization: meshes, camera, the shader program, read-back.

The fragment shader computes per pixel the normal ``n`` and view vector ``v`` (world frame, +z up,
``v`` from the surface to the eye), the arguments ``(a, b)`` of the factorization (``(n, v)`` for
lighting; ``(wi, wo)`` of one directional light in the local frame ``(t(n), n x t(n), n)`` for BRDFs)
and ``homofac_value(a, b)`` of the exported shader (:mod:`homofac.shader.generate`, GLSL 330: the
very code a renderer gets). It writes three float targets, the linear value, ``a`` and ``b``, so the
CPU can evaluate the exact function (and the factorization) at exactly the same arguments. One
sample per pixel; the textures are read with hardware bilinear filtering, clamp to edge, no mipmaps,
as the pinned shader interface prescribes.

The headless renders (:func:`render`, :func:`run_glsl`, :func:`evaluate`) run in the GL device
process (:mod:`homofac.gl.device`): this module builds the programs, textures and uniforms as plain
data and the child draws them, so the GL driver never enters the process that fits. Only the
interactive viewer draws in this process (:class:`Renderer`, on its window's context).
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np
from jaxtyping import Bool, Float, Int

from ..errors import HomofacError
from ..factorization import Quantized
from ..fit import scene
from ..shader import generate
from . import _server, device

#: The GLSL version line of the preview programs (the exported GLSL is 330 core).
GLSL_VERSION = "#version 330 core"

#: Shapes :func:`load_mesh` builds itself; anything else is a mesh file read by trimesh (OBJ, PLY, ...).
SHAPES = ("sphere", "torus")


# --------------------------------------------------------------------------------------------------
# Context


@functools.lru_cache(maxsize=1)
def _standalone():
    import moderngl

    return moderngl.create_standalone_context(backend="egl")


def context():
    """A headless moderngl context (EGL) in *this* process, for callers' own GL objects; HomofacError
    (one line) when there is none. homofac's own renders do not use it: they run in the GL device
    process (:mod:`homofac.gl.device`), which keeps the GL driver out of the process that fits."""
    try:
        import moderngl  # noqa: F401
    except ImportError as e:
        raise HomofacError(f"the GL preview needs moderngl (pip install 'homofac[gl]'): {e}") from None
    try:
        return _standalone()
    except Exception as e:  # noqa: BLE001 - EGL failures come in many types
        msg = " ".join(str(e).split()) or type(e).__name__
        raise HomofacError(f"no headless OpenGL (EGL) context: {msg} (install libegl1 libgl1, see Makefile)") from None


# --------------------------------------------------------------------------------------------------
# Meshes


class Mesh(NamedTuple):
    """A triangle mesh centred at the origin inside the unit sphere, with smooth vertex normals."""

    positions: Float[np.ndarray, "V 3"]
    normals: Float[np.ndarray, "V 3"]
    faces: Int[np.ndarray, "F 3"]


def load_mesh(shape: str | Path = "sphere", *, detail: int = 4) -> Mesh:
    """``"sphere"`` (icosphere), ``"torus"`` (radii 1 and 0.4, around +z) or a mesh file (OBJ ...) via trimesh.

    The mesh is centred on its bounding box and scaled to fit the unit sphere. A sphere gets exact
    normals (its positions); other shapes trimesh's area-weighted vertex normals.
    """
    try:
        import trimesh
    except ImportError as e:
        raise HomofacError(f"the GL preview needs trimesh (pip install 'homofac[gl]'): {e}") from None
    name = str(shape)
    if name == "sphere":
        m = trimesh.creation.icosphere(subdivisions=detail)
    elif name == "torus":
        m = trimesh.creation.torus(major_radius=1.0, minor_radius=0.4, major_sections=16 * detail,
                                   minor_sections=8 * detail)
    else:
        p = Path(name).expanduser()
        if not p.exists():
            raise HomofacError(f"mesh {name!r}: no such file (use sphere, torus or a mesh file such as an OBJ)")
        # the scene loader's checks: a regular file, bounded reads, counts as parsed (homofac.fit.scene)
        v, faces, normals = scene.load_mesh(p)
        m = trimesh.Trimesh(v, faces, vertex_normals=normals, process=False)
    v = np.asarray(m.vertices, np.float64)
    v = v - (v.min(0) + v.max(0)) / 2
    r = np.sqrt((v * v).sum(-1)).max()
    if not np.isfinite(r) or r <= 0:
        raise HomofacError(f"mesh {name!r}: degenerate (zero size or non-finite vertices)")
    v = v / r
    n = v if name == "sphere" else np.asarray(m.vertex_normals, np.float64)
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    return Mesh(v.astype(np.float32), n.astype(np.float32), np.asarray(m.faces, np.int32))


# --------------------------------------------------------------------------------------------------
# Camera (world +z up)


class Camera(NamedTuple):
    """An orbit camera looking at the origin: angles in degrees, +z up, ``fov`` the vertical field of view."""

    azimuth: float = 30.0
    elevation: float = 20.0
    distance: float = 4.5
    fov: float = 30.0

    @property
    def eye(self) -> np.ndarray:
        az, el = math.radians(self.azimuth), math.radians(self.elevation)
        return self.distance * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])

    def matrix(self, aspect: float = 1.0) -> Float[np.ndarray, "4 4"]:
        """Projection x view (row-major, column vectors), near 0.1, far 100."""
        eye = self.eye
        f = -eye / np.linalg.norm(eye)
        up = np.array([0.0, 0.0, 1.0])
        if abs(f @ up) > 0.999:
            up = np.array([0.0, 1.0, 0.0])
        s = np.cross(f, up)
        s /= np.linalg.norm(s)
        u = np.cross(s, f)
        view = np.eye(4)
        view[0, :3], view[1, :3], view[2, :3] = s, u, -f
        view[:3, 3] = -view[:3, :3] @ eye
        near, far = 0.1, 100.0
        t = 1.0 / math.tan(math.radians(self.fov) / 2)
        proj = np.zeros((4, 4))
        proj[0, 0], proj[1, 1] = t / aspect, t
        proj[2, 2], proj[2, 3] = (far + near) / (near - far), 2 * far * near / (near - far)
        proj[3, 2] = -1.0
        return proj @ view


def _mat_bytes(m: np.ndarray) -> bytes:
    return np.ascontiguousarray(m.T, np.float32).tobytes()  # GLSL is column-major


# --------------------------------------------------------------------------------------------------
# The program

VERTEX = f"""{GLSL_VERSION}
uniform mat4 u_mvp;
in vec3 in_position;
in vec3 in_normal;
out vec3 v_pos;
out vec3 v_normal;
void main() {{
    v_pos = in_position;
    v_normal = in_normal;
    gl_Position = u_mvp * vec4(in_position, 1.0);
}}
"""

FRAGMENT_MAIN = """
uniform vec3 u_eye;
uniform int u_mode;          // 0: lighting, a = n, b = v; 1: BRDF under one directional light
uniform vec3 u_light;        // BRDF mode: unit direction to the light (world)
uniform vec3 u_light_rgb;    // BRDF mode: the light's irradiance
uniform int u_times_cos;     // BRDF mode: the factorization is f (times cos theta_i here) or f cos theta_i
uniform float u_exposure;    // > 0: write the tone-mapped sRGB colour instead of the linear value
in vec3 v_pos;
in vec3 v_normal;
layout(location = 0) out vec4 o_value;
layout(location = 1) out vec4 o_a;
layout(location = 2) out vec4 o_b;
vec3 hf_srgb(vec3 x) {
    x = clamp(x, 0.0, 1.0);
    return mix(12.92 * x, 1.055 * pow(x, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), x));
}
void main() {
    vec3 n = hf_normalize(v_normal);
    vec3 v = hf_normalize(u_eye - v_pos);
    vec3 a = n, b = v;
    bool ok = dot(n, v) > 0.0;  // pairs with n.v <= 0 are invalid: L = 0 (docs/conventions.md)
    if (u_mode == 1) {
        a = hf_local(u_light, n);
        b = hf_local(v, n);
        ok = a.z > 0.0 && b.z > 0.0;
    }
    vec3 value = ok ? homofac_value(a, b) : vec3(0.0);
    if (u_mode == 1) value *= u_light_rgb * (u_times_cos == 1 ? max(a.z, 0.0) : 1.0);
    o_value = u_exposure > 0.0 ? vec4(hf_srgb(value * u_exposure), 1.0) : vec4(value, 1.0);
    o_a = vec4(a, 1.0);
    o_b = vec4(b, 1.0);
}
"""


def fragment_source(fac, quantized: Quantized | None = None) -> str:
    """The fragment shader of a factorization: the exported GLSL (its ``homofac_value``) and a main."""
    return "\n".join([GLSL_VERSION, generate.source(fac.model, "glsl", quantized=quantized), FRAGMENT_MAIN])


class Light(NamedTuple):
    """The directional light of a BRDF preview: unit direction to the light (world) and irradiance (RGB)."""

    direction: tuple = (0.4, -0.3, 0.866)
    irradiance: tuple = (1.0, 1.0, 1.0)

    @property
    def unit(self) -> np.ndarray:
        d = np.asarray(self.direction, np.float64)
        return d / np.linalg.norm(d)


def texture_arrays(model, quantized: Quantized | None = None) -> list[np.ndarray]:
    """The model's textures as the pinned interface uploads them: float32 RGB, or the RGBA8 texels
    (uint8) when ``quantized``; rows in array order."""
    if quantized is None:
        return [np.ascontiguousarray(np.asarray(t.data, np.float32)[..., :3]) for t in model.textures]
    return [np.ascontiguousarray(np.asarray(r, np.uint8)) for r in quantized.rgba]


def texture_specs(textures) -> list[tuple]:
    """``(uniform, array)`` pairs as the GL device binds them: ``(uniform, array, dtype, "linear")``,
    ``dtype`` ``"f1"`` (normalised 8-bit) for uint8 arrays, else ``"f4"`` (float32)."""
    out = []
    for uniform, a in textures:
        a = np.asarray(a)
        out.append((uniform, a, "f1", "linear") if a.dtype == np.uint8
                   else (uniform, np.asarray(a, np.float32), "f4", "linear"))
    return out


def program_inputs(fac, light: Light = Light(), quantized: bool = False) -> dict:
    """What the preview program of ``fac`` needs besides the mesh and camera: its fragment source, its
    textures (bound as the pinned interface says) and the uniforms of the light and mode."""
    if fac.kind not in ("lighting", "brdf"):
        raise HomofacError(f"cannot preview a factorization of kind {fac.kind!r}")
    q = fac.encoded() if quantized else None
    textures = texture_specs([(f"hf_{t.name}", a) for t, a in zip(fac.model.textures, texture_arrays(fac.model, q))])
    uniforms = {
        "u_mode": 0 if fac.kind == "lighting" else 1,
        "u_light": tuple(float(c) for c in light.unit),
        "u_light_rgb": tuple(float(c) for c in np.broadcast_to(light.irradiance, (3,))),
        "u_times_cos": 1 if fac.quantity == "brdf" else 0,
    }
    return {"fragment": fragment_source(fac, q), "textures": textures, "uniforms": uniforms}


def camera_uniforms(camera: Camera, aspect: float = 1.0, exposure: float = 0.0) -> dict:
    """The uniforms of one view: the projection-view matrix (column-major bytes), the eye, the exposure."""
    return {"u_mvp": _mat_bytes(camera.matrix(aspect)), "u_eye": tuple(float(c) for c in camera.eye),
            "u_exposure": float(exposure)}


def _mesh_attributes(mesh: Mesh) -> np.ndarray:
    return np.concatenate([mesh.positions, mesh.normals], axis=1).astype(np.float32)


class Renderer:
    """A factorization's textures and program on a moderngl context of this process, and a mesh to draw:
    the interactive viewer (:mod:`homofac.gl.window`), whose window owns its context. Headless renders
    go through the GL device process instead (:func:`render`).

    ``quantized=True`` renders the 8-bit textures (RGBA8, decoded in the shader) instead of the float ones.
    """

    def __init__(self, ctx, fac, mesh: Mesh, light: Light = Light(), quantized: bool = False):
        inputs = program_inputs(fac, light, quantized)
        self.ctx, self.fac, self.light = ctx, fac, light
        try:
            self.prog = _server.program(ctx, vertex_shader=VERTEX, fragment_shader=inputs["fragment"])
        except _server._ProgramError as e:
            raise HomofacError(f"GLSL of {fac.parametrization} does not compile: {str(e)[:300]}") from None
        self.textures = [_server.texture(ctx, a, dtype, filt) for _, a, dtype, filt in inputs["textures"]]
        self._units = [(uniform, k) for k, (uniform, *_rest) in enumerate(inputs["textures"])]
        _server.set_uniforms(self.prog, {**inputs["uniforms"], **dict(self._units)})
        vbo = ctx.buffer(_mesh_attributes(mesh).tobytes())
        ibo = ctx.buffer(np.ascontiguousarray(mesh.faces, np.int32).tobytes())
        self.vao = ctx.vertex_array(self.prog, [(vbo, "3f 3f", "in_position", "in_normal")], index_buffer=ibo,
                                    index_element_size=4)

    def draw(self, camera: Camera, aspect: float = 1.0, exposure: float = 0.0) -> None:
        """Draw into the bound framebuffer (linear values, or tone-mapped when ``exposure`` > 0)."""
        import moderngl

        for k, t in enumerate(self.textures):
            t.use(k)
        _server.set_uniforms(self.prog, camera_uniforms(camera, aspect, exposure))
        self.ctx.enable(moderngl.DEPTH_TEST)
        self.vao.render(moderngl.TRIANGLES)


class Frame(NamedTuple):
    """What one headless render reads back, rows top to bottom.

    ``value``: the linear factorized value per pixel (as the shader computed it); ``a``, ``b``: the
    arguments it was evaluated at (``n``, ``v`` for lighting; ``wi``, ``wo`` for BRDFs); ``mask``:
    pixels covered by the object.
    """

    value: Float[np.ndarray, "H W 3"]
    a: Float[np.ndarray, "H W 3"]
    b: Float[np.ndarray, "H W 3"]
    mask: Bool[np.ndarray, "H W"]


def render(fac, mesh: Mesh | str = "sphere", *, size: int = 256, camera: Camera = Camera(),
           light: Light = Light(), quantized: bool = False) -> Frame:
    """Render ``fac`` on a mesh headless (EGL, in the GL device process) into float targets and read
    them back (a :class:`Frame`).

    ``quantized``: render the 8-bit textures with their decode rule (what the PNG files give a GPU)."""
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or not 8 <= size <= 4096:
        raise HomofacError(f"preview size must be an int in 8 ... 4096, got {size!r}")
    mesh = load_mesh(mesh) if not isinstance(mesh, Mesh) else mesh
    inputs = program_inputs(fac, light, quantized)
    size = int(size)
    try:
        out = device.call("draw", vertex=VERTEX, fragment=inputs["fragment"], attributes=_mesh_attributes(mesh),
                          layout="3f 3f", names=["in_position", "in_normal"],
                          index=np.ascontiguousarray(mesh.faces, np.int32), textures=inputs["textures"],
                          uniforms={**inputs["uniforms"], **camera_uniforms(camera)}, size=(size, size),
                          targets=3, depth=True)
    except device.GLSLError as e:
        raise HomofacError(f"GLSL of {fac.parametrization} does not compile: {e}") from None
    out = [o[::-1] for o in out]  # GL reads bottom row first
    mask = out[0][..., 3] > 0.5
    return Frame(np.ascontiguousarray(out[0][..., :3]), np.ascontiguousarray(out[1][..., :3]),
                 np.ascontiguousarray(out[2][..., :3]), mask)


# --------------------------------------------------------------------------------------------------
# Transform feedback: GLSL functions at arbitrary inputs (tests; GPU evaluation without a mesh)


def run_glsl(declarations: str, expression: str, a, b, *, textures=(), uniforms=None) -> np.ndarray:
    """Evaluate the GLSL ``vec3`` ``expression`` of ``vec3 a, b`` at N input pairs on the GPU.

    ``declarations``: GLSL functions/uniforms the expression uses; ``textures``: ``(uniform name,
    array (H, W, C))`` pairs bound to units 0, 1, ... (float32 data, or uint8 as normalised RGBA8;
    linear filtering, clamp to edge, as :func:`texture_arrays` gives them); ``uniforms``: name -> value.
    Returns float32 ``(N, 3)`` (transform feedback in the GL device process, no rasterisation).
    """
    src = f"""{GLSL_VERSION}
{declarations}
in vec3 in_a;
in vec3 in_b;
out vec3 out_value;
void main() {{ vec3 a = in_a; vec3 b = in_b; out_value = {expression}; }}
"""
    return device.call("transform", vertex=src, varyings=["out_value"], a=np.asarray(a, np.float32),
                       b=np.asarray(b, np.float32), textures=texture_specs(textures), uniforms=dict(uniforms or {}))


def evaluate(fac, a, b, *, quantized: bool = False, language: str = "glsl") -> Float[np.ndarray, "N 3"]:
    """``fac.evaluate(a, b)`` computed on the GPU by the exported shader (GLSL 330, or GLSL ES 3.00 run as
    GLSL 330 -- they share their code), with the textures bound as the pinned interface says."""
    q = fac.encoded() if quantized else None
    decl = generate.source(fac.model, language, quantized=q)
    textures = [(f"hf_{t.name}", arr) for t, arr in zip(fac.model.textures, texture_arrays(fac.model, q))]
    return run_glsl(decl, "homofac_value(a, b)", a, b, textures=textures)


__all__ = ["Camera", "Frame", "GLSL_VERSION", "Light", "Mesh", "Renderer", "SHAPES", "camera_uniforms", "context",
           "evaluate", "load_mesh", "program_inputs", "render", "run_glsl", "texture_arrays", "texture_specs"]
