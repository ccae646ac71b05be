"""One memory estimate covers fit, view, preview and load, and refuses before work (issue 40, item 3).

Reproduced faults: ``homofac.view`` / ``homofac.preview`` of a saved config at environment resolution
1024 applied no budget (killed by the system at 17 GB); the fit's estimate ignored ``sampling.count``
for ``kind: scene`` (the same at any count); loading an output directory capped each texture but not
their total (64 entries naming one EXR: gigabytes).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from homofac.app import budget
from homofac.app import config as cfgmod
from homofac.errors import HomofacError
from homofac.io.exr import write_exr
from homofac.output import JSON_NAME, load

ROOT = Path(__file__).resolve().parents[2]
PY = sys.executable
SCHEMA1 = ROOT / "tests" / "data" / "schema1_nr"


def _scene_cfg(count: int) -> cfgmod.Config:
    return cfgmod.parse({
        "target": {"kind": "lighting", "brdf": {"model": "lambert"}, "environment": {"file": "forest", "resolution": 8}},
        "parametrization": "NR", "texture_size": 16,
        "sampling": {"kind": "scene", "mesh": "demo", "count": count},
    })


def test_the_estimate_counts_the_scene_samples():
    small, big = budget.estimate(_scene_cfg(1000)), budget.estimate(_scene_cfg(100_000_000))
    assert small["pairs"] == 1000 and big["pairs"] == 100_000_000
    assert big["total"] > small["total"] + 100_000_000 * 72  # at least the samples themselves
    with pytest.raises(HomofacError) as e:
        budget.check(_scene_cfg(100_000_000), limit_bytes=8 << 30)
    assert "\n" not in str(e.value) and "100,000,000 training pairs" in str(e.value) and "estimated memory" in str(e.value)
    every = budget.estimate(_scene_cfg(0))  # every covered pixel once: at most the cameras' pixels
    assert every["pairs"] == budget.scene_pixels(_scene_cfg(0).sampling) > 0


def _saved_at(tmp_path: Path, resolution: int) -> Path:
    d = tmp_path / f"res{resolution}"
    shutil.copytree(SCHEMA1, d)
    doc = json.loads((d / JSON_NAME).read_text())
    doc["config"] = {"target": {"kind": "lighting", "brdf": {"model": "lambert"},
                                "environment": {"file": "forest", "resolution": resolution}},
                     "parametrization": "NR", "mapper": "dual_paraboloid", "texture_size": 8}
    (d / JSON_NAME).write_text(json.dumps(doc))
    return d


VIEWS = r"""
import json, resource, sys
# an address-space cap: without the budget the view would be killed (17 GB); here it fails instead
resource.setrlimit(resource.RLIMIT_AS, (8 << 30, resource.RLIM_INFINITY))
from homofac.app.cli import preview_main, view_main
codes = [view_main([sys.argv[1], "--html", sys.argv[2]]), preview_main([sys.argv[1], "-o", sys.argv[3]]),
         view_main([sys.argv[4], "--html", sys.argv[2]])]
print(json.dumps(codes))
"""


def test_view_and_preview_refuse_a_saved_config_over_the_budget_before_any_work(tmp_path):
    """Also, under the cap, 64 entries naming one EXR (3.8 GB to load) are refused as over the budget
    (the limit is half of the 8 GB cap), not as "corrupt or truncated?"."""
    d = _saved_at(tmp_path, 1024)
    many = _many_entries(tmp_path)
    r = subprocess.run([PY, "-c", VIEWS, str(d), str(tmp_path / "v.html"), str(tmp_path / "p.png"), str(many)],
                       capture_output=True, text=True, timeout=300)
    assert json.loads(r.stdout.strip().splitlines()[-1]) == [2, 2, 2], r.stderr[-2000:]
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert len(lines) == 3, lines
    for line, what in zip(lines, ("homofac.view", "homofac.preview", "homofac.view")):
        assert line.startswith(f"homofac: error: {what}: estimated memory") and "exceeds the limit" in line, line
    assert "environment resolution 1024" in lines[0] and "environment resolution 1024" in lines[1]
    assert "corrupt" not in lines[2] and "textures 3.5" in lines[2], lines[2]
    assert not (tmp_path / "v.html").exists() and not (tmp_path / "p.png").exists()


def test_the_view_estimate_grows_with_the_lights_and_the_textures(tmp_path):
    low, high = _saved_at(tmp_path, 16), _saved_at(tmp_path, 1024)
    doc = json.loads((low / JSON_NAME).read_text())
    e_low = budget.view_estimate(doc, cfgmod.parse(doc["config"]), 256, low)
    doc_high = json.loads((high / JSON_NAME).read_text())
    e_high = budget.view_estimate(doc_high, cfgmod.parse(doc_high["config"]), 256, high)
    assert e_low["total"] < 2 * budget.GB < 16 * budget.GB < e_high["total"]  # measured 1.45 GB at 256, killed at 17 GB at 1024
    doc["textures"] = doc["textures"] * 32
    assert budget.texture_bytes(doc) == 32 * budget.texture_bytes(json.loads((low / JSON_NAME).read_text()))


def test_loading_caps_the_total_of_the_textures_not_only_each(tmp_path):
    """64 entries naming one EXR of size 1024 (dual paraboloid: 1024 x 2048): each passes the per-texture
    cap, together they would take 1.6 GB of float32 (3.8 GB with the reader's temporaries)."""
    d = _many_entries(tmp_path)
    with pytest.raises(HomofacError) as e:
        load(d)
    msg = str(e.value)
    assert "\n" not in msg and "64 textures need" in msg and "over the memory budget" in msg, msg


def _many_entries(tmp_path: Path) -> Path:
    d = tmp_path / "many"
    if d.exists():
        return d
    shutil.copytree(SCHEMA1, d)
    write_exr(d / "big.exr", np.zeros((1024, 2048, 3), np.float32))
    doc = json.loads((d / JSON_NAME).read_text())
    doc["textures"] = [{"name": f"t{k}", "file": "big.exr", "mapper": "dual_paraboloid", "size": 1024,
                        "shape": [1024, 2048], "factors": [0] if k == 0 else ([1] if k == 1 else [])}
                       for k in range(64)]
    doc["factors"] = [{"projection": "n", "texture": "t0"}, {"projection": "r", "texture": "t1"}]
    doc.pop("png_decode", None)
    (d / JSON_NAME).write_text(json.dumps(doc))
    return d
