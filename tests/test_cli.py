"""The CLI and config: valid runs write the pinned output directory; bad input is one line, nothing written."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from homofac.app.cli import fit_epilog
from homofac.app.cli import fit_main as main
from homofac.fit.options import AdvancedOptions, FitOptions, HighlightOptions, LinearOptions

SMALL_BRDF = {
    "target": {"kind": "brdf", "brdf": {"model": "cook_torrance", "kd": 0.1, "ks": 1.0, "roughness": 0.3,
                                         "f0": [1.0, 0.78, 0.34]}},
    "parametrization": "PQP",
    "mapper": "parabolic",
    "texture_size": 8,
    "sampling": {"kind": "texels", "size": 8, "validation": 500, "seed": 0},
    "solver": {"method": "lsmr", "tolerance": 1e-5, "max_iterations": 300, "laplacian": 1.0},
    "output": {"dir": "out", "samples": True},
}


def write_config(tmp_path: Path, cfg: dict | str, name="c.yaml") -> Path:
    p = tmp_path / name
    p.write_text(cfg if isinstance(cfg, str) else yaml.safe_dump(cfg))
    return p


def nested(cfg: dict, path: str, value):
    out = json.loads(json.dumps(cfg))
    keys = path.split(".")
    d = out
    for k in keys[:-1]:
        d = d.setdefault(k, {})
    if value is _DELETE:
        del d[keys[-1]]
    else:
        d[keys[-1]] = value
    return out


_DELETE = object()


def leftovers(tmp_path: Path) -> list[str]:
    """Anything homofac may have left behind: outputs or temporary directories."""
    return sorted(p.name for p in tmp_path.iterdir() if p.name not in ("c.yaml", "file.txt", "foreign"))


@pytest.mark.slow
def test_brdf_run_writes_pinned_output(tmp_path):
    cfg = write_config(tmp_path, SMALL_BRDF)
    assert main([str(cfg), "--quiet"]) == 0
    out = tmp_path / "out"
    doc = json.loads((out / "factorization.json").read_text())
    assert doc["parametrization"] == "PQP"
    assert [t["name"] for t in doc["textures"]] == ["p", "q"]
    assert [f["projection"] for f in doc["factors"]] == ["wi", "h", "wo"]
    assert doc["target"]["quantity"] == "brdf"
    for split in ("train", "validation"):
        for kind in ("float", "quantized"):
            m = doc["metrics"][split][kind]
            assert set(m) >= {"avg_abs", "max_abs", "avg_rel", "max_rel", "rms", "nrmse", "log_rms"}
            assert all(np.isfinite(v) for v in m.values())
    assert {"sample_s", "solve_s", "total_s"} <= set(doc["timings"])
    assert doc["counts"]["train"] > 0 and doc["counts"]["validation"] == 500
    assert doc["solver"]["method"] == "lsmr" and doc["solver"]["iterations"] > 0
    assert doc["config"]["texture_size"] == 8
    for t in doc["textures"]:
        assert (out / t["file"]).is_file()
    s = np.load(out / "samples.npz")
    assert set(s.files) == {"a", "b", "y", "val_a", "val_b", "val_y"}
    assert s["a"].dtype == np.float32 and len(s["val_a"]) == 500
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


@pytest.mark.slow
def test_load_reproduces_metrics(tmp_path):
    from homofac.fit.metrics import metrics
    from homofac.output import load

    cfg = write_config(tmp_path, SMALL_BRDF)
    assert main([str(cfg), "--quiet"]) == 0
    fac = load(tmp_path / "out")
    s = np.load(tmp_path / "out" / "samples.npz")
    approx = np.asarray(fac.evaluate(s["val_a"], s["val_b"])) * np.maximum(s["val_a"][:, 2:3], 0)
    exact = s["val_y"] * np.maximum(s["val_a"][:, 2:3], 0)
    m = metrics(approx, exact)
    assert m["nrmse"] == pytest.approx(fac.metrics["validation"]["float"]["nrmse"], rel=1e-4)


def test_rerun_replaces_previous_result_whole(tmp_path):
    cfg = write_config(tmp_path, SMALL_BRDF)
    assert main([str(cfg), "--quiet"]) == 0
    (tmp_path / "out" / "stale.txt").write_text("old")
    assert main([str(cfg), "--quiet"]) == 0
    assert not (tmp_path / "out" / "stale.txt").exists()


BAD = [
    ("malformed yaml", "target: {kind: brdf\n  brdf: [", "malformed YAML"),
    ("unknown key", nested(SMALL_BRDF, "solver.tolerence", 1e-3), "solver: unknown key tolerence (did you mean tolerance?)"),
    ("wrong type", nested(SMALL_BRDF, "texture_size", "big"), "texture_size"),
    ("unknown model", nested(SMALL_BRDF, "target.brdf.model", "glossy9000"), "glossy9000"),
    ("unknown parametrization", nested(SMALL_BRDF, "parametrization", "XYZ"), "XYZ"),
    ("lighting param for brdf", nested(SMALL_BRDF, "parametrization", "NR"), "NR"),
    ("texture too small", nested(SMALL_BRDF, "texture_size", 2), "texture_size"),
    ("texture absurd", nested(SMALL_BRDF, "texture_size", 100000), "texture_size"),
    ("nan roughness", nested(SMALL_BRDF, "target.brdf.roughness", float("nan")), "roughness"),
    ("negative kd", nested(SMALL_BRDF, "target.brdf.kd", -0.5), "kd"),
    ("missing merl", nested(SMALL_BRDF, "target.brdf", {"model": "merl", "file": "nope.binary"}), "nope.binary"),
    ("missing brdf", nested(SMALL_BRDF, "target.brdf", _DELETE), "target.brdf"),
    ("empty file", "", "empty"),
    ("not a mapping", "- 1\n- 2\n", "mapping"),
    ("research key at the top", nested(SMALL_BRDF, "highlight_disc", True),
     "highlight_disc is an advanced key: write it under advanced: (advanced.highlights.disc)"),
    ("unknown advanced key", nested(SMALL_BRDF, "advanced.highlights.dics", True),
     "advanced.highlights: unknown key dics (did you mean disc?)"),
]


@pytest.mark.parametrize("name,cfg,needle", BAD, ids=[b[0] for b in BAD])
def test_bad_config_is_one_line_and_writes_nothing(tmp_path, capsys, name, cfg, needle):
    path = write_config(tmp_path, cfg)
    code = main([str(path)])
    err = capsys.readouterr().err.strip()
    assert code == 2
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("homofac: error:"), err
    assert needle in lines[0]
    assert "Traceback" not in err
    assert leftovers(tmp_path) == []


def test_truncated_merl_is_refused(tmp_path, capsys):
    from homofac import brdf

    table = brdf.tabulate_merl(brdf.lambert(kd=0.5), dims=(90, 90, 180))
    path = tmp_path / "m.binary"
    brdf.save_merl(path, table)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    cfg = write_config(tmp_path, nested(SMALL_BRDF, "target.brdf", {"model": "merl", "file": "m.binary"}))
    assert main([str(cfg)]) == 2
    err = capsys.readouterr().err
    assert "m.binary" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_output_path_that_is_a_file(tmp_path, capsys):
    (tmp_path / "file.txt").write_text("precious")
    cfg = write_config(tmp_path, SMALL_BRDF)
    assert main([str(cfg), "--out", str(tmp_path / "file.txt")]) == 2
    assert "not a directory" in capsys.readouterr().err
    assert (tmp_path / "file.txt").read_text() == "precious"


def test_foreign_directory_is_never_overwritten(tmp_path, capsys):
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("years of work")
    cfg = write_config(tmp_path, SMALL_BRDF)
    assert main([str(cfg), "--out", str(foreign)]) == 2
    assert "not written by homofac" in capsys.readouterr().err
    assert (foreign / "thesis.tex").read_text() == "years of work"


def test_debug_shows_traceback(tmp_path):
    cfg = write_config(tmp_path, nested(SMALL_BRDF, "target.brdf.model", "glossy9000"))
    with pytest.raises(Exception):
        main([str(cfg), "--debug"])


@pytest.mark.slow  # compile- or subprocess-heavy: with the slow set, to keep the fast suite under 5 min
def test_help_documents_options():
    r = subprocess.run([sys.executable, "-m", "homofac.fit", "--help"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0
    for word in ("--out", "--debug", "--quiet", "parametrization", "sampling", "solver", "texture_size"):
        assert word in r.stdout


def test_help_names_every_key_of_the_fit_and_of_its_linear_fit():
    """--help's config summary is derived from the option models: every FitOptions, advanced and LinearOptions key."""
    text = fit_epilog()
    missing = [k for k in (*FitOptions.model_fields, *AdvancedOptions.model_fields, *HighlightOptions.model_fields,
                           *LinearOptions.model_fields) if k not in text]
    assert not missing, missing


