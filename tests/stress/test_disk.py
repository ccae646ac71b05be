"""Trust nothing on disk: the cache, output directories, memory before reading, refusals, kills, locks.

Each test reproduces a fault found by trying homofac as a hostile or unlucky user would: a damaged or
foreign cache entry, a factorization.json that points outside its directory or declares absurd sizes,
an image that is small on disk and huge in memory, a useless fit that exited 0 silently, leftovers of
killed runs, unwritable outputs and file-size limits, process memory limits, two runs on one output.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import homofac as hf
from homofac.app import budget
from homofac.app import config as cfgmod
from homofac.app.cli import fit_main as main
from homofac.errors import HomofacError
from homofac.fit import cache
from homofac.fit.draw import draw_samples
from homofac.fit.options import SamplingOptions
from homofac.fit.samples import Samples
from homofac.io.exr import write_exr
from homofac.output import JSON_NAME, OutputLock, load
from homofac.shader import LANGUAGES

ROOT = Path(__file__).resolve().parents[2]
PY = sys.executable

SMALL = {
    "target": {"kind": "brdf", "brdf": {"model": "cook_torrance", "kd": 0.1, "ks": 1.0, "roughness": 0.3,
                                         "f0": [1.0, 0.78, 0.34]}},
    "parametrization": "PQP", "mapper": "parabolic", "texture_size": 6,
    "sampling": {"kind": "texels", "size": 6, "validation": 200, "cache": False},
    "solver": {"tolerance": 1e-4, "max_iterations": 200},
    "output": {"dir": "out", "preview": False, "samples": False},
}


def _write_cfg(d: Path, cfg: dict, name: str = "c.yaml") -> Path:
    p = d / name
    p.write_text(yaml.safe_dump(cfg))
    return p


def _one_line(capsys, code: int) -> str:
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("homofac: error:") and "Traceback" not in err, err
    return lines[0]


# --------------------------------------------------------------------------------------------------
# 1. The samples cache


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    d = tmp_path / "cache"
    monkeypatch.setenv("HOMOFAC_CACHE_DIR", str(d))
    return d


def _lighting(res=4, seed_kd=0.3):
    env = hf.light.load_environment("studio", resolution=res)
    return hf.light.lighting_target(hf.brdf.lambert(seed_kd), env)


SAMPLING = {"kind": "texels", "size": 6, "validation": 300, "seed": 0}


def _entry(t, sampling=SAMPLING) -> Path:
    k = cache.key(t, SamplingOptions(**sampling).model_dump(), "NR")
    return cache.cache_dir() / f"{k}.npz"


def test_a_truncated_entry_is_resampled_and_replaced(cache_dir):
    t = _lighting()
    first = draw_samples(t, "NR", SAMPLING)
    entry = _entry(t)
    data = entry.read_bytes()
    entry.write_bytes(data[: len(data) // 3])
    logs = []
    again = draw_samples(t, "NR", SAMPLING, log=logs.append)
    assert not any("from cache" in m for m in logs)  # a miss, not BadZipFile
    np.testing.assert_array_equal(again.y, first.y)
    assert entry.read_bytes() != data[: len(data) // 3]  # replaced whole
    logs.clear()
    draw_samples(t, "NR", SAMPLING, log=logs.append)
    assert any("from cache" in m for m in logs)


def test_an_entry_of_another_config_is_never_used(cache_dir):
    t = _lighting()
    other = {**SAMPLING, "seed": 7}
    draw_samples(t, "NR", other)
    shutil.copy(_entry(t, other), _entry(t, SAMPLING))  # seed-7 samples under the seed-0 key
    logs = []
    got = draw_samples(t, "NR", SAMPLING, log=logs.append)
    fresh = draw_samples(t, "NR", {**SAMPLING, "cache": False})
    assert not any("from cache" in m for m in logs)
    np.testing.assert_array_equal(got.val_a, fresh.val_a)


@pytest.mark.parametrize("damage", ["shape", "nan", "dtype", "checksum", "missing_meta"])
def test_damaged_entries_are_misses(cache_dir, damage):
    t = _lighting()
    s = draw_samples(t, "NR", SAMPLING)
    entry = _entry(t)
    with np.load(entry) as z:
        arrays = {k: np.asarray(z[k]) for k in z.files}
    if damage == "shape":
        arrays["y"] = arrays["y"][:, :2]
    elif damage == "nan":
        arrays["val_y"][0, 0] = np.nan
    elif damage == "dtype":
        arrays["a"] = arrays["a"].astype(np.float64)
    elif damage == "checksum":
        arrays["y"] = arrays["y"] * 2
    else:
        del arrays["meta"]
    np.savez(entry, **arrays)
    k = entry.stem
    assert cache.load(k, validation=SAMPLING["validation"]) is None
    again = draw_samples(t, "NR", SAMPLING)
    np.testing.assert_array_equal(again.val_y, s.val_y)
    assert cache.load(k, validation=SAMPLING["validation"]) is not None  # replaced by a good entry


def test_cache_files_follow_the_umask(cache_dir):
    old = os.umask(0o022)
    try:
        draw_samples(_lighting(), "NR", SAMPLING)
    finally:
        os.umask(old)
    entries = list(cache_dir.glob("*.npz"))
    assert entries and all((e.stat().st_mode & 0o777) == 0o644 for e in entries)


def test_check_names_what_is_wrong():
    s = Samples(*(np.zeros((4, 3), np.float32) for _ in range(6)))
    assert cache.check(s) is None
    assert "non-finite" in cache.check(s._replace(y=np.full((4, 3), np.inf, np.float32)))
    assert "float32" in cache.check(s._replace(a=np.zeros((4, 2), np.float32)))
    assert "lengths" in cache.check(s._replace(b=np.zeros((3, 3), np.float32)))
    assert "at most" in cache.check(s, validation=2)


# --------------------------------------------------------------------------------------------------
# 2. Loading an output directory: confined paths, declared sizes, junk documents


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    d = tmp_path_factory.mktemp("saved")
    cfg = _write_cfg(d, SMALL)
    assert main([str(cfg), "--quiet"]) == 0
    return d / "out"


def _copy(saved, tmp_path) -> Path:
    d = tmp_path / "copy"
    shutil.copytree(saved, d)
    return d


def _edit(d: Path, fn) -> None:
    doc = json.loads((d / JSON_NAME).read_text())
    fn(doc)
    (d / JSON_NAME).write_text(json.dumps(doc))


@pytest.mark.parametrize("name", ["../elsewhere/x.exr", "/etc/passwd", "sub/p.exr", "..", ""])
def test_texture_paths_may_not_leave_the_directory(saved, tmp_path, name):
    d = _copy(saved, tmp_path)
    _edit(d, lambda doc: doc["textures"][0].update(file=name))
    with pytest.raises(HomofacError, match="plain file name|textures"):
        load(d)


def test_symlinks_out_of_the_directory_are_refused(saved, tmp_path):
    d = _copy(saved, tmp_path)
    foreign = tmp_path / "foreign.exr"
    shutil.copy(d / "p.exr", foreign)
    (d / "p.exr").unlink()
    (d / "p.exr").symlink_to(foreign)
    with pytest.raises(HomofacError, match="outside the output directory"):
        load(d)
    (d / "p.exr").unlink()
    (d / "p.exr").symlink_to("/etc/passwd")
    with pytest.raises(HomofacError, match="outside the output directory"):
        load(d)  # refused before the file is opened: its existence cannot be probed through homofac


def test_declared_sizes_are_checked(saved, tmp_path):
    d = _copy(saved, tmp_path)
    big = np.ones((512, 1024, 3), np.float32)
    write_exr(d / "p.exr", big)
    _edit(d, lambda doc: doc["textures"][0].pop("shape"))
    with pytest.raises(HomofacError, match="does not match"):
        load(d)
    for size in (1e12, -16, 0, "16", 5000):
        d2 = _copy(saved, tmp_path / f"s{abs(hash(str(size)))}")
        _edit(d2, lambda doc: doc["textures"][0].update(size=size))
        with pytest.raises(HomofacError):
            load(d2)


@pytest.mark.parametrize("junk", [
    "[]", "42", '"x"', "null",
    '{"format": "homofac.factorization", "kind": "brdf", "textures": [], "terms": []}',
    '{"format": "homofac.factorization", "kind": "brdf", "textures": 5}',
    '{"format": "homofac.factorization", "schema_version": 1, "kind": "brdf", "mapper": "parabolic", '
    '"texture_size": 6, "textures": [{"name": "p", "file": "p.exr"}], "factors": [{"projection": "wi", '
    '"texture": "p"}], "correction": 3}',
    '{"format": "homofac.factorization", "kind": "brdf", "textures": [{"name": "p", "file": "p.exr"}], '
    '"correction": [NaN, 1, 1]}',
    "[" * 100000 + "]" * 100000,
    '{"a": ' * 5000 + "1" + "}" * 5000,
])
def test_junk_documents_are_one_line_errors(saved, tmp_path, junk):
    d = _copy(saved, tmp_path)
    (d / JSON_NAME).write_text(junk)
    with pytest.raises(HomofacError) as e:
        load(d)
    assert "\n" not in str(e.value)


# --------------------------------------------------------------------------------------------------
# 2b. Names become code, numbers become infinities: refused on load (docs/format.md, "Names")

HOSTILE = "NR\n    return vec3(1e9);\n//"


def _rename_texture(doc, old, new):
    for t in doc["textures"]:
        if t["name"] == old:
            t["name"] = new
    for f in [f for term in doc.get("terms", []) for f in term["factors"]] + doc.get("factors", []):
        if f["texture"] == old:
            f["texture"] = new


@pytest.mark.parametrize("edit,needle", [
    (lambda doc: doc.update(name=HOSTILE), "name"),
    (lambda doc: doc.update(name=None, parametrization=HOSTILE), "parametrization"),
    (lambda doc: doc.update(name="x */ y"), "name"),
    (lambda doc: doc.update(name="<!--<script>"), "name"),
    (lambda doc: doc["terms"][0].update(kind=HOSTILE), "kind"),
    (lambda doc: _rename_texture(doc, "p", HOSTILE), "textures"),
    (lambda doc: _rename_texture(doc, "p", "normalize"), "reserved"),
    (lambda doc: _rename_texture(doc, "p", "proj_wi"), "reserved"),
    (lambda doc: _rename_texture(doc, "q", "sample_p"), "reserved"),
    (lambda doc: doc["terms"][0]["factors"][0].update(projection="wi */"), "projection"),
    (lambda doc: doc["terms"][0].update(correction=[1e39, 1.0, 1.0]), "float32"),
    (lambda doc: doc["terms"][0].update(png_correction=[1.0, -1e39, 1.0]), "float32"),
    (lambda doc: doc["textures"][0].update(png_decode={"offset": [0, 0, 0], "scale": [1e39, 1, 1]}), "float32"),
    (lambda doc: doc.update(correction=[3.5e38, 1.0, 1.0], schema_version=1), "float32"),
    (lambda doc: doc.update(context={"dominant": [1e39, 0.0, 0.0]}), "dominant"),
], ids=["name", "parametrization", "comment-end", "html", "kind", "texture-newline", "normalize", "proj_wi",
        "sample_p", "projection", "correction", "png_correction", "png_scale", "schema1-correction", "context"])
def test_names_and_numbers_that_would_become_code_or_infinity_are_refused(saved, tmp_path, edit, needle):
    """A name with a newline put ``return vec3(1e9);`` into every generated shader; a texture called
    ``normalize`` made a shader that does not compile; 1e39 loaded as inf. Each is one line on load."""
    d = _copy(saved, tmp_path)
    _edit(d, edit)
    with pytest.raises(HomofacError, match=needle) as e:
        load(d)
    assert "\n" not in str(e.value)


def test_a_correction_of_1e400_is_refused(saved, tmp_path):
    """1e400 is valid JSON that Python reads as inf (no NaN/Infinity constant involved)."""
    d = _copy(saved, tmp_path)
    _edit(d, lambda doc: doc["terms"][0].update(correction=[12345.5, 1.0, 1.0]))
    (d / JSON_NAME).write_text((d / JSON_NAME).read_text().replace("12345.5", "1e400"))
    with pytest.raises(HomofacError, match="float32"):
        load(d)


def test_names_homofac_writes_still_load(saved, tmp_path):
    """The rules admit what homofac writes: labels such as ``E'+NRW x2+R``, texture names such as ``T0``, ``c1``."""
    d = _copy(saved, tmp_path)
    _edit(d, lambda doc: (doc.update(name="E'+NRW x2+R+HSFT x2", parametrization="E'+NRW x2+R+HSFT x2"),
                          _rename_texture(doc, "p", "T0"), doc["terms"][0].update(kind="prefiltered")))
    r = load(d)
    assert r.model.name == "E'+NRW x2+R+HSFT x2" and r.model.textures[0].name == "T0"
    for lang in LANGUAGES:
        assert "return vec3(1e9)" not in r.shader(lang)


