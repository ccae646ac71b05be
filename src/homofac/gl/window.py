"""The interactive viewer: the factorization on a mesh in a window (moderngl-window), orbit camera.

Drag with the mouse to orbit (+z stays up), scroll to zoom, ``=``/``-`` raise/lower the exposure,
``Esc`` closes. The shader is the one of the headless preview (:class:`homofac.gl.engine.Renderer`),
tone-mapped to sRGB in the shader.
"""

from __future__ import annotations

import logging
import os
import sys
import warnings

import numpy as np

from ..errors import HomofacError
from .engine import Camera, Light, Mesh, Renderer, load_mesh


def has_display() -> bool:
    """Whether a window can be opened: a display server on Linux (DISPLAY / WAYLAND_DISPLAY); else assumed."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def require_display() -> None:
    """HomofacError (one line) when no window can be opened."""
    if not has_display():
        raise HomofacError("--window needs a display (DISPLAY / WAYLAND_DISPLAY is not set); "
                           "without --window the preview is written as a PNG")


def show(fac, *, mesh: Mesh | str = "sphere", size: int = 640, camera: Camera = Camera(), light: Light = Light(),
         exposure: float = 1.0, backend: str | None = None, frames: int | None = None) -> np.ndarray | None:
    """Open the viewer window (blocks until it is closed). HomofacError (one line) without a display.

    ``backend``: a moderngl-window class (``pyglet`` by default; ``headless`` renders offscreen through
    EGL, for tests). ``frames``: close after that many frames and return the last one (uint8 RGB).
    """
    if backend != "headless":
        require_display()
    try:
        with warnings.catch_warnings():  # PyGLM's "import glm" deprecation, not ours
            warnings.simplefilter("ignore", PendingDeprecationWarning)
            import moderngl_window as mglw
            import moderngl_window.scene  # noqa: F401 - imports glm
    except ImportError as e:
        raise HomofacError(f"the viewer needs moderngl-window (pip install 'homofac[gl]'): {e}") from None

    mesh = load_mesh(mesh) if not isinstance(mesh, Mesh) else mesh
    state = {"camera": camera, "exposure": float(exposure)}

    class Viewer(mglw.WindowConfig):
        gl_version = (3, 3)
        title = f"homofac: {fac.parametrization} on {fac.mapper} {fac.texture_size}"
        window_size = (size, size)
        aspect_ratio = None
        resizable = True
        log_level = logging.WARNING

        def __init__(self, **kwargs):
            super().__init__(**kwargs)
            self.renderer = Renderer(self.ctx, fac, mesh, light)

        def on_render(self, time: float, frame_time: float) -> None:
            self.wnd.use()
            self.ctx.clear(0.125, 0.125, 0.125, 1.0, depth=1.0)
            w, h = self.wnd.buffer_size
            self.renderer.draw(state["camera"], aspect=w / max(h, 1), exposure=state["exposure"])
            state["frames"] = state.get("frames", 0) + 1
            if frames is not None and state["frames"] >= frames:
                raw = self.wnd.fbo.read(components=3)
                state["image"] = np.frombuffer(raw, np.uint8).reshape(h, w, 3)[::-1].copy()
                self.wnd.close()

        def on_mouse_drag_event(self, x: int, y: int, dx: int, dy: int) -> None:
            c = state["camera"]
            state["camera"] = c._replace(azimuth=c.azimuth - 0.4 * dx,
                                         elevation=max(-89.0, min(89.0, c.elevation + 0.4 * dy)))

        def on_mouse_scroll_event(self, x_offset: float, y_offset: float) -> None:
            c = state["camera"]
            state["camera"] = c._replace(distance=max(1.5, min(50.0, c.distance * 0.9 ** y_offset)))

        def on_key_event(self, key, action, modifiers) -> None:
            keys = self.wnd.keys
            if action != keys.ACTION_PRESS:
                return
            if key == getattr(keys, "EQUAL", object()):
                state["exposure"] *= 1.25
            elif key == getattr(keys, "MINUS", object()):
                state["exposure"] /= 1.25

    args = ["--resizable", "true"] + (["--window", backend] if backend else [])  # never parse our sys.argv
    if backend == "headless":
        args += ["--backend", "egl"]
    try:
        mglw.run_window_config(Viewer, args=args)
    except HomofacError:
        raise
    except Exception as e:  # noqa: BLE001 - window systems fail in many ways
        raise HomofacError(f"cannot open the viewer window: {' '.join(str(e).split()) or type(e).__name__}") from None
    return state.get("image")


__all__ = ["has_display", "require_display", "show"]
