"""A mixed bake: K products below the harmonic's roughness, K - 1 products and the second harmonic from it up, in
the same RGBA maps and the same table channels (a_K, b_K carry h_A, h_B in the harmonic layers); each layer's
channels are read with that layer's meaning, so the packing loses nothing against the unpacked layout."""

from __future__ import annotations

import json

import numpy as np
import pytest

import homofac as hf
import test_bake_harmonic as th
from test_bake import check_glsl_terms
from homofac.bake import shader
from homofac.bake.model import Bake
from homofac.errors import HomofacError
from homofac.bake.plan import plan as make_plan

@pytest.fixture
def mixed_bake(forest_bakes):
    """layers 0.3, 0.38, 0.49, 0.62, 0.79, 1: layer 1 stores 2 products, layer 2 (the crossing) 1, layers 3-5 1 + the
    harmonic (its shaders in every language: test_bake.py)."""
    return forest_bakes("mixed")


def _unpacked(b: Bake) -> Bake:
    """The same content in the unpacked layout (plan ``mixed`` off): a_K, b_K = 0 in the harmonic layers and
    h_A, h_B as two channels of their own after the diffuse weights."""
    K = b.plan.terms
    w = np.asarray(b.W, np.float32)
    h = np.zeros(w.shape[:2] + (2,), np.float32)
    harm = list(b.plan.harmonic_layers())
    h[harm] = w[harm, :, 2 * K - 2:2 * K]
    w = w.copy()
    w[harm, :, 2 * K - 2:2 * K] = 0.0
    return Bake(b.plan._replace(mixed=False), b.roughness, b.shift, b.P, b.E, np.concatenate([w, h], -1), b.info,
                blocks=b.blocks, sources=b.sources, H=b.H)


def test_plan_of_a_mixed_bake():
    """balanced + harmonic 0.3, mixed: 2 RGBA maps per layer, 2 tables of 5 channels: 1 + 2 x 2 + 2 = 7 fetches
    (10 unpacked); the layers from 0.3 up and the one below them keep 1 product."""
    pl = make_plan("balanced", harmonic=0.3, mixed=True, diffuse_basis="texture")
    assert (pl.lookups, pl.maps, pl.tables, pl.channels, pl.harmonic_channel) == (7, 2, 2, 5, 2)
    assert make_plan("balanced", harmonic=0.3, mixed=False, shared_gain=False, diffuse_basis="texture").lookups == 10
    rho, h = pl.roughnesses(), pl.harmonic_layers()
    assert h == tuple(j for j in range(pl.layers) if rho[j] >= 0.3) and rho[min(h) - 1] < 0.3
    assert pl.layer_terms() == tuple(1 if j >= min(h) - 1 else 2 for j in range(pl.layers))
    assert f"the harmonic in layers {min(h)}-{pl.layers - 1}" in pl.describe()
    assert make_plan("balanced", harmonic=0.0).layer_terms() == (2,) * 12  # no harmonic: nothing changes
    with pytest.raises(HomofacError, match="mixed needs at least 2"):
        make_plan("fast", harmonic=0.3, mixed=True)
    assert make_plan("balanced", terms=1).mixed is False  # the preset's mixed needs K >= 2


def test_balanced_mixed_from_0_35():
    """The eighteenth session's preset (benchmarks/bake_accuracy.md, balanced+m0.35, E_0 a texture): K = 2 below
    0.35, 1 + the harmonic from the 0.429 layer up (the 0.324 layer the crossing), 7 fetches; --harmonic 0 is the
    plain K = 2 bake."""
    pl = make_plan("balanced", mixed=True, diffuse_basis="texture")
    assert (pl.harmonic, pl.mixed, pl.lookups) == (0.35, True, 7)
    assert pl.layer_terms() == (2,) * 7 + (1,) * 5 and pl.harmonic_layers() == (8, 9, 10, 11)
    assert make_plan("balanced", harmonic=0.0).layer_terms() == (2,) * 12