# --------------------------------------------------------------------------------------------------
# 3. Memory bounded before reading


MEASURE_BIG_EXR = r"""
import json, resource, sys
from homofac.app.cli import fit_main
code = fit_main([sys.argv[1], "--quiet"])
peak = 0
for line in open("/proc/self/status"):
    if line.startswith("VmHWM:"):
        peak = int(line.split()[1]) * 1024
print(json.dumps({"code": code, "peak": peak}))
"""


def _fake_big_exr(path: Path, width: int, height: int) -> None:
    """A small valid EXR whose header is patched to declare width x height pixels (the data stays tiny)."""
    write_exr(path, np.ones((8, 16, 3), np.float32))
    data = bytearray(path.read_bytes())
    i = data.find(b"dataWindow\x00box2i\x00")
    assert i > 0
    off = i + len(b"dataWindow\x00box2i\x00") + 4
    for name in (b"dataWindow\x00box2i\x00", b"displayWindow\x00box2i\x00"):
        j = data.find(name) + len(name) + 4
        data[j:j + 16] = np.asarray([0, 0, width - 1, height - 1], "<i4").tobytes()
    assert off > 0
    path.write_bytes(bytes(data))


@pytest.mark.slow
def test_a_small_file_declaring_a_huge_image_costs_no_memory(tmp_path):
    """A patched header declaring 16384 x 8192 pixels: refused or read in strips, never allocated whole."""
    _fake_big_exr(tmp_path / "env.exr", 16384, 8192)
    cfg = {**SMALL, "target": {"kind": "lighting", "brdf": {"model": "lambert", "kd": 0.5},
                               "environment": {"file": "env.exr", "resolution": 4}},
           "parametrization": "NR", "mapper": "cube"}
    p = _write_cfg(tmp_path, cfg)
    r = subprocess.run([PY, "-c", MEASURE_BIG_EXR, str(p)], capture_output=True, text=True, timeout=600, cwd=tmp_path)
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["code"] == 2, r.stderr
    assert "env.exr" in r.stderr and "Traceback" not in r.stderr
    assert out["peak"] < 1.5 * 2**30, out  # an allocation of the declared image would be 1.6 GB and more


