"""Each specular map's own atlas (bake.json schema 5): explicit blocks per map, checked on load, read by every
shader language and by ``Bake.terms`` whatever packer placed them."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import homofac as hf
import test_bake_harmonic as th
from homofac.bake import shader
from homofac.bake.atlas import Atlas, bottom_left, check_layout, down, pack, up
from homofac.errors import HomofacError
from helpers import optimized_xla
from test_bake import as_schema_4, check_glsl_terms, check_glslang, check_msl, check_wgsl


def _row_layout(atlas: Atlas, blocks) -> Atlas:
    """The same blocks in one row, last layer's first (another packer's layout: offsets unlike the shelf's)."""
    own = sorted(set(blocks), reverse=True)
    x, at = 0, {}
    for j in own:
        at[j] = (x, 3)
        x += 6 * atlas.sizes[j]
    return Atlas(x, 3 + max(atlas.sizes), tuple(at[b] for b in blocks), atlas.sizes)


def _moved(b):
    """``b`` with every map after the first in :func:`_row_layout` (the first keeps the shelf packer's)."""
    a = b.atlas
    blocks = b.blocks or tuple(range(len(b.P)))
    return dataclasses.replace(b, layouts=(a,) + (_row_layout(a, blocks),) * (b.plan.maps - 1))


@pytest.fixture(scope="module")
def moved(forest_bakes):
    """A plain (RGB, K = 2) and a mixed (RGBA, harmonic) bake, each with its second map in its own layout."""
    plain, mixed = forest_bakes("plain"), forest_bakes("mixed")
    return {"plain": (plain, _moved(plain)), "mixed": (mixed, _moved(mixed))}


def test_check_layout_finds_overlaps_and_blocks_outside():
    assert check_layout(Atlas(96, 16, ((0, 0), (0, 0), (48, 8)), (8, 8, 8))) == (0, 0, 2)
    with pytest.raises(ValueError, match="layers 0 and 1 overlap"):
        check_layout(Atlas(96, 16, ((0, 0), (47, 0)), (8, 8)))
    with pytest.raises(ValueError, match="layers 1 and 2 overlap"):
        check_layout(Atlas(192, 16, ((96, 0), (0, 0), (0, 0)), (8, 16, 8)))  # same corner, another size
    with pytest.raises(ValueError, match="layer 1's block .* outside"):
        check_layout(Atlas(96, 16, ((0, 0), (49, 0)), (8, 8)))