@pytest.mark.slow
def test_default_run_as_a_user_would(tmp_path):
    """`python -m homofac.fit` with no config runs the bundled default (data/default.yaml: its preset, sizes
    and environment, nothing shrunk) and writes a valid directory with its preview, as `make run` does. The
    suite's one run of the true default end to end: the README, notebook and memory-estimate tests run
    the same code at smaller sizes."""
    from PIL import Image

    from homofac.gl import picture

    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    r = subprocess.run([sys.executable, "-m", "homofac.fit", "--quiet"], cwd=tmp_path, capture_output=True,
                       text=True, timeout=900, env=env)
    assert r.returncode == 0, r.stderr
    out = tmp_path / "out"
    doc = json.loads((out / "factorization.json").read_text())
    assert doc["format"] == "homofac.factorization"
    assert np.isfinite(doc["metrics"]["validation"]["float"]["nrmse"])
    assert "preview" not in doc  # the preview is no part of the pinned document
    if os.environ.get("HOMOFAC_REQUIRE_GL") == "0":  # a machine without EGL: the run warns and goes on
        assert (out / "preview.png").is_file() or "preview.png skipped" in r.stderr
        return
    img = np.asarray(Image.open(out / "preview.png").convert("RGB"))
    background = (img == picture.BACKGROUND).all(axis=-1)
    assert 1 - background.mean() > 0.2
    assert len(np.unique(img[~background], axis=0)) > 100