def test_the_estimate_covers_the_environment_image(tmp_path):
    write_exr(tmp_path / "big.exr", np.ones((1024, 2048, 3), np.float32))
    cfg = cfgmod.parse({**SMALL, "target": {"kind": "lighting", "brdf": {"model": "lambert", "kd": 0.5},
                                            "environment": {"file": "big.exr", "resolution": 4}},
                        "parametrization": "NR", "mapper": "cube"})
    est = budget.estimate(cfg, tmp_path)
    assert est["environment"] >= 1024 * 2048 * 12


@pytest.mark.slow  # compile- or subprocess-heavy: with the slow set, to keep the fast suite under 5 min
def test_process_limits_lower_the_default_limit():
    code = textwrap.dedent("""
        import resource
        resource.setrlimit(resource.RLIMIT_AS, (8 << 30, resource.RLIM_INFINITY))
        from homofac.app import budget
        print(budget.default_limit(), budget.process_limit())
    """)
    r = subprocess.run([PY, "-c", code], capture_output=True, text=True, timeout=300)
    limit, process = map(int, r.stdout.split())
    assert process <= 8 << 30 and limit == process // 2


# --------------------------------------------------------------------------------------------------
# 4. Useless fits say so; strict JSON


def test_an_absurd_fit_warns_with_the_figure(tmp_path, capsys):
    cfg = {**SMALL, "target": {"kind": "brdf", "brdf": {"model": "cook_torrance", "kd": 0.0, "ks": 1.0,
                                                         "roughness": 1e-4, "f0": 1.0}}}
    p = _write_cfg(tmp_path, cfg)
    assert main([str(p), "--quiet"]) == 0
    err = capsys.readouterr().err
    text = (tmp_path / "out" / JSON_NAME).read_text()

    def refuse(c):
        raise ValueError(c)

    doc = json.loads(text, parse_constant=refuse)  # strict JSON: no NaN or Infinity
    assert any("does not approximate" in w for w in doc["warnings"])
    assert "homofac: warning:" in err and "does not approximate" in err


