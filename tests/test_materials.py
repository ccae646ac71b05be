"""Material libraries from a config (issue 15): ``target.materials`` fitted on one layout by
``hf.fit.factorize_many``, one pinned output directory per material plus ``index.json``; each equals
a single-material run within 1%; bad configs refused in one line with nothing written; the memory
estimate counts the materials; a failing write leaves the previous library whole.

Small sizes (texture 16, sampling 8, light resolution 8) so the file runs in seconds.
"""

from __future__ import annotations

import errno
import json
import shutil
from pathlib import Path

import pytest
import yaml

import homofac as hf
from homofac import output
from homofac.app import budget, library
from homofac.app import config as cfgmod
from homofac.app.cli import fit_main as main
from homofac.app.run import build_target
from homofac.errors import HomofacError

GOLD = {"model": "cook_torrance", "kd": [0.05, 0.04, 0.02], "ks": 1.0, "roughness": 0.3, "f0": [1.0, 0.78, 0.34]}
PLASTIC = {"model": "cook_torrance", "kd": [0.3, 0.1, 0.1], "ks": 0.5, "roughness": 0.3, "f0": [0.04, 0.04, 0.04]}
COPPER = {"model": "cook_torrance", "kd": 0.0, "ks": 1.0, "roughness": 0.55, "f0": [0.95, 0.64, 0.54]}
MATERIALS = [{"name": "gold", "brdf": GOLD}, {"name": "red-plastic", "brdf": PLASTIC}, {"name": "copper_55", "brdf": COPPER}]
ENV = {"file": "forest", "resolution": 8}
BASE = {
    "parametrization": "NR",
    "mapper": "dual_paraboloid",
    "texture_size": 16,
    "sampling": {"kind": "texels", "size": 8, "validation": 2000, "seed": 0, "cache": False},
    "solver": {"method": "lsmr", "tolerance": 1e-6, "max_iterations": 1000, "laplacian": 1.0},
    "output": {"dir": "lib", "samples": False, "preview": False},
}


def library_config(materials=MATERIALS, **top) -> dict:
    return {"target": {"kind": "lighting", "environment": ENV, "materials": materials}, **BASE, **top}


def write(tmp_path: Path, cfg: dict, name: str = "c.yaml") -> Path:
    p = tmp_path / name
    p.write_text(yaml.safe_dump(cfg))
    return p


def close(a: dict, b: dict, tol: float = 0.01) -> None:
    for split in b:
        for kind in b[split]:
            for name, y in b[split][kind].items():
                x = a[split][kind][name]
                assert abs(x - y) <= tol * max(abs(y), 1e-12), (split, kind, name, x, y)


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    d = tmp_path_factory.mktemp("materials")
    assert main([str(write(d, library_config())), "--quiet"]) == 0
    return d / "lib"


@pytest.mark.slow
def test_index_lists_every_material_with_its_directory_and_metrics(lib):
    index = json.loads((lib / "index.json").read_text())
    assert index["format"] == output.LIBRARY_FORMAT and index["version"] == output.LIBRARY_VERSION
    assert [m["name"] for m in index["materials"]] == ["gold", "red-plastic", "copper_55"]
    assert sorted(p.name for p in lib.iterdir()) == sorted(["index.json", "gold", "red-plastic", "copper_55"])
    for m, spec in zip(index["materials"], MATERIALS):
        assert m["dir"] == m["name"]
        assert m["brdf"]["model"] == "cook_torrance" and m["brdf"]["roughness"] == spec["brdf"]["roughness"]
        doc = json.loads((lib / m["dir"] / "factorization.json").read_text())
        assert m["metrics"]["validation"] == doc["metrics"]["validation"]
        assert 0 < m["metrics"]["validation"]["float"]["nrmse"] < 1
    assert index["layout"] == {"kind": "lighting", "parametrization": "NR", "mapper": "dual_paraboloid",
                               "texture_size": 16, "sampling": index["config"]["sampling"],
                               "train_pairs": index["layout"]["train_pairs"],
                               "validation_pairs": index["layout"]["validation_pairs"]}
    # 250 normals x 8 views; a pair with n.v <= MIN_COS (1e-4) is dropped
    assert 1990 <= index["layout"]["validation_pairs"] <= 2000
    assert index["environment"]["resolution"] == 8
    assert index["timings"]["fit_s"] > 0
    assert output.is_library_dir(lib) and not output.is_homofac_dir(lib)
    assert [p.name for p in lib.parent.iterdir() if p.name.startswith(".")] == []


@pytest.mark.slow
def test_each_directory_loads_and_equals_a_single_material_run(lib, tmp_path):
    for m in MATERIALS:
        d = lib / m["name"]
        fac = hf.load(d)
        assert output.is_homofac_dir(d) and fac.parametrization == "NR" and fac.texture_size == 16
        # the directory records the one-material config a single run of it would be given
        assert fac.config["target"]["brdf"]["f0"] == m["brdf"]["f0"] and fac.config["target"]["materials"] is None
        single = {"target": {"kind": "lighting", "environment": ENV, "brdf": m["brdf"]}, **BASE}
        assert main([str(write(tmp_path, single, f"{m['name']}.yaml")), "--quiet", "--out",
                     str(tmp_path / m["name"])]) == 0
        close(fac.metrics, output.load(tmp_path / m["name"]).metrics)
    # a library member is refitted like any saved factorization
    city = {"target": {"kind": "lighting", "environment": {"file": "city", "resolution": 8}, "brdf": GOLD}, **BASE}
    assert main([str(write(tmp_path, city, "city.yaml")), "--quiet", "--refit", str(lib / "gold"), "--out",
                 str(tmp_path / "gold_city")]) == 0


