"""homofac inside the real three.js (npm package ``three``, headless Chromium, WebGL2 on SwiftShader).

A bundled glTF asset (``data/assets/material_sphere.glb``: base colour, metallic and roughness textures) is
rendered with three's MeshStandardMaterial twice: with three's own PMREM of the environment, and with
homofac's drop-in (``js/homofac-three.js``: ``loadBake``, ``applyBake``) reading a bake of the same
environment. The G-buffer of the same view (world normal, view direction, base colour, metallic and the
roughness three shades with) is read back, so Python evaluates at every covered pixel
(``tests/threejs/scene.py``):

* the bake itself (``hf.load(dir).evaluate``): homofac's 8-bit render equals it within 2/255;
* the exact lighting of the pinned glTF BRDF (``homofac.light.reference``, converged MIS, float64): PMREM's
  and homofac's nrmse against it, homofac's lower.

The bake is written with KTX2 files and the page reads them with three's own KTX2Loader. The recipe's two
pages (PMREM and the drop-in) and js/examples/side-by-side.html run as written.
"""

from __future__ import annotations

import json
import re
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

import homofac as hf
from browser import chromium, console_problems, missing, serve, wait_for
from homofac.light.sources import bundled

sys.path.insert(0, str(Path(__file__).resolve().parent / "threejs"))
from scene import ROOT, edge_texels, nrmse, render, seams  # noqa: E402  (tests/threejs is not a package)

SIZE = 64
ENV = "forest"
#: First sample count per strategy of the converged reference (doubled until the image moves < 0.5 %).
REFERENCE_SAMPLES = 4096

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    if not (ROOT / "js" / "node_modules" / "three").is_dir():
        missing("js/node_modules/three is missing (make js-packages)")
    bake = hf.bake(ENV, preset="fast", max_size=32, diffuse_size=16, data_resolution=8, samples=256)
    out = render(ENV, bake, tmp_path_factory.mktemp("three"), SIZE, REFERENCE_SAMPLES)
    assert out["setup"] is True and out["lookups"][0] == bake.lookups, (out["setup"], out["lookups"])
    return out


def test_the_bake_textures_are_read_by_threes_ktx2loader(rendered):
    """Every texture of the bake comes from its .ktx2 file through three's KTX2Loader (the render checks below
    then hold for what an engine loads from our KTX2 files)."""
    doc = json.loads((rendered["work"] / "bake" / "bake.json").read_text())
    assert all(t.get("ktx2") for t in doc["textures"])
    assert rendered["lookups"][1] == {f"hf_{t['name']}": "KTX2Loader" for t in doc["textures"]}, rendered["lookups"][1]


def test_the_page_renders_without_console_errors(rendered):
    assert not console_problems(rendered["log"]), console_problems(rendered["log"])
    assert rendered["mask"].sum() > 0.3 * SIZE * SIZE  # the sphere fills the view's centre
    # every roughness band and both metallic extremes are on screen
    r, m = rendered["roughness"], rendered["metallic"]
    assert r.min() < 0.15 and r.max() > 0.6 and m.min() < 0.01 and m.max() > 0.99
    # PMREM's memory counts its whole cube: six faces of RGBA half floats and the mips below them
    assert rendered["pmrem_levels"] > 1 and rendered["pmrem_bytes"] > 6 * 8 * rendered["pmrem_size"] ** 2, rendered["pmrem_bytes"]


def test_homofac_in_three_equals_bake_evaluate(rendered):
    """The drop-in's 8-bit output equals the bake's own evaluation at the G-buffer's inputs within 2/255."""
    want = np.clip(rendered["bake"] * rendered["exposure"], 0, 1) * 255
    got = rendered["canvas"][rendered["mask"]][:, :3].astype(np.float64)
    diff = np.abs(got - want)
    assert np.percentile(diff, 99.9) <= 2.0, np.percentile(diff, [50, 99, 99.9, 100])
    flo = rendered["homofac"][rendered["mask"]][:, :3]
    np.testing.assert_allclose(flo, rendered["bake"], rtol=2e-2, atol=2e-3 * float(rendered["bake"].mean()))


def test_physical_material_base_layer_takes_the_bake(rendered):
    """applyBake on MeshPhysicalMaterial (the asset's materials as physical ones, clearcoat, sheen and transmission
    0): its base layer renders what the standard material does with the bake."""
    phys = rendered["physical"][rendered["mask"]][:, :3]
    std = rendered["homofac"][rendered["mask"]][:, :3]
    assert float(np.abs(phys).max()) > 0
    np.testing.assert_allclose(phys, std, rtol=1e-3, atol=1e-4 * float(std.mean()))


def test_homofac_beats_three_pmrem_against_the_exact_lighting(rendered):
    errors = {k: nrmse(rendered, k) for k in ("pmrem", "homofac")}
    print(json.dumps(errors))
    assert errors["homofac"] < errors["pmrem"], errors


RECIPE_PAGE = """<!doctype html><html><head><meta charset="utf-8">
<script type="importmap">{"imports": {"three": "/js/node_modules/three/build/three.module.js",
  "three/addons/": "/js/node_modules/three/examples/jsm/", "/data/homofac-three.js": "/js/homofac-three.js"}}</script>
</head><body><script type="module">
%s
const gl = renderer.getContext();
const px = new Uint8Array(4 * 512 * 512);
gl.readPixels(0, 0, 512, 512, gl.RGBA, gl.UNSIGNED_BYTE, px);
let lit = 0;
for (let i = 0; i < px.length; i += 4) if (px[i] + px[i + 1] + px[i + 2] > 0) lit++;
window.recipe = {lit};
</script></body></html>"""


