"""The 2D table T(n.i, n.v) of a highlight term (``highlights.table``, issue 13): its projection, the lines
turned into a table and back, the structure, the fit (ALS on the lines, the polish on the table), the
chooser's table vote and a refit."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import homofac as hf
from helpers import visible_pairs
from homofac.errors import HomofacError
from homofac.fit import pipeline, structures, table
from homofac.fit.options import FitOptions
from homofac.fit.structures import Structure
from homofac.param import mappers
from homofac.param import projections as pj

SUN = np.array([0.5, -0.3, 0.81])
SUN /= np.linalg.norm(SUN)
GRID = {"kind": "grid", "size": 8, "mapper": "dual_paraboloid", "count": 8000, "validation": 1500, "cache": False}
LINES = Structure("RO", 1, "fitted", True, highlights={"terms": 1, "fresnel": True, "cosine": True})
TABLE = structures.tabled(LINES)


def _pairs(count: int, seed: int = 5):
    return visible_pairs(count, seed)


def test_the_table_coordinate_holds_both_cosines_inside_the_parabolic_disk():
    n, v = _pairs(5000)
    ctx = {"dominant": SUN}
    d = np.asarray(pj.apply("ninv_dom", n, v, ctx), np.float64)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)
    assert np.all(d[:, 2] > 0)  # the upper hemisphere: any lighting mapper and parabolic hold it
    _, u, w = mappers.get("parabolic").to_face_uv(d)
    ni, nv = pj.table_cosines(u, w)  # the inverse reads both cosines back
    np.testing.assert_allclose(ni, np.clip(n @ SUN, 0, 1), atol=1e-5)
    np.testing.assert_allclose(nv, np.clip(np.sum(n * v, 1), 0, 1), atol=1e-5)
    # the square lies inside the disk with a texel to spare: every bilinear texel is valid down to 32 texels
    corners = pj.table_point(np.array([0.0, 0.0, 1.0, 1.0]), np.array([0.0, 1.0, 0.0, 1.0]))
    for size in (32, structures.TABLE_SIZE):
        idx, wts = mappers.bilinear("parabolic", np.asarray(corners, np.float32), size)
        assert np.all(mappers.valid_mask("parabolic", size).reshape(-1)[np.asarray(idx)])
        np.testing.assert_allclose(np.asarray(wts).sum(1), 1.0, atol=1e-6)
    assert not pj.get("ninv_dom").scalar and pj.get("ninv_dom2").context == ("dominant2",)


def test_the_table_in_the_skeleton_label_record_and_refusals():
    assert TABLE.label() == "E'+ROW x1+HFT x1" and LINES.label() == "E'+ROW x1+HFCW x1"
    assert structures.lookups(TABLE, "lighting") == structures.lookups(LINES, "lighting") - 1
    specs, terms = structures.skeleton(TABLE, "lighting", "lighting", "dual_paraboloid", 8)
    assert terms[-1].factors == (("nh_dom", "d1"), ("vh_dom", "f1"), ("ninv_dom", "T1"))
    assert ("T1", "parabolic", structures.TABLE_SIZE, "table") in specs
    assert Structure.of(TABLE.record()) == TABLE and structures.lined(TABLE) == LINES
    with pytest.raises(HomofacError, match="not both"):
        TABLE.with_highlights(cosine=True)
    with pytest.raises(HomofacError, match="set highlights.terms"):
        Structure("RO", 1, highlights={"table": True})
    with pytest.raises(HomofacError, match="cosine line"):
        structures.tabled(LINES.with_highlights(cosine=False))


@pytest.fixture(scope="module")
def target():
    env = hf.light.sun_sky(SUN, sun_radiance=3.0e3, sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6), resolution=8)
    return hf.light.lighting_target(hf.brdf.ggx(kd=0.3, ks=1.0, roughness=0.4, f0=0.04), env, parametrization="RO")


def _fit(target, samples, polish: int, linear: dict | None = None, **highlights):
    return hf.fit.factorize(target, "RO", texture_size=8, samples=samples, diffuse="fitted", nv_factor=True,
                            advanced={"highlights": {"terms": 1, "fresnel": True, **highlights},
                                      "linear": {"polish": polish, **(linear or {})}})


@pytest.fixture(scope="module")
def samples(target):
    return hf.fit.draw_samples(target, "RO", GRID)


@pytest.fixture(scope="module")
def lines(target, samples):
    """A dielectric under a sun, fitted with lines (the ALS fit alone: what tabulate and separate read)."""
    return _fit(target, samples, 0, {"iterations": 4}, cosine=True)


@pytest.fixture(scope="module")
def fits(target, samples):
    """The same, lines and tables, each polished twice off the grid on the same pairs (the slow tests')."""
    return _fit(target, samples, 2, cosine=True), _fit(target, samples, 2, table=True)


def test_tabulate_keeps_the_model_and_separate_recovers_the_lines(lines):
    model = lines.model
    tab = table.tabulate(model, TABLE)
    assert tab.lookups == model.lookups - 1 and "T1" in [t.name for t in tab.textures]
    assert not {"c1", "w1"} & {t.name for t in tab.textures}
    n, v = _pairs(20000)
    ctx_n, ctx_v = jnp.asarray(n, jnp.float32), jnp.asarray(v, jnp.float32)
    ref = np.asarray(model.evaluate(ctx_n, ctx_v))
    scale = np.sqrt(np.mean(ref ** 2))
    # the same function up to the bilinear interpolation of a product (a 58-texel square against 32-texel lines)
    assert np.sqrt(np.mean((np.asarray(tab.evaluate(ctx_n, ctx_v)) - ref) ** 2)) < 0.01 * scale
    back = table.separate(tab, 32)
    assert [(f.projection, f.texture) for f in back.terms[-1].factors] == \
        [(f.projection, f.texture) for f in model.terms[-1].factors]
    assert np.sqrt(np.mean((np.asarray(back.evaluate(ctx_n, ctx_v)) - ref) ** 2)) < 0.01 * scale
    with pytest.raises(HomofacError, match="reads no table"):
        table.tabulate(model, LINES)


@pytest.mark.slow  # two polished fits (about 50 s of compiling); the fast suite tabulates the ALS fit above
def test_a_polished_table_fits_a_dielectric_under_a_sun_better_with_one_lookup_fewer(fits, tmp_path):
    """The property the table is for: the highlight's min(1, n.i / n.v) near the mirror direction is no
    product c(n.i) w(n.v); the ALS fits the lines, the table starts as their product and the polish
    refines it (the lines' ALS fit and the tabulated one agree before the polish)."""
    lines, tab = fits
    assert tab.model.lookups == lines.model.lookups - 1
    assert tab.solver["structure"] == TABLE.record() and tab.solver["table"]["lines"] == LINES.record()
    assert tab.solver["method"] == "als" and tab.solver["polish"]["steps"] == 2
    e_lines = lines.metrics["validation"]["float"]["nrmse"]
    e_tab = tab.metrics["validation"]["float"]["nrmse"]
    assert e_tab < 0.9 * e_lines, (e_tab, e_lines)
    T = np.asarray(tab.model.texture("T1").data)
    assert np.all(np.isfinite(T)) and T.shape == (structures.TABLE_SIZE, structures.TABLE_SIZE, 3)
    tab.save(tmp_path / "out")
    back = hf.output.load(tmp_path / "out")
    n, v = _pairs(500)
    np.testing.assert_allclose(np.asarray(back.model.evaluate(n, v)), np.asarray(tab.model.evaluate(n, v)),
                               rtol=1e-5, atol=1e-6)


@pytest.mark.slow
def test_a_refit_of_a_table_repeats_its_run_and_starts_from_the_separated_lines(fits, target):
    _, tab = fits
    again = hf.fit.refit(tab, target=tab.target, start="fresh")  # the same target: the ALS on the lines, the table, the polish
    np.testing.assert_allclose(again.metrics["validation"]["float"]["nrmse"],
                               tab.metrics["validation"]["float"]["nrmse"], rtol=1e-3)
    warm = hf.fit.refit(tab, target=tab.target)  # from the table's best rank-1 lines
    assert warm.solver["structure"] == TABLE.record()
    assert warm.metrics["validation"]["float"]["nrmse"] < 1.1 * tab.metrics["validation"]["float"]["nrmse"]


def test_the_quality_mode_candidates_read_tables_where_they_would_read_the_cosine_line():
    lines = structures.candidates("lighting", 16)
    tables = structures.candidates("lighting", 16, table=True)
    assert any(c.highlights.cosine for c in lines) and not any(c.highlights.table for c in lines)
    assert not any(c.highlights.cosine for c in tables) and any(c.highlights.table for c in tables)
    assert all(structures.lookups(c, "lighting") <= 16 for c in tables)
    # the lookup a table saves goes to a term: gold's E'+ROW x3+R+HFCW x2 becomes E'+ROW x4+R+HFT x2
    gold = Structure("RO", 3, "fitted", True, reflection=True, highlights={"terms": 2, "fresnel": True, "cosine": True})
    assert gold in lines and structures.tabled(gold).replace(terms=4) in tables
