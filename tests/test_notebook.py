"""notebooks/quickstart.ipynb runs top to bottom at small sizes (HOMOFAC_NOTEBOOK_QUICK=1) in a real
Jupyter kernel of this interpreter, and its results are sane."""

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

NOTEBOOK = Path(__file__).resolve().parent.parent / "notebooks" / "quickstart.ipynb"


def test_notebook_is_committed_without_outputs_and_matches_its_generator():
    import importlib.util

    nb = nbformat.read(NOTEBOOK, as_version=4)
    assert all(not c.get("outputs") for c in nb.cells if c.cell_type == "code")
    spec = importlib.util.spec_from_file_location("make_quickstart", NOTEBOOK.with_name("make_quickstart.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert [c.source for c in mod.build().cells] == [c.source for c in nb.cells]


@pytest.mark.slow
def test_quickstart_notebook_executes(monkeypatch, tmp_path):
    monkeypatch.setenv("HOMOFAC_NOTEBOOK_QUICK", "1")
    monkeypatch.delenv("MPLBACKEND", raising=False)  # ipykernel then picks the inline backend (headless; emits PNGs)
    nb = nbformat.read(NOTEBOOK, as_version=4)
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
    client = nbclient.NotebookClient(nb, km=km, timeout=300, resources={"metadata": {"path": str(run_dir)}})
    client.execute()
    text = "\n".join(
        o.get("text", "") if o.get("output_type") == "stream" else json.dumps(o.get("data", {}).get("text/plain", ""))
        for c in nb.cells if c.cell_type == "code" for o in c.outputs
    )
    assert not any(o.get("output_type") == "error" for c in nb.cells if c.cell_type == "code" for o in c.outputs)
    nrmse = float(re.search(r"^validation nrmse ([0-9.]+)", text, re.M).group(1))
    assert 0 < nrmse < 1.0, text  # NR of gold under forest at these sizes: ~0.5 (the gold bound test pins it)
    assert "reloaded == in memory: True" in text
    bnrmse = float(re.search(r"PQP validation nrmse ([0-9.]+)", text).group(1))
    assert 0 < bnrmse < 1.5
    # the textures figure and the preview are drawn (matplotlib through the inline backend)
    images = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs if "image/png" in o.get("data", {})]
    preview = re.search(r"preview pixels: nrmse ([0-9.]+)", text)
    if os.environ.get("HOMOFAC_REQUIRE_GL") == "0":  # a machine without EGL: the notebook says so and goes on
        assert preview or "no preview:" in text
        assert len(images) >= 1
    else:  # like tests/test_gl.py, EGL is expected (make test installs it)
        assert preview, text
        assert 0 < float(preview.group(1)) < 1.0  # GL render against the exact lighting, same pixels
        assert len(images) >= 2
