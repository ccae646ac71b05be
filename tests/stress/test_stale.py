"""Silent or stale (issue 40, item 5): a refit never writes a config that contradicts its textures, a
killed run's lock file is reclaimed by the next run, long sum fits show progress and stop on convergence."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import homofac as hf
from homofac.errors import HomofacError
from homofac.output import JSON_NAME, OutputLock, load

ROOT = Path(__file__).resolve().parents[2]
PY = sys.executable
SCHEMA1 = ROOT / "tests" / "data" / "schema1_nr"
CONFIG = {"target": {"kind": "lighting", "brdf": {"model": "lambert"}, "environment": {"file": "forest", "resolution": 4}},
          "parametrization": "NR", "mapper": "dual_paraboloid", "texture_size": 8,
          "sampling": {"kind": "texels", "size": 4, "validation": 50, "cache": False}}


def _saved(tmp_path: Path, name: str, **edits) -> Path:
    d = tmp_path / name
    shutil.copytree(SCHEMA1, d)
    doc = json.loads((d / JSON_NAME).read_text())
    doc["config"] = {**CONFIG, **edits}
    (d / JSON_NAME).write_text(json.dumps(doc))
    return d


def test_a_refit_refuses_a_saved_model_that_contradicts_its_recorded_config(tmp_path):
    """The textures are NR on dual_paraboloid 8; a recorded config of size 16, of NRV or of a cube was
    followed by the refit, which wrote that config beside textures of another layout."""
    state = hf.fit.prepare_refit(load(_saved(tmp_path, "ok")))  # agreeing: prepared
    assert state.state.texture_size == 8
    for name, edits, needle in (("size", {"texture_size": 16}, "texture_size 8 in the textures, 16 in the config"),
                                ("param", {"parametrization": "NRV"}, "parametrization 'NR' in the textures, 'NRV'"),
                                ("mapper", {"mapper": "cube"}, "mapper 'dual_paraboloid' in the textures, 'cube'")):
        with pytest.raises(HomofacError) as e:
            hf.fit.prepare_refit(load(_saved(tmp_path, name, **edits)))
        assert "\n" not in str(e.value) and needle in str(e.value) and "contradicts" in str(e.value), str(e.value)


HOLD = textwrap.dedent("""
    import sys, time
    from homofac.output import OutputLock
    with OutputLock(sys.argv[1]):
        print("locked", flush=True)
        time.sleep(120)
""")


def test_a_killed_runs_lock_file_is_reclaimed_and_removed_by_the_next_run(tmp_path):
    out = tmp_path / "out"
    lock = tmp_path / ".out.lock"
    holder = subprocess.Popen([PY, "-c", HOLD, str(out)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(HomofacError, match="being written by another homofac run"):
            with OutputLock(out):
                pass
        holder.send_signal(signal.SIGKILL)
        holder.wait(timeout=30)
    finally:
        if holder.poll() is None:
            holder.kill()
            holder.wait()
    assert lock.exists() and lock.read_text().strip() == str(holder.pid)  # left behind by the kill
    with OutputLock(out):  # its flock died with the run: taken over
        assert lock.read_text().strip() == str(os.getpid())
    assert not lock.exists()  # and removed when done
    lock.unlink(missing_ok=True)
    os.mkfifo(lock)  # a FIFO planted as the lock file is refused, never blocks
    with pytest.raises(HomofacError, match="not a regular file"):
        with OutputLock(out):
            pass


@pytest.fixture(scope="module")
def plastic():
    from homofac.fit import sampling
    from homofac.fit.samples import Samples, evaluate_grouped

    env = hf.light.load_environment("forest", resolution=4)
    target = hf.light.lighting_target(hf.brdf.cook_torrance(kd=(0.3, 0.25, 0.2), ks=1.0, roughness=0.6, f0=0.04), env)
    g = sampling.grouped_grid("dual_paraboloid", 6, 2000, 0)
    vg = sampling.grouped_random(500, 1)
    p, v = g.flatten(), vg.flatten()
    return target, Samples(p.a, p.b, np.asarray(evaluate_grouped(target, g)), v.a, v.b,
                           np.asarray(evaluate_grouped(target, vg)))


def test_a_long_als_fit_stops_on_convergence_and_shows_progress(plastic, monkeypatch):
    """``linear.iterations: 100000`` ran every sweep silently (hours); it now stops when a sweep lowers the
    objective by less than ``linear.tolerance`` of it, logs its progress, and records what it ran."""
    from homofac.fit import sums
    from homofac.fit.options import LinearOptions
    from homofac.fit.structures import Structure

    target, s = plastic
    st = Structure("NR", 2, "fitted", True)
    lines: list[str] = []
    monkeypatch.setattr(sums, "PROGRESS_S", 0.0)  # every sweep's line (the CLI shows one every few seconds)
    fit = sums.fit_sum(target, st, "dual_paraboloid", 6, s, LinearOptions(method="als", iterations=100_000,
                                                                          tolerance=1e-3), lines.append)
    rec = fit.solver
    assert rec["converged"] is True and 2 <= rec["iterations"] < 1000, rec
    sweeps = [x for x in lines if x.startswith("ALS sweep ")]
    assert sweeps and sweeps[-1].endswith("(converged)") and f"ALS sweep {rec['iterations']} / 100000" in sweeps[-1]
    # a tolerance of 0 runs every sweep and records that it did not converge
    full = sums.fit_sum(target, st, "dual_paraboloid", 6, s, LinearOptions(method="als", iterations=4, tolerance=0))
    assert full.solver["iterations"] == 4 and full.solver["converged"] is False
