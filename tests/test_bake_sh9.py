"""SH9 as the bake's diffuse term (``diffuse: sh9``): E_d(n) from 9 RGB constants instead of a cube texture,
0 lookups instead of 1 per E_d; the projection, the plan's count, CPU == GPU, the directory, the shaders."""

from __future__ import annotations

import json

import numpy as np
import pytest

import homofac as hf
from homofac.bake import shader
from homofac.bake.model import diffuse_sh9
from homofac.bake.plan import PRESETS, plan as make_plan
from homofac.errors import HomofacError
from homofac.light.sh import sh9_basis
from homofac.param import mappers
from helpers import made_up_bake, visible_pairs
from test_bake import check_glslang


def test_lookups_drop_by_the_diffuse_maps():
    for p in PRESETS:
        tex, sh = make_plan(p, diffuse_basis="texture"), make_plan(p, diffuse_basis="sh9")
        assert sh.lookups == tex.lookups - tex.diffuse and sh.tables == tex.tables
        assert "SH9" in sh.describe()
    assert [make_plan(p, diffuse_basis="sh9").lookups for p in PRESETS] == [3, 8, 14]
    assert [make_plan(p).diffuse_basis for p in PRESETS] == ["texture", "sh9", "texture"]
    with pytest.raises(HomofacError):
        hf.bake("forest", diffuse="sh3")


def test_projection_recovers_a_band_2_map():
    """A map that is a band-2 function is projected back onto its own coefficients (least squares, exact)."""
    rng = np.random.default_rng(4)
    c = rng.normal(size=(2, 9, 3))
    d = mappers.texel_directions("cube", 8).reshape(-1, 3)
    E = np.einsum("ti,dic->tdc", sh9_basis(d), c).reshape(8, 48, 2, 3)
    np.testing.assert_allclose(diffuse_sh9(E), c, rtol=1e-4, atol=1e-5)


def test_sh9_bake_evaluates_its_coefficients_on_cpu_and_gpu():
    """I_d = sum_d (sum_i c_di Y_i(n)) w_d(n.v): the CPU terms equal that formula, the generated GLSL equals the CPU."""
    b = made_up_bake("best", diffuse_basis="sh9")
    tex = made_up_bake("best")
    n, v = visible_pairs(500, seed=5)
    t_sh, t_tex = np.asarray(b.terms(n, v, 0.3)), np.asarray(tex.terms(n, v, 0.3))
    np.testing.assert_allclose(t_sh[:, 1:], t_tex[:, 1:], rtol=1e-6)  # the specular part is untouched
    assert 0 < np.linalg.norm(t_sh[:, 0] - t_tex[:, 0]) / np.linalg.norm(t_tex[:, 0]) < 0.2  # E_d smooth: close
    assert [u for u, _ in shader.texture_arrays(b)] == [f"hf_P{k}" for k in range(5)] + ["hf_W0", "hf_W1", "hf_W2", "hf_W3"]
    pytest.importorskip("moderngl")
    from homofac.gl.engine import run_glsl
    decl = shader.source(b) + ("uniform float rho;\n"
                               "vec3 hf_d(vec3 n, vec3 v) { vec3 d, a, s; homofac_ibl_terms(n, v, rho, d, a, s); return d; }\n")
    gpu = run_glsl(decl, "hf_d(a, b)", n, v, textures=shader.texture_arrays(b), uniforms={"rho": 0.3})
    assert np.abs(gpu - t_sh[:, 0]).max() <= 1e-4 * np.abs(t_sh[:, 0]).max()


def test_directory_holds_coefficients_not_maps(tmp_path):
    b = made_up_bake("fast", diffuse_basis="sh9")
    d = b.save(tmp_path / "b")
    doc = json.loads((d / "bake.json").read_text())
    assert doc["plan"]["diffuse_basis"] == "sh9" and doc["lookups"] == 3
    assert not list(d.glob("E*.exr")) and [t["kind"] for t in doc["textures"]] == ["prefiltered", "weights"]
    loaded = hf.load(d)
    np.testing.assert_allclose(loaded.sh, b.sh, rtol=1e-6)
    n, v = visible_pairs(50, seed=6)
    np.testing.assert_allclose(np.asarray(loaded.terms(n, v, 0.5))[:, 0], np.asarray(b.terms(n, v, 0.5))[:, 0], rtol=2e-3)
    for bad in ([[[1.0, 2.0, 3.0]] * 8], [[[1e400, 0, 0]] * 9]):
        doc["diffuse_sh9"] = bad
        (d / "bake.json").write_text(json.dumps(doc).replace("Infinity", "1e400"))
        with pytest.raises(HomofacError, match="diffuse_sh9") as e:
            hf.load(d)
        assert "\n" not in str(e.value)


@pytest.mark.parametrize("language", ["glsl", "glsl_es", "hlsl"])
def test_sh9_shaders_compile(language, tmp_path):
    b = made_up_bake("balanced", diffuse_basis="sh9")
    src = shader.source(b, language)
    assert "hf_E0" not in src and "hf_sh9_0(n)" in src
    check_glslang(b, language, tmp_path, y_ups=(False,))
