"""homofac.gl: the OpenGL preview of a factorization (moderngl; headless through EGL, or a window).

* :mod:`homofac.gl.engine`: meshes (sphere, torus, OBJ via trimesh), the orbit camera, the headless
  render into float targets (:func:`render`) and GPU evaluation at arbitrary pairs (:func:`evaluate`),
  all with the exported shader of :mod:`homofac.shader` (the code a renderer gets);
* :mod:`homofac.gl.picture`: :func:`preview`, the factorized render beside the exact target and an
  error heat map with a colour bar, as an image array; :func:`write_preview` writes it as a PNG;
* :mod:`homofac.gl.bakes`: :func:`preview_bake`, a bake on a textured glTF asset (:mod:`homofac.gl.asset`)
  beside the exact lighting and split-sum's;
* :mod:`homofac.gl.window`: the interactive viewer (moderngl-window, orbit camera);
* :mod:`homofac.gl.device`: the child process that owns the headless GL context. Every headless render
  runs there, so the GL driver (Mesa llvmpipe, with its own LLVM and JIT code) stays out of the process
  that fits, and a driver crash costs one call.

Importing this package does not import moderngl; the headless renders import it in the GL device
process, the viewer in this one (the ``gl`` extra).
"""

from __future__ import annotations

from . import bakes
from .asset import load_asset
from .bakes import preview_bake, render_bake
from .engine import Camera, Frame, Light, Mesh, context, evaluate, load_mesh, render
from .picture import preview, write_preview

__all__ = ["Camera", "Frame", "Light", "Mesh", "bakes", "context", "evaluate", "load_asset", "load_mesh", "preview",
           "preview_bake", "render", "render_bake", "write_preview"]
