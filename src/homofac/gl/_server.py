"""The GL device process: headless OpenGL (moderngl over EGL) in a process of its own.

The headless renders of :mod:`homofac.gl.engine` run here, in a child that never imports JAX, so the
process that fits never loads a GL driver: Mesa's llvmpipe brings its own LLVM, JIT-compiles every
shader into memory mappings of its own and keeps rasterizer threads, and a driver crash costs one
call instead of the session (:mod:`homofac.gl.device` starts a new child). (This was first written
for two segfaults of the slow suite inside XLA's compile after a preview; their cause was the
process's mapping limit, :mod:`homofac.fit.programs`, not the driver.)

This file is run as a script (``python _server.py``) and imports nothing but the standard library,
numpy and moderngl; :mod:`homofac.gl.device` starts it and talks to it. The protocol is pickled
tuples over the child's stdin / stdout (its own prints go to stderr): requests ``(op, kwargs)``,
answers ``("ok", value)`` or ``("error", kind, message)``; ``kind`` is ``"glsl"`` for a program that
does not compile, ``"gl"`` otherwise. The first answer, before any request, says whether a context
could be created. The process ends when its stdin closes (its parent exited).

Two operations, both plain data in and numpy arrays out:

* ``draw``: a vertex / fragment program over vertex attributes (optionally indexed triangles) into
  ``targets`` float RGBA colour targets of ``size`` (with a depth buffer when ``depth``); returns the
  targets as read back, bottom row first (OpenGL's order);
* ``transform``: a vertex program with ``varyings`` evaluated at ``n`` vertices by transform feedback
  (no rasterisation); returns the captured ``vec3`` values ``(n, 3)``.

Textures are ``(uniform, array (H, W, C), dtype, filter)``: ``dtype`` ``"f4"`` (float) or ``"f1"``
(normalised 8-bit), ``filter`` ``"linear"`` or ``"nearest"``; clamp to edge, no mipmaps, rows in array
order (the pinned interface's binding); bound to units 0, 1, ... in order. Uniforms: name -> value
(a tuple for vectors; bytes for matrices, column-major float32); uniforms the compiler removed are
skipped.
"""

from __future__ import annotations

import os
import pickle
import sys

import numpy as np


def texture(ctx, array: np.ndarray, dtype: str, filter: str = "linear"):
    """A 2D texture of ``array`` (H, W, C) as the pinned interface binds it (clamp to edge, no mipmaps)."""
    import moderngl

    a = np.ascontiguousarray(array)
    t = ctx.texture((a.shape[1], a.shape[0]), a.shape[2], data=a.tobytes(), dtype=dtype)
    f = moderngl.NEAREST if filter == "nearest" else moderngl.LINEAR
    t.filter = (f, f)
    t.repeat_x = t.repeat_y = False
    return t


def set_uniforms(prog, uniforms: dict) -> None:
    """Set ``uniforms`` on ``prog``; bytes are written raw (matrices); unused uniforms are skipped."""
    for name, value in uniforms.items():
        if name not in prog:  # unused uniforms are optimised away
            continue
        if isinstance(value, (bytes, bytearray)):
            prog[name].write(bytes(value))
        else:
            prog[name].value = value


def bind(ctx, prog, textures) -> list:
    """Create ``textures`` on ``ctx``, bind them to units 0, 1, ... and point their uniforms there."""
    made = []
    for unit, (uniform, array, dtype, filt) in enumerate(textures):
        t = texture(ctx, array, dtype, filt)
        made.append(t)
        t.use(unit)
        if uniform in prog:
            prog[uniform].value = unit
    return made


class _ProgramError(Exception):
    """A program the driver did not compile; the message is its log on one line."""


def program(ctx, **kwargs):
    """``ctx.program(**kwargs)``; a compile error becomes ``_ProgramError`` with the driver's message."""
    import moderngl

    try:
        return ctx.program(**kwargs)
    except moderngl.Error as e:
        raise _ProgramError(" ".join(str(e).split())) from None


