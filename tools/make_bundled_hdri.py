"""Make the bundled 256x128 environment maps from the 1024x512 originals (run once; reproducible).

    python tools/make_bundled_hdri.py SOURCE_DIR      # e.g. ../shared/data/hdri

For each of city, forest, interior, studio (CC0, Greg Zaal / Poly Haven; see
src/homofac/data/hdri/LICENSE.txt):

1. read the 1024x512 lat-long RGB float32 EXR;
2. set non-finite pixels to 0 and clamp negative values (DWAB compression artefacts) to 0;
3. average each 4x4 block weighted by the exact pixel solid angle of the pinned lat-long layout
   (:func:`homofac.light.latlong.box_downsample`): the energy sum(L dw) per channel is preserved (up to
   the final rounding);
4. write 256x128 half-float RGB, PIZ compression (each file well under 400 KB), with the header
   attribute envmap = latlong.

The output is deterministic: same input, same bytes. The script prints the energy of the original and
of the bundled map (after the half rounding) per channel.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import OpenEXR

from homofac.io.exr import read_exr, write_exr
from homofac.light.latlong import box_downsample, latlong_solid_angles
from homofac.light.sources import BUNDLED

FACTOR = 4


def energy(rgb: np.ndarray) -> np.ndarray:
    h, w, _ = rgb.shape
    return (rgb.astype(np.float64) * latlong_solid_angles(h, w)[:, None, None]).sum(axis=(0, 1))


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__.splitlines()[2].strip(), file=sys.stderr)
        return 2
    src = Path(argv[1])
    dst = Path(__file__).resolve().parents[1] / "src" / "homofac" / "data" / "hdri"
    for name in BUNDLED:
        a = read_exr(src / f"{name}.exr")
        a = np.maximum(np.where(np.isfinite(a).all(axis=-1, keepdims=True), a, 0.0), 0.0)
        small = box_downsample(a.astype(np.float64), FACTOR)
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
