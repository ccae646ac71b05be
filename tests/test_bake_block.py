"""The sharp layers' shared block holds the source's detail (:func:`homofac.bake.build.block_lights`)."""

from __future__ import annotations

import numpy as np

import homofac as hf
from homofac.bake.build import _Lights, block_lights
from homofac.io.exr import write_exr
from homofac.light import load_environment
from homofac.light.sources import bundled
from homofac.light.latlong import latlong_directions
from homofac.param import mappers
from helpers import optimized_xla

SIZE = 8
#: Azimuthal frequency of the test map's stripes: a period of 0.79 rad, four texels of the 8 face.
FREQ = 8


def _radiance(d: np.ndarray) -> np.ndarray:
    phi = np.arctan2(d[..., 1], d[..., 0])
    return 1.0 + 0.5 * np.cos(FREQ * phi) * (1.0 - d[..., 2] ** 2)


def test_block_lights_are_finer_than_the_block_and_bounded():
    """Never coarser than the face, finer than it at the sizes bakes use (up to the bundled maps' 64 face: the
    next test's stripes need it), growing with the face, and bounded: a large face is filtered at its own size."""
    sizes = [8, 16, 32, 64, 128, 256, 512, 1024, 4096]
    lights = [block_lights(s) for s in sizes]
    assert all(isinstance(n, int) and n >= s for n, s in zip(lights, sizes))
    assert all(block_lights(s) > s for s in (8, 16, 32, 64))
    assert lights == sorted(lights)
    assert block_lights(4096) == 4096 and block_lights(2048) == 2048


def test_the_sharp_block_reads_the_source_at_its_texel_centres(tmp_path):
    """A mirror-like material reads L(r) times its albedo. At the block's texel centres (where the bilinear read
    is the stored texel) the bake reads stripes four texels wide as the source times one number, within 6 %
    (measured 4.1 %; with lights at the face's size 49 %, the stripes' contrast 0.62 of the source's): the block
    is filtered from lights four times finer than its face, so it is neither box-averaged over its own texels
    nor smoothed by one."""
    img = _radiance(latlong_directions(64, 128))[..., None].repeat(3, -1).astype(np.float32)
    path = write_exr(tmp_path / "stripes.exr", img)
    with optimized_xla():  # helpers.optimized_xla: a bake runs long at -O0
        b = hf.bake(str(path), preset="fast", layers=3, nv_size=8, samples=64, data_resolution=8, diffuse_size=8,
                    max_size=SIZE, analytic_source=False)
    assert b.blocks[0] == 0 and b.P[0].shape[0] == SIZE
    r = np.asarray(mappers.texel_directions("cube", SIZE), np.float64).reshape(-1, 3)
    got = np.asarray(b.terms(r, r, b.roughness[0]), np.float64)[:, 1:, 0].sum(1)  # I_A + I_B at n = v = r
    ratio = got / _radiance(r)  # the albedo (one number) wherever the block holds the source
    assert np.max(ratio) / np.min(ratio) - 1 < 0.06, (np.min(ratio), np.max(ratio))


def test_the_block_lights_lose_the_same_core_as_the_map_the_source_was_found_in():
    """``take_source(64, finer=256)``: the 256 lights, loaded from the source itself, lose the core found at 64
    (the removed power is the light's, its Gaussians' summed, within 5 %) and nothing farther than 0.15 rad from it."""
    lights = _Lights(bundled("city"))
    parts, _ = lights.take_source(64, 256)
    found = parts[0]._replace(power=tuple(np.sum([p.power for p in parts], 0)))
    fine, orig = lights(256), load_environment(bundled("city"), 256)
    d = np.asarray(orig.directions, np.float64)
    dw = np.asarray(orig.solid_angle, np.float64)[:, None]
    removed = np.sum((np.asarray(orig.radiance, np.float64) - np.asarray(fine.radiance, np.float64)) * dw, 0)
    np.testing.assert_allclose(removed, found.power, rtol=0.05)
    far = d @ np.asarray(found.direction) < np.cos(0.15)
    np.testing.assert_array_equal(np.asarray(fine.radiance)[far], np.asarray(orig.radiance)[far])