# --------------------------------------------------------------------------------------------------
# 5. Leftovers of killed runs; modes


KILL_AT_SWAP = r"""
import os, signal, sys
import homofac.output as out
real = out.os.replace
def replace(a, b):
    real(a, b)
    if str(b).rsplit("/", 1)[-1].startswith(".out.old-"):
        os.kill(os.getpid(), signal.SIGKILL)   # between the two renames of the final swap
out.os.replace = replace
from homofac.app.cli import fit_main
sys.exit(fit_main([sys.argv[1], "--quiet"]))
"""


@pytest.mark.slow
def test_a_kill_between_the_two_renames_is_recovered(tmp_path, capsys):
    p = _write_cfg(tmp_path, SMALL)
    assert main([str(p), "--quiet"]) == 0
    before = (tmp_path / "out" / JSON_NAME).read_bytes()
    r = subprocess.run([PY, "-c", KILL_AT_SWAP, str(p)], cwd=tmp_path, timeout=600)
    assert r.returncode == -signal.SIGKILL
    assert not (tmp_path / "out").exists() and list(tmp_path.glob(".out.old-*"))
    (tmp_path / ".out.tmp-deadbeef").mkdir()  # and a temporary directory of another killed run
    # the next run puts the stranded result back, then replaces it whole; nothing is left beside it
    with OutputLock(tmp_path / "out"):
        assert (tmp_path / "out" / JSON_NAME).read_bytes() == before
    assert main([str(p), "--quiet"]) == 0
    assert sorted(x.name for x in tmp_path.iterdir()) == ["c.yaml", "out"]


