"""The schema-2 model and the pinned output directory: sums of products, schema 1 compatibility, the
docs' stand-alone NumPy reader.

Multi-term factorizations are built by hand here (a diffuse term on n plus a specular term on r with a
1D factor of n.v) and checked against the sum of their separate evaluations, through evaluate, the
8-bit textures, save / load, the GPU and the exported shaders.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import homofac as hf
from homofac.errors import HomofacError
from homofac.factorization import Factor, Factorization, Term, Texture
from homofac.fit import precision, sampling
from homofac.fit.result import Result
from homofac.output import JSON_NAME
from homofac.param import mappers
from homofac.shader import LANGUAGES
from helpers import nrw_sum, two_terms

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "data"


def _one(model: Factorization, k: int) -> Factorization:
    return Factorization(model.kind, model.quantity, model.textures, (model.terms[k],), model.context, "one")


def _pairs(n=3000, seed=0):
    p = sampling.random_pairs("lighting", n, seed)
    return p.a, p.b


def test_sum_of_products_equals_the_sum_of_its_terms():
    model = two_terms()
    a, b = _pairs()
    whole = np.asarray(model.evaluate(a, b))
    parts = [np.asarray(_one(model, k).evaluate(a, b)) for k in range(2)]
    np.testing.assert_allclose(whole, parts[0] + parts[1], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(np.asarray(model.term_values(a, b)), np.stack(parts), rtol=1e-6, atol=1e-7)
    assert model.lookups == 3 and model.uses("E") == 1
    # by hand: term 2 is correction * bilinear(P, r) * linear(W, n.v)
    r = 2 * np.sum(a * b, 1, keepdims=True) * a - b
    nv = np.clip(np.sum(a * b, 1), 0, 1)
    want = (np.asarray(model.terms[1].correction) * np.asarray(mappers.lookup("dual_paraboloid", model.textures[1].data, r))
            * np.asarray(mappers.lookup("line", model.textures[2].data, nv)))
    np.testing.assert_allclose(parts[1], want, rtol=1e-5, atol=1e-7)


def test_the_model_is_a_pytree_with_gradients():
    model = two_terms()
    a, b = (jnp.asarray(x) for x in _pairs(200))
    g = jax.grad(lambda m: jnp.sum(m.evaluate(a, b) ** 2))(model)
    assert all(np.any(np.asarray(t.data) != 0) for t in g.textures)
    assert np.any(np.asarray(g.terms[0].correction) != 0)


def test_model_structure_is_checked():
    model = two_terms()
    with pytest.raises(HomofacError, match="not one of"):
        Factorization("lighting", "lighting", model.textures, (Term((Factor("n", "X"),), jnp.ones(3)),))
    with pytest.raises(HomofacError, match="scalar"):
        Factorization("lighting", "lighting", model.textures, (Term((Factor("nv", "E"),), jnp.ones(3)),))
    with pytest.raises(HomofacError, match="hemisphere"):
        Factorization("lighting", "lighting", (Texture("t", "parabolic", 8, jnp.ones((8, 8, 3))),),
                      (Term((Factor("r", "t"),), jnp.ones(3)),))
    with pytest.raises(HomofacError, match="unique"):
        Factorization("lighting", "lighting", model.textures[:1] * 2, model.terms[:1])


@pytest.mark.parametrize("signed", [False, True])
def test_multi_term_save_load_round_trip(tmp_path, signed):
    fac = Result(two_terms(signed=signed))
    a, b = _pairs(2000, 4)
    out = fac.save(tmp_path / "o", png=True, shaders=list(LANGUAGES))
    doc = json.loads((out / JSON_NAME).read_text())
    assert doc["schema_version"] == 2 and len(doc["terms"]) == 2 and doc["lookups"] == 3
    assert "factors" not in doc and "correction" not in doc  # schema 1's keys are for one-term results only
    assert [t["mapper"] for t in doc["textures"]] == ["dual_paraboloid", "dual_paraboloid", "line"]
    assert [t["shape"] for t in doc["textures"]] == [[8, 16], [8, 16], [1, 16]]
    for lang in LANGUAGES.values():
        assert (out / lang.file).is_file() and (out / lang.file.replace(".", "_8bit.", 1)).is_file()
    back = hf.load(out)
    np.testing.assert_allclose(np.asarray(back.evaluate(a, b)), np.asarray(fac.evaluate(a, b)), rtol=1e-6, atol=1e-7)
    # the 8-bit textures: per texture offset + scale x code/255 (signed textures get an offset)
    q = np.asarray(back.evaluate(a, b, quantized=True))
    ref = np.asarray(fac.evaluate(a, b))
    assert np.abs(q - ref).max() <= 0.02 * np.abs(ref).max()
    if signed:
        assert min(doc["textures"][1]["png_decode"]["offset"]) < 0
        assert float(np.min(np.asarray(fac.model.textures[1].data))) < 0
    png = hf.load(out, textures="png")
    np.testing.assert_allclose(np.asarray(png.evaluate(a, b)), q, rtol=1e-5, atol=1e-7)


def test_normalize_keeps_a_multi_term_value_and_dilates():
    model = two_terms()
    a, b = _pairs(1000, 2)
    norm = precision.normalize(model)
    np.testing.assert_allclose(np.asarray(norm.evaluate(a, b)), np.asarray(model.evaluate(a, b)), rtol=1e-5, atol=1e-7)
    for t in norm.textures:
        valid = mappers.valid_mask(t.mapper, t.size)
        assert np.abs(np.asarray(t.data)[valid]).max() == pytest.approx(1.0)


@pytest.mark.parametrize("name", ["schema1_nr", "schema1_pqp"])
def test_schema_1_directories_still_load(name):
    """Directories written by homofac 0.1.0 give the values 0.1.0 computed (float and 8-bit)."""
    d = DATA / name
    ref = np.load(d / "expected.npz")
    fac = hf.load(d)
    assert len(fac.model.terms) == 1 and fac.parametrization in ("NR", "PQP")
    # float32 rounding: the reference was computed by XLA's optimized build, the suite compiles with its cheap
    # settings (tests/conftest.py), which round some float32 operations differently (seen: 3e-6 relative)
    np.testing.assert_allclose(np.asarray(fac.evaluate(ref["a"], ref["b"])), ref["float"], rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(np.asarray(fac.evaluate(ref["a"], ref["b"], quantized=True)), ref["quantized"],
                               rtol=1e-5, atol=1e-7)


def test_one_term_results_also_write_schema_1_keys(tmp_path):
    fac = hf.load(DATA / "schema1_nr")
    out = fac.save(tmp_path / "again", png=True)
    doc = json.loads((out / JSON_NAME).read_text())
    assert doc["schema_version"] == 2 and len(doc["terms"]) == 1
    assert doc["parametrization"] == "NR" and doc["mapper"] == "dual_paraboloid" and doc["texture_size"] == 8
    assert doc["factors"] == doc["terms"][0]["factors"] and doc["correction"] == doc["terms"][0]["correction"]
    assert doc["png_decode"]["encoding"] == "rgba8" and doc["png_decode"]["written"] is True
    ref = np.load(DATA / "schema1_nr" / "expected.npz")
    np.testing.assert_allclose(np.asarray(hf.load(out).evaluate(ref["a"], ref["b"])), ref["float"], rtol=2e-6, atol=1e-7)


def _reader_source() -> str:
    """The stand-alone NumPy reader of docs/format.md (the block after the ``<!-- reader -->`` marker)."""
    text = (ROOT / "docs" / "format.md").read_text()
    m = re.search(r"<!-- reader -->\s*```python\n(.*?)```", text, re.S)
    assert m, "docs/format.md has no reader block"
    return m.group(1)


def test_the_documented_numpy_reader_reads_real_directories(tmp_path):
    """The docs' reader (NumPy and OpenEXR only, no homofac) reproduces homofac's values."""
    src = _reader_source()
    assert len([ln for ln in src.splitlines() if ln.strip() and not ln.strip().startswith("#")]) <= 25
    ns: dict = {}
    exec(compile(src, "docs/format.md", "exec"), ns)
    a, b = _pairs(1500, 6)
    for d in (Result(two_terms()).save(tmp_path / "two"), DATA / "schema1_nr"):
        np.testing.assert_allclose(ns["value"](str(d), a, b), np.asarray(hf.load(d).evaluate(a, b)),
                                   rtol=1e-5, atol=1e-6)


def test_a_directory_of_the_previous_layout_is_read_and_prepared_for_a_refit(tmp_path):
    """factorization.json pins "the full resolved config": a directory written before the research keys
    moved under ``advanced`` (research keys at the top of the recorded config, the structure's highlights
    flat in ``solver.structure``) loads, rebuilds its target, agrees with today's config of the same
    layout and is prepared for a refit with the same structure."""
    from homofac.app.config import parse
    from homofac.app.run import layout_difference, target_from_config
    from homofac.fit.structures import Structure

    cfg = parse({"target": {"brdf": {"model": "ggx", "kd": 0.2, "roughness": 0.4, "f0": 0.04},
                            "environment": {"file": "interior", "resolution": 4}},
                 "parametrization": "NR", "texture_size": 4, "terms": 1, "nv_factor": True,
                 "sampling": {"kind": "grid", "count": 3000, "validation": 300, "cache": False},
                 "advanced": {"linear": {"iterations": 2}, "highlights": {"terms": 0}}})
    old = cfg.model_dump(mode="json")
    adv = old.pop("advanced")
    old.update({k: adv[k] for k in ("reflection", "prefiltered", "rw_terms", "line_size", "linear", "baseline",
                                    "analysis")})
    old.update({f"highlight_{k}": v for k, v in adv["highlights"].items()})
    structure = Structure("NR", 1, None, True)
    flat = {k: v for k, v in structure.record().items() if k != "highlights"}
    flat.update({f"highlight_{k}": v for k, v in structure.record()["highlights"].items()})
    Result(nrw_sum(K=1, S=4), solver={"method": "als", "iterations": 2, "converged": True, "structure": flat},
           config=old).save(tmp_path / "old")
    back = hf.load(tmp_path / "old")
    assert "advanced" not in back.config and back.config["highlight_terms"] == 0
    assert Structure.of(back.solver["structure"]) == structure
    assert target_from_config(back) is not None
    assert layout_difference(back.config, cfg, "lighting") is None  # today's config describes the old layout
    ready = hf.fit.prepare_refit(back)
    assert ready.state.structure == structure and ready.state.options.advanced.linear.iterations == 2
