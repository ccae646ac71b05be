"""Make the bundled 256x128 environment maps from the 1024x512 originals (run once; reproducible).

    python src/homofac/data/hdri/make_bundled.py [SOURCE_DIR]   # default /work/shared/data/hdri

For each of city, forest, interior, studio (CC0, Greg Zaal / Poly Haven; see LICENSE.txt):

1. read the 1024x512 lat-long RGB float32 EXR;
2. set non-finite pixels to 0 and clamp negative values (DWAB compression artefacts) to 0;
3. average each 4x4 block weighted by the exact pixel solid angle
   (2 pi / W)(cos theta_top - cos theta_bottom) of the pinned lat-long layout (DESIGN.md). The solid
   angle of a coarse pixel is exactly the sum of its 16 fine ones, so the energy sum(L dw) per
   channel is preserved (up to the final rounding);
4. write 256x128 half-float RGB, PIZ compression (each file well under 400 KB), with the header
   attribute envmap = latlong.

The output is deterministic: same input, same bytes. The script prints the energy of the original and
of the bundled map (after the half rounding) per channel.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

NAMES = ("city", "forest", "interior", "studio")
FACTOR = 4


def pixel_solid_angles(h: int, w: int) -> np.ndarray:
    """(H,) solid angle of one pixel of each row of an H x W lat-long map (float64)."""
    edges = np.pi * np.arange(h + 1) / h
    return (2.0 * np.pi / w) * (np.cos(edges[:-1]) - np.cos(edges[1:]))


def downsample(rgb: np.ndarray, f: int = FACTOR) -> np.ndarray:
    """Solid-angle weighted f x f box average of an (H, W, 3) lat-long map (energy preserving)."""
    h, w, _ = rgb.shape
    assert h % f == 0 and w % f == 0, (h, w, f)
    dw = pixel_solid_angles(h, w)[:, None, None]
    e = (rgb.astype(np.float64) * dw).reshape(h // f, f, w // f, f, 3).sum(axis=(1, 3))
    dw_c = pixel_solid_angles(h // f, w // f)[:, None, None]
    return e / dw_c


def energy(rgb: np.ndarray) -> np.ndarray:
    h, w, _ = rgb.shape
    return (rgb.astype(np.float64) * pixel_solid_angles(h, w)[:, None, None]).sum(axis=(0, 1))


def main(argv: list[str]) -> int:
    import OpenEXR

    from homofac.io.exr import read_exr, write_exr

    src = Path(argv[1]) if len(argv) > 1 else Path("/work/shared/data/hdri")
    dst = Path(__file__).resolve().parent
    for name in NAMES:
        a = read_exr(src / f"{name}.exr")
        a = np.where(np.isfinite(a).all(axis=-1, keepdims=True), a, 0.0)
        a = np.maximum(a, 0.0)
        small = downsample(a)
        out = dst / f"{name}.exr"
        write_exr(out, small, half=True, compression="piz", header={"envmap": OpenEXR.ENVMAP_LATLONG})
        back = read_exr(out)
        e0, e1 = energy(a), energy(back)
        print(f"{name}: {a.shape[1]}x{a.shape[0]} -> {back.shape[1]}x{back.shape[0]}, {out.stat().st_size} bytes, "
              f"energy {np.round(e0, 4).tolist()} -> {np.round(e1, 4).tolist()} "
              f"(max rel diff {np.max(np.abs(e1 - e0) / e0):.1e})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv))
