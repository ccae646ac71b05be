"""The README's code runs as written: every ```python block, in order, in one namespace, in a temporary
directory (so its output directories land there)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(), re.S)


def test_readme_has_python_blocks():
    assert len(blocks()) >= 2


@pytest.mark.slow
def test_readme_python_blocks_run_as_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    for i, src in enumerate(blocks()):
        exec(compile(src, f"README.md python block {i + 1}", "exec"), ns)
    assert (tmp_path / "out_quickstart" / "factorization.json").is_file()
    assert "homofac_radiance" in ns["glsl"]