def test_output_modes_follow_the_umask(tmp_path):
    old = os.umask(0o022)
    try:
        p = _write_cfg(tmp_path, SMALL)
        assert main([str(p), "--quiet"]) == 0
    finally:
        os.umask(old)
    out = tmp_path / "out"
    assert (out.stat().st_mode & 0o777) == 0o755
    assert all((f.stat().st_mode & 0o777) == 0o644 for f in out.iterdir())


# --------------------------------------------------------------------------------------------------
# 6. Refusals as promised: one line, exit 2, nothing written


@pytest.mark.parametrize("text,needle", [
    ("a:\n" + "".join("  " * (i + 1) + f"k{i}:\n" for i in range(60)) + "  " * 61 + "x: 1\n", "nested"),
    ("[" * 20000 + "]" * 20000, "nested"),
    (b"target: {kind: brdf}\nparametrization: \xff\xfe\n", "UTF-8"),
    ("target: {kind: brdf, kind: lighting}\n", "duplicate key"),
])
def test_hostile_yaml_is_one_line(tmp_path, capsys, text, needle):
    p = tmp_path / "c.yaml"
    p.write_bytes(text if isinstance(text, bytes) else text.encode())
    assert needle in _one_line(capsys, main([str(p)]))


@pytest.mark.parametrize("path,value,needle", [
    ("limits.memory_gb", float("inf"), "limits.memory_gb"),
    ("sampling.seed", -5, "sampling.seed"),
    ("texture_size", 1.5, "texture_size"),
])
def test_bad_values_are_one_line(tmp_path, capsys, path, value, needle):
    cfg = json.loads(json.dumps(SMALL))
    node = cfg
    *head, last = path.split(".")
    for k in head:
        node = node.setdefault(k, {})
    node[last] = value
    p = tmp_path / "c.yaml"
    p.write_text(yaml.safe_dump(cfg))
    assert needle in _one_line(capsys, main([str(p)]))
    assert not (tmp_path / "out").exists()