def test_each_layer_stores_its_own_channels(mixed_bake):
    b = mixed_bake
    assert b.plan.layer_terms() == (2, 2, 1, 1, 1, 1) and b.plan.harmonic_layers() == (3, 4, 5)
    w = np.asarray(b.W)
    assert w.shape[-1] == 5
    assert np.abs(np.asarray(b.P[1])[..., 1, :]).max() > 0 and np.abs(w[1, :, 2:4]).max() > 0
    for j in range(2, 6):  # the crossing and the harmonic layers: no second product
        assert np.all(np.asarray(b.P[j])[..., 1, :] == 0)
    assert np.all(w[2, :, 2:4] == 0) and all(np.abs(w[j, :, 2:4]).max() > 0 for j in (3, 4, 5))
    assert [h is not None for h in b.H] == [False, False, False, True, True, True]
    for j in range(6):  # the second map: P_2's RGB, or the tensor's face gauge
        expect = b.H[j] if b.H[j] is not None else np.asarray(b.P[j])[..., 1, :]
        np.testing.assert_array_equal(shader._specular_layer(b, j, 1), expect)
        np.testing.assert_array_equal(shader._specular_layer(b, j, 0), np.asarray(b.P[j])[..., 0, :])


def test_mixed_terms_equal_the_unpacked_layout(mixed_bake):
    """At every roughness, the two crossings included, the packed channels read what the unpacked layout (each
    channel one meaning) reads: no a_K is blended with an h_A."""
    b = mixed_bake
    n, v = th._pairs(600, 3)
    rho = np.linspace(0.28, 1.0, len(n))
    np.testing.assert_allclose(np.asarray(b.terms(n, v, rho)), np.asarray(_unpacked(b).terms(n, v, rho)), rtol=1e-6, atol=1e-7)


def test_save_load_round_trip_schema_4_and_3(mixed_bake, tmp_path):
    b = mixed_bake
    out = b.save(tmp_path / "m", exr="float32")
    doc = json.loads((out / "bake.json").read_text())
    assert doc["schema_version"] == 8 and doc["plan"]["mixed"] is True and doc["lookups"] == 7
    assert [t["channels"] for t in doc["textures"] if t["kind"] != "diffuse"] == [
        ["P0.r", "P0.g", "P0.b"], ["P1.r/M.uu", "P1.g/M.vv", "P1.b/M.uv"],
        ["a0", "b0", "a1/hA"], ["b1/hB", "w0", "-"]]
    back = hf.load(out)
    n, v = th._pairs(300, 4)
    for rho in (0.35, 0.43, 0.55, 0.9):
        np.testing.assert_allclose(np.asarray(back.terms(n, v, rho)), np.asarray(b.terms(n, v, rho)), rtol=1e-5, atol=1e-7)
    # a schema-4 directory (RGBA maps with the tensor's 5 channels, the layers' x, y) loads as the same bake
    th.write_rgba_schema(b, out, 4)
    np.testing.assert_allclose(np.asarray(hf.load(out).terms(n, v, 0.55)), np.asarray(b.terms(n, v, 0.55)), rtol=1e-4, atol=1e-6)
    # a schema-3 directory (no plan.mixed) still loads, as an unpacked bake
    u = _unpacked(b)
    old = u.save(tmp_path / "u", exr="float32")
    th.write_rgba_schema(u, old, 3)
    doc = json.loads((old / "bake.json").read_text())
    del doc["plan"]["mixed"]
    (old / "bake.json").write_text(json.dumps(doc))
    got = hf.load(old)
    assert got.plan.mixed is False and got.lookups == 10
    np.testing.assert_allclose(np.asarray(got.terms(n, v, 0.55)), np.asarray(b.terms(n, v, 0.55)), rtol=1e-5, atol=1e-7)


def test_gpu_equals_cpu_across_the_crossings(mixed_bake):
    """The GLSL selects each layer's meaning (P_2 below the harmonic layers, the tensor in them) before the blend:
    GPU = CPU in a two-product interval (0.35), across both crossings (0.43, 0.55) and in the harmonic layers."""
    pytest.importorskip("moderngl")
    n, v = th._pairs(1500, 9)
    check_glsl_terms(mixed_bake, n, v, (0.35, 0.43, 0.55, 0.9), 1e-3)


@pytest.mark.parametrize("material", [(0.8, 0.3, 0.2, 0.0, 0.45), (0.95, 0.64, 0.54, 1.0, 0.7)], ids=["dielectric", "metal"])
def test_opengl_recipe_reads_the_mixed_maps(mixed_bake, material, tmp_path):
    """docs/recipes/opengl.md's bake program, run as written on a mixed bake (RGB P maps, the tensor in face-gauge channels), equals its evaluation."""
    import test_recipes_bake as tr
    d = mixed_bake.save(tmp_path / "bake")
    tr.test_opengl_bake_recipe_renders_homofac_ibl((d, hf.load(d)), material, tmp_path)