def draw(ctx, *, vertex: str, fragment: str, attributes: np.ndarray, layout: str, names: list[str],
         index: np.ndarray | None = None, textures=(), uniforms=None, size=(1, 1), targets: int = 1,
         depth: bool = False) -> list[np.ndarray]:
    """Draw triangles with a program into float RGBA targets; the targets read back (bottom row first)."""
    import moderngl

    objs = []
    try:
        prog = program(ctx, vertex_shader=vertex, fragment_shader=fragment)
        objs.append(prog)
        objs += bind(ctx, prog, textures)
        set_uniforms(prog, uniforms or {})
        vbo = ctx.buffer(np.ascontiguousarray(attributes, np.float32).tobytes())
        objs.append(vbo)
        ibo = None
        if index is not None:
            ibo = ctx.buffer(np.ascontiguousarray(index, np.int32).tobytes())
            objs.append(ibo)
        vao = ctx.vertex_array(prog, [(vbo, layout, *names)], index_buffer=ibo, index_element_size=4)
        objs.append(vao)
        w, h = int(size[0]), int(size[1])
        colours = [ctx.texture((w, h), 4, dtype="f4") for _ in range(int(targets))]
        objs += colours
        rb = ctx.depth_renderbuffer((w, h)) if depth else None
        if rb is not None:
            objs.append(rb)
        fbo = ctx.framebuffer(color_attachments=colours, depth_attachment=rb)
        objs.append(fbo)
        fbo.use()
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        if depth:
            ctx.enable(moderngl.DEPTH_TEST)
        else:
            ctx.disable(moderngl.DEPTH_TEST)
        vao.render(moderngl.TRIANGLES)
        ctx.finish()
        return [np.frombuffer(fbo.read(components=4, attachment=i, dtype="f4"), np.float32).reshape(h, w, 4).copy()
                for i in range(len(colours))]
    finally:
        for o in reversed(objs):
            o.release()


def transform(ctx, *, vertex: str, varyings: list[str], a: np.ndarray, b: np.ndarray, textures=(),
              uniforms=None) -> np.ndarray:
    """Evaluate a vertex program with inputs ``in_a``, ``in_b`` (vec3) at N vertices by transform feedback."""
    import moderngl

    a = np.ascontiguousarray(np.asarray(a, np.float32).reshape(-1, 3))
    b = np.ascontiguousarray(np.asarray(b, np.float32).reshape(-1, 3))
    objs = []
    try:
        prog = program(ctx, vertex_shader=vertex, varyings=list(varyings))
        objs.append(prog)
        inp = ctx.buffer(np.concatenate([a, b], axis=1).tobytes())
        out = ctx.buffer(reserve=max(1, len(a)) * 12)
        objs += [inp, out]
        used = [n for n in ("in_a", "in_b") if n in prog]  # an unused input is optimised away: skip its bytes
        fmt = " ".join("3f" if n in prog else "3x4" for n in ("in_a", "in_b"))
        vao = ctx.vertex_array(prog, [(inp, fmt, *used)] if used else [])
        fbo = ctx.simple_framebuffer((1, 1))  # surfaceless EGL has no default framebuffer: draws would be dropped
        objs += [vao, fbo]
        fbo.use()
        objs += bind(ctx, prog, textures)
        set_uniforms(prog, uniforms or {})
        vao.transform(out, mode=moderngl.POINTS, vertices=len(a))
        return np.frombuffer(out.read(), np.float32).reshape(-1, 3)[: len(a)].copy()
    finally:
        for o in reversed(objs):
            o.release()


OPS = {"draw": draw, "transform": transform}


def serve(inp, out) -> None:
    """Answer requests from ``inp`` on ``out`` until ``inp`` closes."""
    def send(msg) -> None:
        pickle.dump(msg, out, protocol=pickle.HIGHEST_PROTOCOL)
        out.flush()

    try:
        import moderngl
    except ImportError as e:
        send(("error", "import", f"the GL preview needs moderngl (pip install 'homofac[gl]'): {e}"))
        return
    try:
        ctx = moderngl.create_standalone_context(backend="egl")
    except Exception as e:  # noqa: BLE001 - EGL failures come in many types
        send(("error", "context", " ".join(str(e).split()) or type(e).__name__))
        return
    send(("ok", ctx.info.get("GL_RENDERER", "")))
    while True:
        try:
            op, kwargs = pickle.load(inp)
        except EOFError:
            return
        try:
            send(("ok", OPS[op](ctx, **kwargs)))
        except _ProgramError as e:
            send(("error", "glsl", str(e)))
        except Exception as e:  # noqa: BLE001 - reported to the parent, which raises it as one line
            send(("error", "gl", f"{type(e).__name__}: {' '.join(str(e).split())}"))


def main() -> None:
    # The protocol owns the real stdout; anything else printed (drivers, moderngl) goes to stderr.
    out = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    serve(sys.stdin.buffer, out)


if __name__ == "__main__":
    main()
