"""The preview picture: the factorized render (GL) beside the exact lighting (JAX) and an error heat map.

:func:`preview` renders a mesh headless (:func:`homofac.gl.engine.render`), evaluates the exact target
at exactly the arguments the shader used per pixel (read back from the float targets: ``n``, ``v`` for
lighting, ``wi``, ``wo`` of the directional light for BRDFs), and composes with numpy + pillow::

    [ factorized (GL) | exact (JAX) | relative error + colour bar ]
    caption: parametrization, mapper, size, mesh, pixel errors

All three panels use one exposure and the sRGB curve. The error is per pixel
``mean_c |a - e| / max(mean_c e, tau)`` with ``tau = 1e-3 mean(e)`` (as the pinned ``avg_rel``).
"""

from __future__ import annotations

from pathlib import Path

import jax.numpy as jnp
import numpy as np
from jaxtyping import Float, UInt8
from PIL import Image, ImageDraw, ImageFont

from ..errors import HomofacError
from ..target import evaluate
from .engine import Camera, Frame, Light, Mesh, render

#: Display value of the background (8-bit, all channels).
BACKGROUND = 32
#: Anchors of the viridis colour map (perceptually uniform), evenly spaced on [0, 1].
_VIRIDIS = np.array([
    [68, 1, 84], [71, 44, 122], [59, 81, 139], [44, 113, 142], [33, 144, 141],
    [39, 173, 129], [92, 200, 99], [170, 220, 50], [253, 231, 37],
], np.float64) / 255.0
#: Pixels per exact-evaluation call (a fixed shape, compiled once).
_BLOCK = 4096
#: Round error scales (upper ends of the colour bar).
_NICE = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)


def colormap(x: Float[np.ndarray, "*s"]) -> Float[np.ndarray, "*s 3"]:
    """Viridis (piecewise linear through 9 anchors) of values in [0, 1] (clipped)."""
    t = np.clip(np.nan_to_num(np.asarray(x, np.float64)), 0.0, 1.0) * (len(_VIRIDIS) - 1)
    i = np.minimum(np.floor(t).astype(int), len(_VIRIDIS) - 2)
    f = (t - i)[..., None]
    return _VIRIDIS[i] * (1 - f) + _VIRIDIS[i + 1] * f