def test_an_unwritable_output_is_refused_before_any_work(tmp_path, capsys):
    p = _write_cfg(tmp_path, SMALL)
    line = _one_line(capsys, main([str(p), "--out", "/proc/homofac-test/out"]))
    assert "/proc/homofac-test" in line


@pytest.mark.slow
def test_a_file_size_limit_is_one_line_and_keeps_the_previous_result(tmp_path):
    """``ulimit -f``: the write fails (SIGXFSZ ignored), one line naming the output, old result intact."""
    cfg = {**SMALL, "output": {**SMALL["output"], "samples": True}}
    p = _write_cfg(tmp_path, cfg)
    assert main([str(p), "--quiet"]) == 0
    before = {f.name: f.read_bytes() for f in (tmp_path / "out").iterdir()}
    code = textwrap.dedent(f"""
        import resource, sys
        resource.setrlimit(resource.RLIMIT_FSIZE, (20000, 20000))
        from homofac.app.cli import fit_main
        sys.exit(fit_main([{str(p)!r}, "--quiet"]))
    """)
    r = subprocess.run([PY, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "cannot write" in lines[0], r.stderr
    assert {f.name: f.read_bytes() for f in (tmp_path / "out").iterdir()} == before
    assert sorted(x.name for x in tmp_path.iterdir()) == ["c.yaml", "out"]


# --------------------------------------------------------------------------------------------------
# 8. Two runs, one output directory


@pytest.mark.slow  # compile- or subprocess-heavy: with the slow set, to keep the fast suite under 5 min
def test_a_second_run_on_a_locked_output_is_refused(tmp_path, capsys):
    p = _write_cfg(tmp_path, SMALL)
    code = textwrap.dedent(f"""
        import sys, time
        from homofac.output import OutputLock
        with OutputLock({str(tmp_path / 'out')!r}):
            print("locked", flush=True)
            time.sleep(60)
    """)
    holder = subprocess.Popen([PY, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        line = _one_line(capsys, main([str(p), "--quiet"]))
        assert "being written by another homofac run" in line
        assert not (tmp_path / "out").exists()
    finally:
        holder.kill()
        holder.wait()
    assert main([str(p), "--quiet"]) == 0  # the lock of a dead run does not block the next one


# --------------------------------------------------------------------------------------------------
# Fuzz: random structures and values give HomofacError, never another exception


def _json_values(depth=3):
    leaf = st.one_of(st.none(), st.booleans(), st.integers(-10**12, 10**12),
                     st.floats(allow_nan=False, allow_infinity=False), st.text(max_size=12))
    return st.recursive(leaf, lambda kids: st.one_of(st.lists(kids, max_size=4),
                                                     st.dictionaries(st.text(max_size=10), kids, max_size=4)),
                        max_leaves=20)


KEYS = list(cfgmod.Config.model_fields)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.dictionaries(st.sampled_from(KEYS + ["x", "targt"]), _json_values(), max_size=6))
def test_fuzz_the_config_loader(data):
    try:
        cfgmod.parse(data, "fuzz.yaml")
    except HomofacError as e:
        assert "\n" not in str(e)


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(mutation=st.dictionaries(
    st.sampled_from(["textures", "terms", "factors", "correction", "kind", "schema_version", "mapper", "texture_size",
                     "context", "target", "png_decode", "format", "metrics"]), _json_values(), max_size=4))
def test_fuzz_factorization_json_loading(saved, tmp_path_factory, mutation):
    d = tmp_path_factory.mktemp("fuzz")
    for f in saved.iterdir():
        shutil.copy(f, d / f.name)
    doc = json.loads((saved / JSON_NAME).read_text())
    doc.update(mutation)
    (d / JSON_NAME).write_text(json.dumps(doc))
    try:
        load(d)
    except HomofacError as e:
        assert "\n" not in str(e)


#: Substrings that would break out of a comment, a line or an HTML script if a document's string reached them.
BREAKOUTS = st.sampled_from([HOSTILE, "*/", "/*", "\n", "\r", "\\", "\u2028", "\x85", "</script>", "<!--<script>",
                             "normalize", "proj_n", "sample_p", "alpha_p", "p_sampler", "hf_p", "return", "__", "é"])
NAME_FIELDS = ["name", "parametrization", "kind", "texture", "projection"]


def _set_string(doc: dict, field: str, value: str) -> None:
    if field in ("name", "parametrization"):
        doc[field] = value
    elif field == "kind":
        doc["terms"][0]["kind"] = value
    elif field == "texture":
        _rename_texture(doc, "p", value)
    else:
        doc["terms"][0]["factors"][0]["projection"] = value
        doc["factors"][0]["projection"] = value


_BASE_SHADERS: dict = {}


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(field=st.sampled_from(NAME_FIELDS),
       value=st.one_of(st.text(max_size=20), BREAKOUTS,
                       st.lists(st.one_of(st.text(max_size=4), BREAKOUTS), max_size=4).map("".join)))
def test_fuzz_factorization_json_strings(saved, tmp_path_factory, field, value):
    """Random unicode names, kinds, parametrizations, texture and projection names: either a one-line
    HomofacError on load, or shaders in every language that are printable ASCII lines with no comment
    delimiter or line continuation, as many lines and ``return`` statements as the unmodified document's."""
    d = tmp_path_factory.mktemp("fuzzs")
    for f in saved.iterdir():
        shutil.copy(f, d / f.name)
    doc = json.loads((saved / JSON_NAME).read_text())
    _set_string(doc, field, value)
    (d / JSON_NAME).write_text(json.dumps(doc))
    try:
        r = load(d)
    except HomofacError as e:
        assert "\n" not in str(e)
        return
    if not _BASE_SHADERS:
        base = load(saved)
        _BASE_SHADERS.update({lang: base.shader(lang) for lang in LANGUAGES})
    same_structure = field != "projection" or value == "wi"
    for lang in LANGUAGES:
        src = r.shader(lang)
        assert all(" " <= c <= "~" for c in src.replace("\n", "")), (lang, value)
        assert "*/" not in src and "/*" not in src and "\\" not in src, (lang, value)
        assert not any(h in src for h in (HOSTILE, "return vec3(1e9)", "</script>", "<!--", "\u2028")), (lang, value)
        if same_structure:
            base = _BASE_SHADERS[lang]
            returns = [len(re.findall(r"\breturn\b", re.sub(r"//.*", "", t))) for t in (src, base)]  # code, not comments
            assert src.count("\n") == base.count("\n") and returns[0] == returns[1], (lang, value)
