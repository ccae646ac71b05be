"""The notebooks (quickstart.ipynb, time_of_day.ipynb, inverse_rendering.ipynb) are committed without outputs, match their
generators (notebooks/make_<name>.py), run top to bottom at small sizes (HOMOFAC_NOTEBOOK_QUICK=1) in a
real Jupyter kernel of this interpreter, and their results are sane."""

from __future__ import annotations

import json
import os
import re
import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"
NOTEBOOK = NOTEBOOKS / "quickstart.ipynb"
NAMES = ("quickstart", "time_of_day", "inverse_rendering")


@pytest.mark.parametrize("name", NAMES)
def test_notebook_is_committed_without_outputs_and_matches_its_generator(name):
    import importlib.util

    path = NOTEBOOKS / f"{name}.ipynb"
    nb = nbformat.read(path, as_version=4)
    assert all(not c.get("outputs") for c in nb.cells if c.cell_type == "code")
    spec = importlib.util.spec_from_file_location(f"make_{name}", NOTEBOOKS / f"make_{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert [c.source for c in mod.build().cells] == [c.source for c in nb.cells]


#: A first cell the test adds: helpers.small_fits in the kernel (see test_quickstart_notebook_executes).
SMALL_FITS = (f"import builtins, sys\nsys.path.insert(0, {str(Path(__file__).resolve().parent)!r})\n"
              "import helpers\nhelpers.small_fits(builtins.setattr)")


def execute(path: Path, monkeypatch, tmp_path, small: bool = False) -> tuple[nbformat.NotebookNode, str]:
    """Run a notebook in QUICK mode in a kernel of this interpreter; (the executed notebook, its text output).
    ``small``: first run :data:`SMALL_FITS` in the kernel (an added cell; the notebook's own cells run as written)."""
    monkeypatch.setenv("HOMOFAC_NOTEBOOK_QUICK", "1")
    monkeypatch.delenv("MPLBACKEND", raising=False)  # ipykernel then picks the inline backend (headless; emits PNGs)
    nb = nbformat.read(path, as_version=4)
    if small:
        nb.cells.insert(0, nbformat.v4.new_code_cell(SMALL_FITS))
    # A kernelspec of our own, pinned to this interpreter: an installed "python3" spec (user-level, or
    # another environment's with an absolute path) must not decide which Python runs the notebook.
    from jupyter_client.kernelspec import KernelSpecManager
    from jupyter_client.manager import KernelManager

    spec_dir = tmp_path / "kernels" / "homofac-test"
    spec_dir.mkdir(parents=True)
    (spec_dir / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "homofac test", "language": "python"}))
    km = KernelManager(kernel_name="homofac-test",
                       kernel_spec_manager=KernelSpecManager(kernel_dirs=[str(tmp_path / "kernels")]))
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    client = nbclient.NotebookClient(nb, km=km, timeout=600, resources={"metadata": {"path": str(run_dir)}})
    client.execute()
    text = "\n".join(
        o.get("text", "") if o.get("output_type") == "stream" else json.dumps(o.get("data", {}).get("text/plain", ""))
        for c in nb.cells if c.cell_type == "code" for o in c.outputs
    )
    assert not any(o.get("output_type") == "error" for c in nb.cells if c.cell_type == "code" for o in c.outputs)
    return nb, text


def images(nb) -> list:
    return [o for c in nb.cells if c.cell_type == "code" for o in c.outputs if "image/png" in o.get("data", {})]


@pytest.mark.slow
def test_quickstart_notebook_executes(monkeypatch, tmp_path):
    """Every cell runs at the notebook's QUICK sizes, and its fits with the grid and validation pair counts
    of helpers.small_fits (20 000 / 2 000; the preset's candidates, votes and polish unchanged): the
    preset's own counts run in tests/test_cli.py's default run."""
    nb, text = execute(NOTEBOOK, monkeypatch, tmp_path, small=True)
    nrmse = float(re.search(r"^validation nrmse ([0-9.]+) \(balanced", text, re.M).group(1))
    split = float(re.search(r"^split-sum validation nrmse ([0-9.]+)", text, re.M).group(1))
    assert 0 < nrmse < split < 1.0, text  # the balanced preset beats split-sum, printed beside it
    assert "reloaded == in memory: True" in text
    bnrmse = float(re.search(r"PQP validation nrmse ([0-9.]+)", text).group(1))
    assert 0 < bnrmse < 1.5
    # the textures figure and the preview are drawn (matplotlib through the inline backend)
    pictures = images(nb)
    preview = re.search(r"preview pixels: nrmse ([0-9.]+)", text)
    if os.environ.get("HOMOFAC_REQUIRE_GL") == "0":  # a machine without EGL: the notebook says so and goes on
        assert preview or "no preview:" in text
        assert len(pictures) >= 1
    else:  # like tests/test_gl.py, EGL is expected (make test installs it)
        assert preview, text
        assert 0 < float(preview.group(1)) < 1.0  # GL render against the exact lighting, same pixels
        assert len(pictures) >= 2


@pytest.mark.slow
def test_time_of_day_notebook_executes(monkeypatch, tmp_path):
    nb, text = execute(NOTEBOOKS / "time_of_day.ipynb", monkeypatch, tmp_path)
    assert re.search(r"^24 skies of 384 lights; sun elevation -\d+ \.\.\. \d+ degrees; daylight hours 16$", text, re.M), text
    full = float(re.search(r"^full fit at 12.5 h: validation nrmse ([0-9.]+), ([0-9.]+) s", text, re.M).group(2))
    m = re.search(r"^first refit \(cold\) ([0-9.]+) s; warm refit median ([0-9.]+) s", text, re.M)
    assert float(m.group(2)) < full  # a warm refit costs a fraction of a full fit
    lo, hi = map(float, re.search(r"^validation nrmse per hour ([0-9.]+) \.\.\. ([0-9.]+)$", text, re.M).groups())
    assert 0 < lo <= hi < 1.5
    checks = re.findall(r"^hour (\d+\.5): refit nrmse ([0-9.]+), full run nrmse ([0-9.]+)", text, re.M)
    assert [h for h, _, _ in checks] == ["6.5", "18.5"]
    for _, a, b in checks:  # each refit is the full run of its hour (issue 15: within 1%)
        assert abs(float(a) - float(b)) <= 0.01 * float(b)
    assert len(images(nb)) >= 1  # the error / time plot
    previews = re.findall(r"^preview (\d+\.5) h: pixel nrmse ([0-9.]+)", text, re.M)
    if os.environ.get("HOMOFAC_REQUIRE_GL") == "0":
        assert previews or "no preview:" in text
    else:
        assert len(previews) == 2 and all(0 < float(e) < 1.0 for _, e in previews), text
        assert len(images(nb)) >= 3


@pytest.mark.slow
def test_inverse_rendering_notebook_executes(monkeypatch, tmp_path):
    nb, text = execute(NOTEBOOKS / "inverse_rendering.ipynb", monkeypatch, tmp_path)
    m = re.search(r"errors: roughness ([0-9.]+), F0 \[([0-9. ]+)\]", text)
    assert m, text
    # QUICK sizes (4 x 4 x 6 lights, 8^2 textures, a 16^2 image): measured 0.006 and up to 0.02
    assert float(m.group(1)) < 0.03
    assert all(float(e) < 0.04 for e in m.group(2).split())
    assert re.search(r"gradient evaluation: [0-9.]+ s", text)
    assert images(nb)