@pytest.mark.slow
def test_a_failing_write_leaves_the_previous_library_whole(lib, tmp_path, monkeypatch):
    out = tmp_path / "lib2"
    shutil.copytree(lib, out)
    before = json.loads((out / "index.json").read_text())

    def full_disk(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(library, "write_result", full_disk)
    renamed = [{**m, "name": m["name"] + "-2"} for m in MATERIALS]  # same shapes: compiled programs reused
    with pytest.raises(HomofacError, match="cannot write the library"):
        library.run_library(cfgmod.parse(library_config(materials=renamed)), tmp_path, str(out))
    assert json.loads((out / "index.json").read_text()) == before  # the old library, whole
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in lib.iterdir())
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


@pytest.mark.slow
def test_a_kill_between_the_renames_restores_the_previous_library(lib, tmp_path):
    # what a kill between the two renames of the swap leaves: no library, the old one beside it
    shutil.copytree(lib, tmp_path / ".lib.old-0123abcd")
    (tmp_path / ".lib.tmp-89abcdef").mkdir()
    with output.OutputLock(tmp_path / "lib"):
        pass
    assert output.is_library_dir(tmp_path / "lib")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lib"]


@pytest.mark.parametrize("materials, message", [
    ([{"name": "gold", "brdf": GOLD}, {"name": "gold", "brdf": COPPER}], "used twice"),
    ([{"name": "Gold", "brdf": GOLD}, {"name": "gold", "brdf": COPPER}], "differing only in case"),
    ([{"name": "../evil", "brdf": GOLD}], "target.materials.0.name"),
    ([{"name": "a/b", "brdf": GOLD}], "target.materials.0.name"),
    ([{"name": ".hidden", "brdf": GOLD}], "target.materials.0.name"),
    ([{"name": "index.json", "brdf": GOLD}], "target.materials.0.name"),
    ([{"name": "", "brdf": GOLD}], "target.materials.0.name"),
    ([{"name": "x" * 65, "brdf": GOLD}], "target.materials.0.name"),
    ([{"brdf": GOLD}], "name"),
    ([{"name": "gold"}], "brdf"),
    ([{"name": "gold", "brdf": GOLD, "colour": 1}], "unknown key colour"),
    ([], "materials"),
])
def test_bad_library_configs_are_refused_in_one_line(tmp_path, capsys, materials, message):
    capsys.readouterr()
    assert main([str(write(tmp_path, library_config(materials))), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("homofac: error: ") and message in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.yaml"]


def test_brdf_and_materials_together_or_neither_are_refused(tmp_path, capsys):
    both = library_config()
    both["target"]["brdf"] = GOLD
    neither = library_config()
    del neither["target"]["materials"]
    for cfg, message in ((both, "not both"), (neither, "missing brdf: give target.brdf")):
        capsys.readouterr()
        assert main([str(write(tmp_path, cfg)), "--quiet"]) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and "target.materials (a library)" in err and "\n" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.yaml"]


def test_a_foreign_output_directory_is_not_replaced(tmp_path, capsys):
    (tmp_path / "lib").mkdir()
    (tmp_path / "lib" / "mine.txt").write_text("mine")
    assert main([str(write(tmp_path, library_config())), "--quiet"]) == 2
    assert "not empty and was not written by homofac" in capsys.readouterr().err
    assert [p.name for p in (tmp_path / "lib").iterdir()] == ["mine.txt"]


def test_the_memory_estimate_counts_the_materials(tmp_path, capsys):
    one = budget.estimate(cfgmod.parse(library_config(materials=MATERIALS[:1])))
    many = [{"name": f"m{i}", "brdf": {**GOLD, "roughness": 0.1 + 0.05 * i}} for i in range(16)]
    sixteen = budget.estimate(cfgmod.parse(library_config(materials=many)))
    single = budget.estimate(cfgmod.parse({"target": {"kind": "lighting", "environment": ENV, "brdf": GOLD}, **BASE}))
    assert one["total"] == single["total"] and "materials" not in one
    assert sixteen["materials"] > 0 and sixteen["total"] == single["total"] + sixteen["materials"]
    # a limit one material fits in but sixteen do not: refused before any work, nothing written
    limit_gb = (single["total"] + sixteen["materials"] / 2) / budget.GB
    cfg = library_config(materials=many, limits={"memory_gb": limit_gb})
    capsys.readouterr()
    assert main([str(write(tmp_path, cfg)), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "estimated memory" in err and "exceeds the limit" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.yaml"]
    single_cfg = {"target": {"kind": "lighting", "environment": ENV, "brdf": GOLD}, **BASE,
                  "limits": {"memory_gb": limit_gb}}
    budget.check(cfgmod.parse(single_cfg))  # one material passes the same limit


def test_build_target_refuses_a_library():
    with pytest.raises(HomofacError, match="describes a library"):
        build_target(cfgmod.parse(library_config()), Path("."))
