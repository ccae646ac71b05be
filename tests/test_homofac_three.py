"""js/homofac-three.js's loadBake under node (fast; tests/test_threejs.py renders with it in Chromium): a bake's
textures reach three as the files hold them, rows in file order, from the KTX2 files when the bake has them
(ktx-parse, as three ships it) and from the EXR files otherwise (three's EXRLoader, rows put back in file order)."""

from __future__ import annotations

import base64
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from browser import serve
from helpers import made_up_bake
from homofac.io.exr import read_exr

JS = Path(__file__).resolve().parents[1] / "js"
HALF_FLOAT_TYPE = 1016  # three.HalfFloatType


@pytest.fixture(scope="module")
def node():
    path = shutil.which("node")
    if path is None or not (JS / "node_modules" / "three").is_dir():
        pytest.skip("node or js/node_modules/three is missing (make js-packages)")
    return path


@pytest.mark.parametrize("ktx2", [True, False])
def test_load_bake_gives_three_the_files_texels(node, tmp_path, ktx2):
    out = made_up_bake("balanced").save(tmp_path / "bake", ktx2=ktx2)
    doc = json.loads((out / "bake.json").read_text())
    with serve({"/": tmp_path}) as url:
        r = subprocess.run([node, str(JS / "load-bake-info.mjs"), f"{url}/bake/"], capture_output=True, text=True,
                           timeout=60)
    assert r.returncode == 0, r.stderr[-2000:]
    got = json.loads(r.stdout)
    assert got["lookups"] == doc["lookups"]
    assert set(got["textures"]) == {f"hf_{t['name']}" for t in doc["textures"]}
    for t in doc["textures"]:
        g = got["textures"][f"hf_{t['name']}"]
        assert g["source"] == ("ktx-parse" if ktx2 else "EXRLoader")
        assert (g["width"], g["height"], g["type"], g["flipY"]) == (t["width"], t["height"], HALF_FLOAT_TYPE, False)
        texels = np.frombuffer(base64.b64decode(g["data"]), np.float16).reshape(t["height"], t["width"], g["channels"])
        np.testing.assert_array_equal(texels[..., :3].astype(np.float32), read_exr(out / t["file"]))
