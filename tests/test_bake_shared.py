"""The shared gain: the harmonic layers keep K products and the tensor map, and one table channel h_A whose gain
scales I_A and I_B alike (plan ``shared_gain``; ``balanced``: with E_0 as SH9, 0 + 3 maps x 2 + 2 tables = 8
fetches)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import homofac as hf
import test_bake_harmonic as th
from test_bake import check_glsl_terms
from homofac.bake.model import Bake, harmonic_gain
from homofac.bake.plan import plan as make_plan
from homofac.errors import HomofacError

@pytest.fixture
def shared_bake(forest_bakes):
    """layers 0.3, 0.38, 0.49, 0.62, 0.79, 1: layers 3-5 (from 0.55) store the harmonic beside 2 products
    (its shaders in every language: test_bake.py)."""
    return forest_bakes("shared")


def test_balanced_keeps_two_products_in_8_fetches():
    """balanced: K = 2 in every layer, the harmonic from 0.35 in its own map, E_0 as SH9, one h channel: channels
    a0 b0 a1 b1 w0 hA in 2 tables, 0 + 2 x 3 + 2 = 8 fetches."""
    pl = make_plan("balanced")
    assert (pl.shared_gain, pl.mixed, pl.diffuse_basis, pl.harmonic) == (True, False, "sh9", 0.35)
    assert (pl.maps, pl.channels, pl.tables, pl.lookups, pl.harmonic_channel) == (3, 6, 2, 8, 5)
    assert pl.layer_terms() == (2,) * 12
    assert "one harmonic gain" in pl.describe()
    assert make_plan("balanced", shared_gain=False).lookups == 9  # h_B in a third table
    assert make_plan("balanced", harmonic=0.0).shared_gain is False  # nothing to share without the harmonic
    assert make_plan("balanced", mixed=True).shared_gain is False  # mixed keeps h_A, h_B in a_K, b_K's channels
    with pytest.raises(HomofacError, match="shared_gain needs the unpacked harmonic"):
        make_plan("balanced", mixed=True, shared_gain=True)
    assert make_plan("fast").shared_gain is False and make_plan("fast").diffuse_basis == "texture"


def test_one_gain_scales_both_lobes(shared_bake):
    """I_A and I_B of the bake are the products' I_A, I_B times one gain max(0, 1 + h_A H / Y(I_A)): the ratio
    I_B / I_B(no harmonic) equals I_A / I_A(no harmonic), and I_A is what the h_A, h_B layout reads with h_B's
    channel dropped."""
    b = shared_bake
    assert b.plan.shared_gain and np.asarray(b.W).shape[-1] == 6 and b.plan.harmonic_layers() == (3, 4, 5)
    n, v = th._pairs(600, 5)
    rho = np.linspace(0.5, 1.0, len(n))
    got = np.asarray(b.terms(n, v, rho), np.float64)
    flat = Bake(b.plan._replace(harmonic=0.0, shared_gain=False), b.roughness, b.shift, b.P, b.E,
                np.asarray(b.W)[..., :5], b.info, sh=b.sh, blocks=b.blocks, layouts=b.layouts)
    base = np.asarray(flat.terms(n, v, rho), np.float64)
    np.testing.assert_allclose(got[:, 0], base[:, 0], rtol=1e-6, atol=1e-8)  # I_d untouched
    ga = got[:, 1] / np.where(base[:, 1] != 0, base[:, 1], 1)
    gb = got[:, 2] / np.where(base[:, 2] != 0, base[:, 2], 1)
    ok = (np.abs(base[:, 1]) > 1e-4) & (np.abs(base[:, 2]) > 1e-4)
    assert ok.sum() > 1000 and np.abs(ga - 1)[ok].max() > 1e-3  # the harmonic moves these pairs
    np.testing.assert_allclose(gb[ok], ga[ok], rtol=1e-4, atol=1e-6)
    own = Bake(b.plan._replace(shared_gain=False), b.roughness, b.shift, b.P, b.E,
               np.concatenate([np.asarray(b.W), np.zeros(np.shape(b.W)[:2] + (1,), np.float32)], -1), b.info,
               sh=b.sh, blocks=b.blocks, H=b.H, layouts=b.layouts)
    np.testing.assert_allclose(got[:, 1], np.asarray(own.terms(n, v, rho))[:, 1], rtol=1e-6, atol=1e-8)
    assert float(np.asarray(harmonic_gain(np.zeros((1, 3), np.float32), np.ones(1, np.float32)))[0]) == 1.0


def test_save_load_round_trip_schema_7_and_6(shared_bake, tmp_path):
    b = shared_bake
    out = b.save(tmp_path / "s", exr="float32")
    doc = json.loads((out / "bake.json").read_text())
    assert doc["schema_version"] == 8 and doc["plan"]["shared_gain"] is True and doc["lookups"] == 8
    assert [t["channels"] for t in doc["textures"]] == [
        ["P0.r", "P0.g", "P0.b"], ["P1.r", "P1.g", "P1.b"], ["M.uu", "M.vv", "M.uv"], ["a0", "b0", "a1"], ["b1", "w0", "hA"]]
    back = hf.load(out)
    n, v = th._pairs(300, 4)
    for rho in (0.45, 0.55, 0.7, 1.0):
        np.testing.assert_allclose(np.asarray(back.terms(n, v, rho)), np.asarray(b.terms(n, v, rho)), rtol=1e-5, atol=1e-7)
    # a schema-6 document has no plan.shared_gain: its plan is h_A and h_B (9 fetches), so these 8 are refused
    del doc["plan"]["shared_gain"]
    doc["schema_version"] = 6
    (out / "bake.json").write_text(json.dumps(doc))
    with pytest.raises(HomofacError, match="lookups do not match the plan"):
        hf.load(out)


def test_gpu_equals_cpu(shared_bake):
    pytest.importorskip("moderngl")
    n, v = th._pairs(1500, 9)
    check_glsl_terms(shared_bake, n, v, (0.4, 0.55, 0.7, 1.0), 1e-3)