@pytest.mark.parametrize("block", ["threejs-pmrem", "threejs-dropin"])
def test_the_threejs_recipe_runs_as_written(rendered, tmp_path, block):
    """docs/recipes/threejs.md's PMREM page and its drop-in page, run as written next to a bake, the environment
    and the asset: the sphere is lit and the console is clean."""
    text = (ROOT / "docs" / "recipes" / "threejs.md").read_text()
    code = re.search(rf"<!-- recipe: {block} -->\s*```js\n(.*?)\n```", text, re.S).group(1)
    shutil.copytree(rendered["work"] / "bake", tmp_path / "bake")
    shutil.copy(rendered["work"] / "asset.glb", tmp_path / "asset.glb")
    shutil.copy(bundled(ENV), tmp_path / "forest.exr")
    (tmp_path / "recipe.html").write_text(RECIPE_PAGE % code)
    with serve({"/data": tmp_path, "/": ROOT}) as url, chromium() as browser:
        browser.get(f"{url}/data/recipe.html")
        state, log = wait_for(browser, "recipe")
    assert state, console_problems(log)
    assert state["lit"] > 0.2 * 512 * 512, state  # the sphere covers a good part of the view, lit
    assert not console_problems(log), console_problems(log)


def test_the_side_by_side_page_renders_both_ways(rendered, tmp_path):
    """js/examples/side-by-side.html (one glTF scene, three's PMREM left, homofac's bake right) on the test's bake:
    both views are lit, the right one reports the bake's lookups, and the console is clean."""
    shutil.copytree(rendered["work"] / "bake", tmp_path / "bake")
    query = "?bake=/data/bake/&env=/src/homofac/data/hdri/forest.exr&asset=/src/homofac/data/assets/material_sphere.glb"
    with serve({"/data": tmp_path, "/": ROOT}) as url, chromium() as browser:
        browser.get(f"{url}/js/examples/side-by-side.html{query}")
        state, log = wait_for(browser, "sideBySide")
    assert state, console_problems(log)
    px = state["size"] ** 2
    assert state["lit"][0] > 0.2 * px and state["lit"][1] > 0.2 * px, state
    assert state["label"] == f"homofac bake ({rendered['lookups'][0]} lookups per pixel)", state
    assert not console_problems(log), console_problems(log)


def test_a_bake_with_the_harmonic_renders_in_three_as_bake_evaluate(tmp_path):
    """A bake whose rough layers carry the second harmonic (RGBA specular maps, schema 3) through the same
    drop-in (the generated GLSL ES, its KTX2 files through KTX2Loader) equals its own evaluation within 2/255."""
    if not (ROOT / "js" / "node_modules" / "three").is_dir():
        missing("js/node_modules/three is missing (make js-packages)")
    bake = hf.bake(ENV, preset="fast", harmonic=0.3, max_size=32, diffuse_size=16, data_resolution=8, samples=256)
    out = render(ENV, bake, tmp_path, SIZE, REFERENCE_SAMPLES)
    assert out["setup"] is True and out["lookups"][0] == bake.lookups == 7
    want = np.clip(out["bake"] * out["exposure"], 0, 1) * 255
    got = out["canvas"][out["mask"]][:, :3].astype(np.float64)
    assert np.percentile(np.abs(got - want), 99.9) <= 2.0, np.percentile(np.abs(got - want), [50, 99, 99.9, 100])


def test_the_render_equals_bake_evaluate_on_face_and_block_seams(tmp_path):
    """The schema-5 layout (``balanced``: P_2 in blocks of half the layer's face, one shared zero block, E_d at 16)
    in three: at the pixels whose reads lie within half a texel of a cube face's edge (where the read is clamped
    to the face, and where the atlas blocks meet; scene.edge_texels) and on boundaries between texels, the
    drop-in's render equals ``Bake.evaluate`` as closely as at the interior and the texel centres."""
    if not (ROOT / "js" / "node_modules" / "three").is_dir():
        missing("js/node_modules/three is missing (make js-packages)")
    bake = hf.bake(ENV, preset="balanced", max_size=32, data_resolution=8, samples=256)
    out = render(ENV, bake, tmp_path, SIZE, REFERENCE_SAMPLES)
    loaded = hf.load(tmp_path / "bake")
    assert out["setup"] is True and out["lookups"][0] == loaded.lookups
    sizes = loaded.atlases[1].sizes
    assert any(s < p.shape[0] for s, p in zip(sizes, loaded.P)), sizes  # blocks smaller than their layer's face
    s = seams(out, loaded)
    print(json.dumps(s))
    for seam, inner in (("face_edge", "interior"), ("texel_boundary", "texel_centre")):
        assert s[seam]["pixels"] >= 100 and s[inner]["pixels"] >= 100, s
        assert s[seam]["gpu_cpu"] <= 2.0 * s[inner]["gpu_cpu"] + 2e-3, (seam, s)
    edge, _ = edge_texels(loaded, out["n"], out["v"], out["roughness"])
    want = np.clip(out["bake"] * out["exposure"], 0, 1) * 255
    got = out["canvas"][out["mask"]][:, :3].astype(np.float64)
    diff = np.abs(got - want)[edge < 0.5]
    assert np.percentile(diff, 99.9) <= 2.0, np.percentile(diff, [50, 99, 99.9, 100])