def srgb(x: Float[np.ndarray, "*s"]) -> Float[np.ndarray, "*s"]:
    """The sRGB transfer curve of linear values clipped to [0, 1]."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def to_display(value: Float[np.ndarray, "H W 3"], mask, exposure: float) -> UInt8[np.ndarray, "H W 3"]:
    """Linear values -> 8-bit sRGB, background where ``mask`` is False."""
    out = np.round(srgb(np.asarray(value, np.float64) * exposure) * 255).astype(np.uint8)
    out[~mask] = BACKGROUND
    return out


def auto_exposure(value: Float[np.ndarray, "N 3"]) -> float:
    """1 / the 99.5th percentile of the per-pixel maximum channel (1 when that is not positive)."""
    if value.size == 0:
        return 1.0
    hi = float(np.percentile(np.max(value, axis=-1), 99.5))
    return 1.0 / hi if np.isfinite(hi) and hi > 0 else 1.0


def relative_error(approx: Float[np.ndarray, "N 3"], exact: Float[np.ndarray, "N 3"]) -> Float[np.ndarray, "N"]:
    """Per pixel ``mean_c |a - e| / max(mean_c e, tau)``, ``tau = 1e-3 mean(e)`` (0 where e and a vanish)."""
    e = np.mean(exact, axis=-1)
    tau = max(1e-3 * float(np.mean(exact)) if exact.size else 0.0, 1e-12)
    return np.mean(np.abs(approx - exact), axis=-1) / np.maximum(e, tau)


def _block_values(target, a, b, light: Light) -> np.ndarray:
    """The displayed exact values of one block of ``_BLOCK`` pairs (fixed shapes: one compile each)."""
    y = evaluate(target, a, b, chunk=_BLOCK)
    if target.kind == "brdf":
        y = target.shown(jnp.asarray(a), y) * jnp.asarray(np.broadcast_to(light.irradiance, (3,)), y.dtype)
    return np.asarray(y, np.float32)


def exact_values(target, frame: Frame, light: Light = Light()) -> Float[np.ndarray, "N 3"]:
    """The exact target at the frame's covered pixels (same arguments as the shader), as displayed.

    Lighting: ``L(v, n)`` (0 where n.v <= 0). BRDF: ``f(wi, wo) cos(theta_i) E`` for the light's
    irradiance E (0 below either horizon). Padded to blocks of ``_BLOCK`` pairs in numpy, so that
    every picture size runs the same compiled programs.
    """
    a = np.asarray(frame.a[frame.mask], np.float32)
    b = np.asarray(frame.b[frame.mask], np.float32)
    n = len(a)
    if n == 0:
        return np.zeros((0, 3), np.float32)
    pad = (-n) % _BLOCK
    a_p = np.concatenate([a, np.broadcast_to(a[:1], (pad, 3))])
    b_p = np.concatenate([b, np.broadcast_to(b[:1], (pad, 3))])
    y = np.concatenate([_block_values(target, a_p[i : i + _BLOCK], b_p[i : i + _BLOCK], light)
                        for i in range(0, n + pad, _BLOCK)])[:n]
    ok = ((a[:, 2] > 0) & (b[:, 2] > 0)) if target.kind == "brdf" else (np.sum(a * b, axis=-1) > 0)
    return np.where(ok[:, None], y, 0.0).astype(np.float32)


def _font(size: int):
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: the bitmap font only
        return ImageFont.load_default()


def _nice(x: float) -> float:
    return next((n for n in _NICE if x <= n), _NICE[-1])


def compose(panels: list[tuple[str, np.ndarray]], caption: str, colour_bar: tuple[float, str] | None = None
            ) -> UInt8[np.ndarray, "H W 3"]:
    """Panels side by side under titles, an optional colour bar ``(scale, label)`` after the last one,
    and a caption line; all on the background colour."""
    size = panels[0][1].shape[0]
    fs = max(10, size // 18)
    font, small = _font(fs), _font(max(9, fs - 2))
    head, foot, gap = fs + 8, fs + 10, 6
    bar_w = (fs * 4 + 24) if colour_bar else 0
    W = len(panels) * size + (len(panels) - 1) * gap + bar_w + 2 * gap
    H = head + size + foot
    img = Image.new("RGB", (W, H), (BACKGROUND,) * 3)
    draw = ImageDraw.Draw(img)
    x = gap
    for title, px in panels:
        img.paste(Image.fromarray(np.ascontiguousarray(px)), (x, head))
        draw.text((x + 4, 3), title, fill=(230, 230, 230), font=font)
        x += size + gap
    if colour_bar:
        scale, label = colour_bar
        bx, by, bh, bw = x, head + fs // 2, size - fs, 12
        ramp = colormap(np.linspace(1, 0, bh))[:, None, :].repeat(bw, axis=1)
        img.paste(Image.fromarray(np.round(ramp * 255).astype(np.uint8)), (bx, by))
        for t in (0.0, 0.25, 0.5, 0.75, 1.0):
            y = by + round((1 - t) * (bh - 1))
            draw.line([(bx + bw, y), (bx + bw + 3, y)], fill=(230, 230, 230))
            v = t * scale
            draw.text((bx + bw + 5, y - fs // 2), f"{v:.3g}" if t < 1 else f"{v:.3g}+", fill=(230, 230, 230), font=small)
        draw.text((bx, 3), label, fill=(230, 230, 230), font=small)
    draw.text((gap + 4, head + size + 4), caption, fill=(200, 200, 200), font=small)
    return np.asarray(img)


def check_finite(fac) -> None:
    """Refuse a factorization with non-finite texels or corrections (one line naming the texture): a picture
    of NaN says nothing, and the page of :mod:`homofac.app.view` cannot hold it."""
    model = fac.model
    for t in model.textures:
        bad = int(np.count_nonzero(~np.isfinite(np.asarray(t.data))))
        if bad:
            raise HomofacError(f"texture {t.name}: {bad} non-finite texels (NaN or Inf); nothing to show "
                               "(refit, or repair the texture)")
    for k, term in enumerate(model.terms):
        if not np.all(np.isfinite(np.asarray(term.correction))):
            raise HomofacError(f"term {k}: non-finite correction {np.asarray(term.correction).tolist()}; nothing to show")


def preview(
    fac,
    target=None,
    *,
    mesh: Mesh | str = "sphere",
    size: int = 256,
    camera: Camera = Camera(),
    light: Light = Light(),
    exposure: float | None = None,
    error_scale: float | None = None,
    return_data: bool = False,
):
    """The preview picture of a factorization: its GL render beside the exact target and the error.

    Args:
        fac: a :class:`~homofac.fit.result.Result` (lighting: a = n, b = v in the world frame; BRDF:
            lit by ``light``).
        target: the exact target (``hf.light.lighting_target(...)`` / ``hf.fit.brdf_target(...)``);
            default: the target the result was fitted to (``fac.target``), else only the factorized
            render is shown (:func:`homofac.app.run.target_from_config` rebuilds the target of a
            loaded output directory).
        mesh: ``"sphere"``, ``"torus"``, a mesh file (OBJ ...) or a :class:`~homofac.gl.engine.Mesh`.
        size: pixels of each square panel.
        camera: orbit camera (+z up).
        light: directional light of BRDF previews.
        exposure: linear scale before the sRGB curve (default: the 99.5th percentile of the exact
            values, or of the factorized ones without a target, maps to 1).
        error_scale: relative error at the top of the colour bar (default: a round number at or above
            the 95th percentile).
        return_data: also return a dict with the frame, the exact values and the pixel errors.

    Returns:
        ``uint8 (H, W, 3)`` image (and the dict when ``return_data``). Raises HomofacError (one line)
        when no headless GL context can be created.
    """
    check_finite(fac)
    if target is None:
        target = getattr(fac, "target", None)
    if target is not None and target.kind != fac.kind:
        raise HomofacError(f"target kind {target.kind} does not match the factorization ({fac.kind})")
    name = mesh if isinstance(mesh, str) else "mesh"
    frame = render(fac, mesh, size=size, camera=camera, light=light)
    approx = frame.value[frame.mask]
    exact = exact_values(target, frame, light) if target is not None else None
    if exposure is None:
        exposure = auto_exposure(exact if exact is not None else approx)
    panels = [("factorized (GL)", to_display(frame.value, frame.mask, exposure))]
    head = f"{fac.parametrization} ({len(fac.model.terms)} term{'s' if len(fac.model.terms) > 1 else ''}) on {fac.mapper} {fac.texture_size}, {Path(str(name)).name}"
    data = {"frame": frame, "exposure": exposure}
    if exact is None:
        img = compose(panels, f"{head}; no exact target to compare with")
    else:
        err = relative_error(approx, exact)
        scale = float(error_scale) if error_scale else _nice(float(np.percentile(err, 95)) if err.size else 1.0)
        ex = np.zeros_like(frame.value)
        ex[frame.mask] = exact
        panels.append(("exact (JAX)", to_display(ex, frame.mask, exposure)))
        heat = np.full(frame.value.shape, BACKGROUND, np.uint8)
        heat[frame.mask] = np.round(colormap(err / scale) * 255).astype(np.uint8)
        panels.append(("relative error", heat))
        a64, e64 = np.asarray(approx, np.float64), np.asarray(exact, np.float64)  # float32 squares overflow at 1e19
        nrmse = float(np.linalg.norm(a64 - e64) / max(np.linalg.norm(e64), 1e-30)) if err.size else 0.0
        mean_rel = float(np.mean(err)) if err.size else 0.0
        img = compose(panels, f"{head}; pixels: nrmse {nrmse:.3g}, mean rel. error {mean_rel:.3g}",
                      colour_bar=(scale, "rel. err."))
        data.update(exact=exact, error=err, nrmse=nrmse, mean_rel=mean_rel, error_scale=scale)
    return (img, data) if return_data else img


def write_preview(fac, path, target=None, **kwargs) -> Path:
    """:func:`preview` written as a PNG file."""
    img = preview(fac, target, **kwargs)
    path = Path(path)
    Image.fromarray(img).save(path, format="PNG")
    return path


__all__ = ["auto_exposure", "check_finite", "colormap", "compose", "exact_values", "preview", "relative_error", "srgb",
           "to_display", "write_preview"]
