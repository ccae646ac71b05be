"""The README's picture: ``python docs/make_readme_figure.py`` writes docs/img/readme_sphere.png.

A gold sphere under the bundled forest map, three panels rendered at the same pixels: the exact lighting
(computed in JAX at the GL framebuffer's normals and views), homofac's fit within 8 lookups (the
``balanced`` preset's budget; the OpenGL render of the exported shader) and split-sum (Karis 2013, the
same renderer), each titled with its nrmse over the sphere's pixels. One fit of about two to four minutes
on two cores. Needs the ``gl`` extra and EGL.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from PIL import Image

import homofac as hf
from homofac.gl import picture
from homofac.gl.engine import Camera, render

OUT = Path(__file__).resolve().parent / "img" / "readme_sphere.png"
SIZE = 256
CAMERA = Camera(azimuth=30.0, elevation=20.0)


def nrmse(approx: np.ndarray, exact: np.ndarray) -> float:
    """RMS error over the pixels divided by the RMS of the exact values, per channel, then averaged."""
    return float(np.mean(np.sqrt(np.mean((approx - exact) ** 2, 0)) / np.sqrt(np.mean(exact ** 2, 0))))


def main() -> int:
    env = hf.light.load_environment("forest", resolution=32)
    gold = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    target = hf.light.lighting_target(gold, env)
    log = lambda msg: print(msg, flush=True)  # noqa: E731 - a fit of minutes says where it is
    fits = [("homofac, 8 lookups", hf.fit.factorize(target, "NR", max_lookups=8, log=log)),
            ("split-sum, 3 lookups", hf.fit.factorize(target, "split_sum", log=log))]
    frames = [(name, render(fac, "sphere", size=SIZE, camera=CAMERA)) for name, fac in fits]
    frame = frames[0][1]
    exact = picture.exact_values(target, frame)
    exposure = picture.auto_exposure(exact)
    full = np.zeros_like(frame.value)
    full[frame.mask] = exact
    panels = [("exact lighting", picture.to_display(full, frame.mask, exposure))]
    for name, f in frames:
        assert np.array_equal(f.mask, frame.mask)
        panels.append((f"{name}: nrmse {nrmse(f.value[f.mask], exact):.3f}",
                       picture.to_display(f.value, f.mask, exposure)))
    img = picture.compose(panels, "gold under the forest map; the fits rendered by OpenGL from their exported shaders")
    OUT.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(OUT, optimize=True)
    print(f"wrote {OUT} ({OUT.stat().st_size // 1024} KiB); selection: {fits[0][1].selection.get('reason')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