@pytest.mark.parametrize("kind", ["plain", "mixed"])
def test_own_layouts_change_nothing_but_the_files(moved, kind, tmp_path):
    """The maps' texels and the terms are the bake's whatever layout each map has; bake.json lists each map's
    blocks and the directory reads back to the same layouts and terms."""
    b, m = moved[kind]
    assert m.atlases[1] != m.atlases[0] and m.atlases[0] == b.atlas
    n, v = th._pairs(200, 3)
    for rho in (0.05, 0.4, 0.9):
        np.testing.assert_array_equal(np.asarray(m.terms(n, v, rho)), np.asarray(b.terms(n, v, rho)))
    arrays = dict(shader.texture_arrays(m))
    a1 = m.atlases[1]
    assert arrays["hf_P1"].shape[:2] == (a1.height, a1.width)
    assert m.texture_bytes() != b.texture_bytes()
    assert m.texture_bytes() == 2 * sum(np.asarray(x).size for x in arrays.values())  # every texture it binds, in halves
    out = m.save(tmp_path / "b", exr="float32")
    doc = json.loads((out / "bake.json").read_text())
    maps = [t for t in doc["textures"] if t["kind"] == "prefiltered"]
    assert doc["schema_version"] == 8 and doc["texture_bytes_half"] == m.texture_bytes()
    assert [[(k["x"], k["y"], k["size"]) for k in t["blocks"]] for t in maps] == [
        [(x, y, s) for (x, y), s in zip(a.offsets, a.sizes)] for a in m.atlases]
    assert [(t["width"], t["height"]) for t in maps] == [(a.width, a.height) for a in m.atlases]
    back = hf.load(out)
    assert back.atlases == m.atlases and back.blocks == b.blocks
    np.testing.assert_allclose(np.asarray(back.terms(n, v, 0.4)), np.asarray(b.terms(n, v, 0.4)), rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("kind", ["plain", "mixed"])
def test_gpu_reads_each_map_in_its_own_atlas(moved, kind):
    b, m = moved[kind]
    n, v = th._pairs(300, 5)
    src = check_glsl_terms(m, n, v, (0.05, 0.45, 0.9), 1e-4 if kind == "plain" else 1e-3)
    assert "HF_LAYER1[j]" in src and "HF_ATLAS1" in src


def test_own_layouts_compile_and_run_in_every_language(moved, tmp_path):
    m = moved["mixed"][1]
    for language in ("glsl_es", "hlsl"):
        check_glslang(m, language, tmp_path, y_ups=(False,))
    check_msl(m, tmp_path, y_ups=(False,))
    check_wgsl(m, 300, (1e-3, 3e-3))
    check_wgsl(moved["plain"][1], 300, (1e-4, 2e-3))


def _edit(doc: dict, texture: int, layer: int, **block) -> dict:
    bad = json.loads(json.dumps(doc))
    [t for t in bad["textures"] if t["kind"] == "prefiltered"][texture]["blocks"][layer].update(block)
    return bad


def test_loader_checks_each_maps_blocks(moved, tmp_path):
    """A schema-5 bake.json whose blocks overlap, leave the atlas, are neither the layers' sizes nor power-of-two
    fractions of them, or are missing is refused with one line naming it; a map that shares blocks between
    other layers than the first map loads (each map's own rule); schema 4 (x, y of the shelf layout) still loads."""
    b = moved["plain"][0]
    out = b.save(tmp_path / "b", exr="float32")
    f = out / "bake.json"
    doc = json.loads(f.read_text())
    blocks = doc["textures"][0]["blocks"]
    assert blocks[0] == blocks[1] != blocks[2]  # the sharp layers share one block
    height = doc["textures"][1]["height"]
    assert blocks[2]["y"] >= blocks[2]["size"] // 2 and blocks[0]["y"] == 0
    no_blocks = json.loads(json.dumps(doc))
    del no_blocks["textures"][1]["blocks"]
    cases = [
        (_edit(doc, 1, 2, y=blocks[2]["y"] - blocks[2]["size"] // 2), "layers 0 and 2 overlap"),
        (_edit(doc, 1, 2, y=height - blocks[2]["size"] + 1), "outside"),
        (_edit(doc, 0, 2, size=2 * blocks[2]["size"]), "not the layers' sizes"),
        (_edit(doc, 0, 2, size=3 * blocks[2]["size"] // 4), "not the layers' sizes"),
        (no_blocks, "one block per layer"),
    ]
    for bad, message in cases:
        f.write_text(json.dumps(bad))
        with pytest.raises(HomofacError, match=message) as e:
            hf.load(out)
        assert "\n" not in str(e.value)
    own = dataclasses.replace(b, layouts=(b.atlas, bottom_left(b.atlas.sizes)))  # map 1: every layer its own block
    back = hf.load(own.save(tmp_path / "own", exr="float32"))
    assert back.blocks == b.blocks and back.atlases[1].offsets[1] != back.atlases[1].offsets[0]
    np.testing.assert_array_equal(np.asarray(back.P[1]), np.asarray(b.P[1]))
    f.write_text(json.dumps(as_schema_4(doc)))
    np.testing.assert_array_equal(np.asarray(hf.load(out).P[2]), np.asarray(b.P[2]))
    moved_offsets = as_schema_4(doc)
    moved_offsets["layers"][2]["y"] += 1
    f.write_text(json.dumps(moved_offsets))
    with pytest.raises(HomofacError, match="do not match the atlas layout"):
        hf.load(out)


def test_bottom_left_packs_beside_shorter_blocks():
    """The skyline packer puts a block at the lowest free position: the last small block beside a shorter one of
    a full row (the shelf packer opens a row for it), blocks disjoint and inside, shared blocks once."""
    sizes, blocks = (64, 64, 64, 32, 16, 8, 8, 8), (0, 0, 2, 3, 4, 5, 6, 7)
    a = bottom_left(sizes, blocks)
    assert (a.width, a.height) == (384, 64 + 64 + 32) and check_layout(a) == blocks
    assert a.offsets[7] == (192 + 96, 128 + 8)  # on the 8 beside the 16, not on a new row
    assert pack(sizes, blocks).height == 64 + 64 + 32 + 8
    z = bottom_left((8, 8, 32, 32, 8, 16), (0, 0, 2, 3, 0, 5))  # one 8 block shared by layers 0, 1, 4
    assert (z.width, z.height) == (192, 32 + 32 + 16) and check_layout(z) == (0, 0, 2, 3, 0, 5)


def test_down_and_up_per_face():
    t = np.random.default_rng(0).normal(size=(8, 48, 3)).astype(np.float32)
    h = down(t, 2)
    assert h.shape == (4, 24, 3)
    np.testing.assert_allclose(h[1, 7], t[2:4, 14:16].mean(axis=(0, 1)), rtol=1e-6)  # within face 1
    np.testing.assert_array_equal(down(up(h, 2), 2), h)


@pytest.fixture(scope="module")
def halved():
    """``(b, h)``: a balanced (mixed) bake in every map's full-face layout, and the same bake as it is stored
    (P_2 at half its layers' face, one shared block of zeros in the crossing, the tensors at their faces,
    skyline-packed: :func:`homofac.bake.build.map_layouts`)."""
    with optimized_xla():  # its prefilter at -O0: 15.1 s CPU against 8.5 s
        h = hf.bake("forest", preset="balanced", layers=6, min_roughness=0.3, max_size=16, nv_size=8, samples=64,
                    data_resolution=4, harmonic=0.55, mixed=True, diffuse="texture")
    return dataclasses.replace(h, layouts=()), h


def test_stored_layout_halves_p2_and_shares_one_zero_block(halved):
    b, h = halved
    kept, harm = h.plan.layer_terms(), h.plan.harmonic_layers()
    a0, a1 = h.atlases
    assert h.plan.later_face == 2 and h.plan.diffuse_size == 16 and a0.sizes == b.atlas.sizes
    for j, s in enumerate(a0.sizes):
        if j in harm:
            assert a1.sizes[j] == s  # the tensor at its face
        elif kept[j] == 2:
            assert a1.sizes[j] == s // 2 and np.any(np.asarray(h.P[j])[:, :, 1])
        else:  # the crossing: P_2 = 0, the shared zero block
            assert a1.sizes[j] == 8 and not np.any(np.asarray(h.P[j])[:, :, 1])
    zero = [j for j in range(h.plan.layers) if j not in harm and kept[j] < 2]
    assert zero and len({a1.offsets[j] for j in zero}) == 1
    assert h.texture_bytes() < b.texture_bytes()


def test_smaller_blocks_are_read_at_their_size(halved, tmp_path):
    """A block at half its layer's face holds the layer's map box-averaged per face and is read there (not the
    full map): the terms change, the files hold exactly those blocks, and the directory reads back to the same
    terms (the loader replicates the block; its box average is the block)."""
    b, m = halved
    n, v = th._pairs(200, 3)
    assert m.texture_bytes() < b.texture_bytes()
    arrays = dict(shader.texture_arrays(m))
    a = m.atlases[1]
    j = next(j for j in range(m.plan.layers) if 8 <= a.sizes[j] < b.atlas.sizes[j])
    (x, y), s = a.offsets[j], a.sizes[j]
    np.testing.assert_allclose(arrays["hf_P1"][y:y + s, x:x + 6 * s], down(shader._specular_layer(m, j, 1), 2), rtol=1e-6)
    assert not np.allclose(np.asarray(m.terms(n, v, 0.33)), np.asarray(b.terms(n, v, 0.33)))
    back = hf.load(m.save(tmp_path / "h", exr="float32"))
    assert back.atlases == m.atlases
    for rho in (0.3, 0.35, 0.45, 0.9):
        np.testing.assert_allclose(np.asarray(back.terms(n, v, rho)), np.asarray(m.terms(n, v, rho)), rtol=1e-5, atol=1e-7)


def test_gpu_reads_smaller_blocks_as_the_cpu(halved, tmp_path):
    m = halved[1]
    n, v = th._pairs(300, 5)
    check_glsl_terms(m, n, v, (0.3, 0.35, 0.45, 0.9), 1e-3)
    check_wgsl(m, 300, (1e-3, 3e-3))
    check_glslang(m, "glsl_es", tmp_path, y_ups=(False,))


def test_presets_layout_and_the_later_face_option():
    """balanced stores P_2 at half its face and E_d at 16 (0.97x split-sum's memory at the bundled maps' 64),
    fast and best keep their faces; ``later_face`` overrides it (a power of two, at most 8)."""
    from homofac.bake.plan import plan
    assert (plan("balanced").later_face, plan("balanced").diffuse_size) == (2, 16)
    assert (plan("best").later_face, plan("fast").diffuse_size) == (1, 32)
    assert plan("balanced", later_face=1, diffuse_size=32).later_face == 1
    with pytest.raises(HomofacError, match="later_face must be a power of two"):
        hf.bake("forest", later_face=3)


def test_a_sharp_block_finer_than_max_size_and_the_layers_below_max_size_s_half_texel_follow_it():
    """The sharp block's face (plan.block_face): ``factor`` x the source's cube face (at 2 a texel half its lat-long
    pixel), at most BLOCK_MAX and no finer than the sharpest lobe asks; the presets keep it at the source's face
    (factor 1), ``block_size`` sets it. Only the layers whose lobe is at most half a texel of the block share it,
    the other layers sharp at max_size get their own maps up to the block's face, the rest keep max_size: a
    256 x 128 lat-long (face 64) with ``block_size`` 128 has the block and layers 0.079, 0.105 at 128, 0.139 on at
    most 64, and the map layouts put P_2 of the own layers at half their face."""
    from homofac.bake.build import layer_face, map_layouts, sharp
    from homofac.bake.plan import BLOCK_MAX, block_face, plan
    assert block_face(64, 0.045) == 128 and block_face(256, 0.045) == BLOCK_MAX == 256
    assert block_face(64, 0.3) == 32  # pi / 0.09: the lobe asks for no more
    assert block_face(64, 0.045, 1) == 64
    assert all(plan(p, max_size=64, source_face=64).block == 64 for p in ("fast", "balanced", "best"))  # factor 1
    pl = plan("balanced", max_size=64, source_face=64, block_size=128)
    assert pl.block == 128
    rho = pl.roughnesses()
    sizes = [layer_face(r, pl.max_size, pl.block) for r in rho]
    shared = [sharp(r, pl.block) for r in rho]
    assert sizes[:7] == [128, 128, 128, 128, 64, 64, 64] and shared[:3] == [True, True, False]
    assert [layer_face(r, 64, 64) for r in rho][:5] == [64] * 5  # block = max_size: the previous layout
    blocks = tuple(0 if s else j for j, s in enumerate(shared))
    p0, p1 = map_layouts(pl, sizes, blocks, shared, [r >= pl.harmonic for r in rho])[:2]
    assert p0.sizes[:5] == (128, 128, 128, 128, 64) and p1.sizes[:5] == (8, 8, 64, 64, 32)


def test_lights_above_the_coarse_map_come_from_the_finer_lights():
    """After ``take_source(64, finer=256)`` a resolution between them (128, the layers below the block,
    :func:`homofac.bake.build.layer_face`) is the finer lights box-averaged: it keeps their detail (not the 64 map
    upsampled) and loses the same power; 32 still comes from the 64 map."""
    from homofac.bake.build import _Lights
    from homofac.light import load_environment
    from homofac.light.resample import from_cube
    from homofac.light.sources import bundled
    lights = _Lights(bundled("forest"))
    lights.take_source(64, 256)
    fine, mid, coarse = lights(256), lights(128), lights(64)
    strip = np.asarray(fine.radiance, np.float32)[: 6 * 256 * 256].reshape(256, 6 * 256, 3)
    np.testing.assert_allclose(np.asarray(mid.radiance), np.asarray(from_cube(strip, 128).radiance), rtol=1e-6)

    def power(e):
        return np.sum(np.asarray(e.radiance, np.float64) * np.asarray(e.solid_angle, np.float64)[:, None], 0)
    np.testing.assert_allclose(power(mid), power(fine), rtol=1e-5)
    up = np.asarray(from_cube(np.asarray(coarse.radiance, np.float32)[: 6 * 64 * 64].reshape(64, 6 * 64, 3), 128).radiance)
    assert np.max(np.abs(np.asarray(mid.radiance) - up)) > 0.1 * np.max(np.asarray(mid.radiance))  # not the 64 map upsampled
    assert np.abs(power(lights(32)) - power(coarse)).max() < 1e-4 * power(coarse).max()
    assert power(load_environment(bundled("forest"), 128))[0] > power(mid)[0]  # the source is out
