"""``python -m homofac.fit --refit OUT_DIR config.yaml`` (issue 15): a saved factorization refitted to the
target a config describes, written like a run; metrics within 1% of a full run of the same config;
configs whose layout differs, and bad saved directories, refused in one line with nothing written.

Small sizes (texture 16, sampling 8, light resolution 8) so the file runs in seconds.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

import homofac as hf
from homofac.app.cli import fit_main as main
from homofac.errors import HomofacError
from helpers import worst

GOLD = {"model": "cook_torrance", "kd": [0.05, 0.04, 0.02], "ks": 1.0, "roughness": 0.3, "f0": [1.0, 0.78, 0.34]}
CFG = {
    "target": {"kind": "lighting", "brdf": GOLD, "environment": {"file": "forest", "resolution": 8}},
    "parametrization": "NR",
    "mapper": "dual_paraboloid",
    "texture_size": 16,
    "sampling": {"kind": "texels", "size": 8, "validation": 2000, "seed": 0, "cache": False},
    "solver": {"method": "lsmr", "tolerance": 1e-6, "max_iterations": 1000, "laplacian": 1.0},
    "output": {"dir": "out", "samples": True, "preview": False},
}


def config(tmp_path: Path, name: str, **changes) -> Path:
    cfg = json.loads(json.dumps(CFG))
    for path, value in changes.items():
        d = cfg
        keys = path.split("__")
        for k in keys[:-1]:
            d = d[k]
        d[keys[-1]] = value
    p = tmp_path / f"{name}.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return p


def metrics(d: Path) -> dict:
    return json.loads((d / "factorization.json").read_text())["metrics"]


def entries(tmp_path: Path) -> list[str]:
    return sorted(p.name for p in tmp_path.iterdir() if p.suffix != ".yaml")


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """A full run of the forest config (the factorization that is refitted), in ``forest``."""
    d = tmp_path_factory.mktemp("refit")
    assert main([str(config(d, "forest")), "--quiet", "--out", str(d / "forest")]) == 0
    return d


@pytest.fixture(scope="module")
def city_full(tmp_path_factory):
    """A full run of the city config: what a refit of ``saved`` to city must equal (the slow tests read it)."""
    d = tmp_path_factory.mktemp("city")
    city = config(d, "city", target__environment={"file": "city", "resolution": 8})
    assert main([str(city), "--quiet", "--out", str(d / "city_full")]) == 0
    return d / "city_full"


@pytest.mark.slow  # compile- or subprocess-heavy: with the slow set, to keep the fast suite under 5 min
def test_refit_through_the_cli_equals_a_full_run(saved, city_full, tmp_path, capsys):
    city = config(tmp_path, "city", target__environment={"file": "city", "resolution": 8})
    out = tmp_path / "city_refit"
    capsys.readouterr()
    assert main([str(city), "--quiet", "--refit", str(saved / "forest"), "--out", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"wrote {out}: NR on dual_paraboloid 16") and "validation nrmse" in lines[0]
    assert lines[1].startswith(f"refit of {saved / 'forest'}: values ") and "solve" in lines[1]
    rel, where = worst(metrics(out), metrics(city_full))
    assert rel < 0.01, where
    doc = json.loads((out / "factorization.json").read_text())
    assert doc["solver"]["refit"] is True
    assert doc["solver"]["method"] == "lsmr" and doc["solver"]["converged"]  # one right-hand side: no factoring
    assert doc["config"]["target"]["environment"]["file"] == "city"
    assert doc["target"]["environment"]["source"].endswith("city.exr") or "city" in json.dumps(doc["target"])
    assert (out / "samples.npz").is_file()
    # the written directory is a normal one: it loads, and its textures reproduce the refit's metrics
    fac = hf.output.load(out)
    assert fac.parametrization == "NR" and fac.texture_size == 16
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_brdf_refit_through_the_cli_equals_a_full_run(saved, tmp_path):
    copper = {**GOLD, "f0": [0.95, 0.64, 0.54], "roughness": 0.3}
    cfg = config(tmp_path, "copper", target__brdf=copper)
    assert main([str(cfg), "--quiet", "--out", str(tmp_path / "full")]) == 0
    assert main([str(cfg), "--quiet", "--refit", str(saved / "forest"), "--out", str(tmp_path / "refit")]) == 0
    rel, where = worst(metrics(tmp_path / "refit"), metrics(tmp_path / "full"))
    assert rel < 0.01, where


def test_refit_output_dir_from_the_config(saved, tmp_path):
    cfg = config(tmp_path, "city", target__environment={"file": "city", "resolution": 8}, output__dir="lib/city")
    assert main([str(cfg), "--quiet", "--refit", str(saved / "forest")]) == 0
    assert hf.output.is_homofac_dir(tmp_path / "lib" / "city")


@pytest.mark.parametrize("change, field", [
    ({"texture_size": 8}, "texture_size"),
    ({"parametrization": "NRV"}, "parametrization"),
    ({"mapper": "cube"}, "mapper"),
    ({"sampling__size": 6}, "sampling.size"),
    ({"sampling__seed": 3}, "sampling.seed"),
    ({"solver__laplacian": 2.0}, "solver.laplacian"),
])
def test_a_different_layout_is_refused_in_one_line(saved, tmp_path, capsys, change, field):
    cfg = config(tmp_path, "bad", target__environment={"file": "city", "resolution": 8}, **change)
    capsys.readouterr()
    assert main([str(cfg), "--quiet", "--refit", str(saved / "forest"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("homofac: error: --refit: the config's layout differs")
    assert f": {field}: " in err, err
    assert entries(tmp_path) == []


def test_bad_refit_inputs_are_refused_in_one_line(saved, tmp_path, capsys):
    city = config(tmp_path, "city", target__environment={"file": "city", "resolution": 8})
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "notes.txt").write_text("mine")
    (tmp_path / "file.txt").write_text("x")
    brdf_cfg = config(tmp_path, "brdf", target={"kind": "brdf", "brdf": GOLD}, parametrization="PQP",
                      mapper="parabolic")
    lib = config(tmp_path, "lib", target={"kind": "lighting", "environment": {"file": "city", "resolution": 8},
                                          "materials": [{"name": "gold", "brdf": GOLD}]})
    cases = [
        ([str(city), "--refit", str(tmp_path / "missing")], "no such directory"),
        ([str(city), "--refit", str(tmp_path / "foreign")], "is not a homofac output directory"),
        ([str(city), "--refit", str(tmp_path / "file.txt")], "not a directory"),
        ([str(brdf_cfg), "--refit", str(saved / "forest")], "target.kind"),
        ([str(lib), "--refit", str(saved / "forest")], "not a library"),
        ([str(city), "--refit", str(saved / "forest"), "--out", str(tmp_path / "foreign")], "not empty"),
    ]
    before = entries(tmp_path)
    for argv, message in cases:
        capsys.readouterr()
        assert main(argv + ["--quiet"]) == 2, argv
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and err.startswith("homofac: error: ") and message in err, (argv, err)
    assert entries(tmp_path) == before  # nothing written, nothing left behind
    assert sorted((tmp_path / "foreign").iterdir()) == [tmp_path / "foreign" / "notes.txt"]


def test_lsmr_refit_equals_the_factored_one(saved):
    fac = hf.fit.prepare_refit(hf.output.load(saved / "forest"))
    city = hf.light.load_environment("city", resolution=8)
    target = hf.light.lighting_target(hf.brdf.cook_torrance(**{k: v for k, v in GOLD.items() if k != "model"}), city)
    lsmr = hf.fit.refit(fac, target=target, solve="lsmr")
    normal = hf.fit.refit(fac, target=target)
    assert lsmr.solver["method"] == "lsmr" and normal.solver["method"].startswith("normal equations")
    for split in normal.metrics:
        for kind in normal.metrics[split]:
            for name, y in normal.metrics[split][kind].items():
                assert abs(lsmr.metrics[split][kind][name] - y) <= 0.01 * max(abs(y), 1e-12), (split, kind, name)
    with pytest.raises(HomofacError, match="solve must be auto or lsmr"):
        hf.fit.refit(fac, target=target, solve="cholesky")


@pytest.mark.slow
def test_refit_through_the_module_entry_point(saved, city_full, tmp_path):
    city = config(tmp_path, "city", target__environment={"file": "city", "resolution": 8})
    r = subprocess.run([sys.executable, "-m", "homofac.fit", str(city), "--quiet", "--refit", str(saved / "forest"),
                        "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[1].startswith(f"refit of {saved / 'forest'}: ")
    rel, where = worst(metrics(tmp_path / "o"), metrics(city_full))
    assert rel < 0.01, where
