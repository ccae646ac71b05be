"""The GL device: the child process that owns the headless OpenGL context (:mod:`homofac.gl._server`).

Every headless render and GPU evaluation of :mod:`homofac.gl.engine` is a :func:`call` here: plain
data (GLSL sources, numpy arrays, uniform values) goes to the child, numpy arrays come back. The child
is started on the first call and kept for the life of this process (one per process, about 0.3 s to
start); it imports numpy and moderngl only, so the GL driver (Mesa llvmpipe, its LLVM, its JIT
code and threads) never enters the process that fits (:mod:`homofac.gl._server`). When the child
dies (a driver crash), the call raises one line and the next call starts a new one.
"""

from __future__ import annotations

import atexit
import pickle
import subprocess
import sys
import threading
from pathlib import Path

from ..errors import HomofacError

SERVER = Path(__file__).with_name("_server.py")

_lock = threading.Lock()
_child: dict = {}


class GLSLError(HomofacError):
    """A program the GL driver did not compile (the message is the driver's log, on one line)."""


def _start() -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-u", str(SERVER)], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        status = pickle.load(proc.stdout)
    except (EOFError, pickle.UnpicklingError):
        status = ("error", "context", f"the GL process exited with code {proc.wait()}")
    if status[0] != "ok":
        proc.stdin.close()
        proc.wait()
        kind, msg = status[1], status[2]
        if kind == "import":
            raise HomofacError(msg)
        raise HomofacError(f"no headless OpenGL (EGL) context: {msg} (install libegl1 libgl1, see Makefile)")
    return proc


def _stop() -> None:
    proc = _child.pop("proc", None)
    if proc is not None and proc.poll() is None:
        try:
            proc.stdin.close()
            proc.wait(timeout=5)
        except Exception:  # noqa: BLE001 - exiting anyway
            proc.kill()


atexit.register(_stop)


def call(op: str, **kwargs):
    """Run ``op`` (``"draw"`` or ``"transform"``, see :mod:`homofac.gl._server`) in the GL process.

    Raises :class:`GLSLError` for a program that does not compile and HomofacError (one line) for
    every other failure, including no EGL context and a child that died.
    """
    with _lock:
        proc = _child.get("proc")
        if proc is None or proc.poll() is not None:
            proc = _child["proc"] = _start()
        try:
            pickle.dump((op, kwargs), proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            proc.stdin.flush()
            answer = pickle.load(proc.stdout)
        except (BrokenPipeError, EOFError, pickle.UnpicklingError):
            code = proc.wait()
            _child.pop("proc", None)
            raise HomofacError(f"the GL process died during {op} (exit code {code})") from None
    if answer[0] == "ok":
        return answer[1]
    if answer[1] == "glsl":
        raise GLSLError(answer[2][:300])
    raise HomofacError(f"GL {op} failed: {answer[2][:300]}")


__all__ = ["GLSLError", "SERVER", "call"]