API_CASES = [
    ("sampling", {"kind": "texels", "sise": 8}, "sampling: unknown key sise (did you mean size?)"),
    ("solver", {"methd": "lsmr"}, "solver: unknown key methd (did you mean method?)"),
    ("solver", {"tolerance": "small"}, "solver.tolerance: Input should be a valid number"),
    ("solver", {"method": "lsmr", "max_iterations": 1.5}, "solver.max_iterations: Input should be a valid integer"),
    ("texture_size", 2000, "texture_size: Input should be less than or equal to 1024"),
    ("mapper", "cubee", "(did you mean cube?)"),
    ("sampling", {"\n": None}, "sampling: unknown key '\\n'"),  # a key with a newline stays on one line
    ("linear", {"polish": 1}, "linear is an advanced key: write it under advanced: (advanced.linear)"),
    ("advanced", {"line_size": 1}, "advanced.line_size: Input should be greater than or equal to 2"),
]


@pytest.mark.parametrize("key,value,needle", API_CASES)
def test_python_api_refuses_exactly_as_the_cli(tmp_path, capsys, key, value, needle):
    """One validation layer: hf.fit.factorize and the CLI give the same one-line message for the same bad value."""
    import homofac as hf

    target = hf.fit.brdf_target(hf.brdf.lambert(0.5))
    with pytest.raises(hf.HomofacError) as e:
        hf.fit.factorize(target, "PQP", **{key: value})
    api = str(e.value)
    assert needle in api
    cfg = json.loads(json.dumps(SMALL_BRDF))
    cfg[key] = value
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(cfg))
    assert main([str(path), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"homofac: error: {path}: {api}"


def test_the_disc_line_names_both_structures_the_radius_and_the_kept_one():
    from homofac.app.cli import disc_line

    note = {"radii": [0.0227], "labels": ["E'+ROW x4+R+HFT x2", "E'+ROW x4+R+HSFT x2"], "validation_nrmse": [0.07, 0.08],
            "validation_ridge_nrmse": [0.14, 0.12], "kept": True}
    assert disc_line(note) == ("disc: validation nrmse with the ridge stratum E'+ROW x4+R+HFT x2 0.14, "
                               "E'+ROW x4+R+HSFT x2 0.12 (disc radius 1.3 degrees); the disc kept")
    plain = {k: v for k, v in note.items() if k != "validation_ridge_nrmse"}
    assert disc_line({**plain, "kept": False}).endswith("0.08 (disc radius 1.3 degrees); the point light kept")


def test_the_polish_line_reads_every_record_generation():
    """The run summary's polish line: three or two stages voted on with the ridge stratum, the one-stage
    records of 2026-12-05 and the older ones without ``kept`` (the polish was always kept then)."""
    from homofac.app.cli import polish_line

    two = {"steps": 8, "validation_nrmse_before": 0.062, "validation_ridge_nrmse_before": 0.128,
           "validation_nrmse_after": 0.076, "validation_ridge_nrmse_after": 0.110, "rule": "vote", "kept": True,
           "stage": 0, "ridge": 0, "stages": [{"ridge": 0, "validation_nrmse": 0.076, "validation_ridge_nrmse": 0.110},
                                             {"ridge": 20000, "validation_nrmse": 0.118,
                                              "validation_ridge_nrmse": 0.141}]}
    assert polish_line(two) == ("polish: 8 Levenberg-Marquardt steps off the grid, then 8 more with 20000 ridge "
                                "pairs, validation nrmse with the ridge stratum 0.128 -> 0.11 / 0.141 (stage 1 kept)")
    assert polish_line({**two, "kept": False, "stage": None}).endswith("(not kept)")
    three = {**two, "stage": 2, "ridge": 20000, "start": "als", "validation_nrmse_after": 0.07,
             "validation_ridge_nrmse_after": 0.105,
             "stages": [{**st, "start": start} for st, start in zip(two["stages"], ("als", "polish"))]
             + [{"ridge": 20000, "start": "als", "validation_nrmse": 0.07, "validation_ridge_nrmse": 0.105}]}
    assert polish_line(three) == ("polish: 8 Levenberg-Marquardt steps off the grid, then 8 more with 20000 ridge "
                                  "pairs, or 8 with them from the ALS fit, validation nrmse with the ridge stratum "
                                  "0.128 -> 0.11 / 0.141 / 0.105 (stage 3 kept)")
    direct = {**three, "stages": three["stages"][2:]}  # a plan's polish_direct: the third stage alone
    assert polish_line(direct) == ("polish: 8 Levenberg-Marquardt steps off the grid with 20000 ridge pairs, "
                                   "validation nrmse with the ridge stratum 0.128 -> 0.105 (kept)")
    assert polish_line({**direct, "kept": False, "stage": None}).endswith("0.128 -> 0.105 (not kept)")
    one = {"steps": 8, "validation_nrmse_before": 0.062, "validation_nrmse_after": 0.118, "rule": "vote",
           "kept": False, "ridge": 20000}
    assert polish_line(one) == ("polish: 8 Levenberg-Marquardt steps off the grid and 20000 ridge pairs, "
                                "validation nrmse 0.062 -> 0.118 (not kept)")
    old = {"steps": 8, "validation_nrmse_before": 0.3, "validation_nrmse_after": 0.2}
    assert polish_line(old) == "polish: 8 Levenberg-Marquardt steps off the grid, validation nrmse 0.3 -> 0.2 (kept)"


def test_the_summary_names_a_sum_by_its_structure_label_and_nested_model(capsys):
    """The run summary of a sum: the kept structure's label and its nested model in words, from the
    solver record (also from a record of the flat layout written before the nested model)."""
    from homofac.app.cli import _summary
    from homofac.fit.result import Result
    from homofac.fit.structures import Structure
    from helpers import nrw_sum

    metrics = {"validation": {"float": {"nrmse": 0.1, "avg_rel": 0.2}}}
    structure = Structure("NR", 1, None, True)
    flat = {**{k: v for k, v in structure.record().items() if k != "highlights"}, "highlight_terms": 0}
    for rec in (structure.record(), flat):
        fac = Result(nrw_sum(K=1, S=4), solver={"method": "als", "iterations": 3, "structure": rec}, metrics=metrics)
        _summary(fac, "out", 1.0)
        line = capsys.readouterr().out.splitlines()[0]
        assert line.startswith("wrote out: NRW x1 (NR products x1, nv_factor) on dual_paraboloid 4 (3 lookups)"), line
