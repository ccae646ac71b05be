"""The README is what a newcomer reads in five minutes: short, every link and picture there, its preset table
generated from the committed benchmark results, its stress table naming tests that exist, its make targets
real, and its Python code running as written (every ```python block, in order, in one namespace, in a
temporary directory so its output lands there)."""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import pytest

from helpers import small_fits

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")

#: About 150 lines (issue 41): a page, not a manual; the generated preset table is a few lines of it.
MAX_LINES = 160


def text() -> str:
    return README.read_text()


def blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", text(), re.S)


def section(title: str) -> str:
    """The README's ``## title`` section, up to the next ``##``."""
    m = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", text(), re.M | re.S)
    assert m, f"README has no section {title!r}"
    return m.group(1)


def _pages():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        spec = importlib.util.spec_from_file_location("homofac_bench_pages", ROOT / "benchmarks" / "pages.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))


def test_readme_is_short_and_has_the_newcomer_sections():
    lines = text().splitlines()
    assert len(lines) <= MAX_LINES, f"README.md has {len(lines)} lines (at most {MAX_LINES})"
    titles = re.findall(r"^## (.+)$", text(), re.M)
    for title in ("Install and run", "In Python", "Choose a preset", "Command line", "Stress and bad input",
                  "Documentation"):
        assert title in titles, titles
    assert len(section("Command line").split("```sh\n", 1)[1].split("```", 1)[0].strip().splitlines()) <= 5


def test_every_relative_link_and_image_exists():
    missing = []
    for target in LINK.findall(text()):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue
        if not (ROOT / target.split("#", 1)[0]).exists():
            missing.append(target)
    assert not missing, missing
    images = [t for t in re.findall(r"!\[[^\]]*\]\(([^)\s]+)\)", text()) if not t.startswith("http")]
    assert images, "the README shows a picture"
    for image in images:
        assert (ROOT / image).stat().st_size < 400_000, f"{image}: keep the README's picture small"


def test_make_targets_named_in_the_readme_exist():
    makefile = (ROOT / "Makefile").read_text()
    targets = set(re.findall(r"^([a-z][a-z-]*):", makefile, re.M))
    named = set(re.findall(r"^make ([a-z-]+)", section("Install and run"), re.M))
    assert {"run", "test", "docs"} <= named
    assert named <= targets, named - targets


def test_the_preset_table_is_generated_from_the_committed_results():
    pages = _pages()
    table = pages.preset_table(pages.load_rows(ROOT / "benchmarks" / "accuracy.json"),
                               pages.load_rows(ROOT / "benchmarks" / "presets.json"))
    block = text().split(pages.START, 1)[1].split(pages.END, 1)[0].strip()
    assert block == table.strip(), "run python benchmarks/pages.py"
    for name, lookups in pages.PRESETS.items():
        assert re.search(rf"^\| `{name}` \| {lookups} \| [^|]+ \| [0-9.]+(-[0-9.]+)?x", block, re.M), name


def test_the_preset_table_prefers_the_preset_benchmark():
    """Rows of benchmarks/presets.json replace the accuracy benchmark's budgets where they hold the figure."""
    pages = _pages()
    acc = [{"method": "split_sum", "material": "m", "environment": "e", "nrmse": 0.4, "fit_s": 2.0},
           {"method": "max_lookups 8", "material": "m", "environment": "e", "nrmse": 0.2, "fit_s": 100.0}]
    before = pages.preset_table(acc, [])
    assert "| `balanced` | 8 | 100 s | 0.50x (1 case) |" in before
    assert "`benchmarks/presets.json` is not there yet" in before
    after = pages.preset_table(acc, [{"preset": "balanced", "fit_s": 12.0},
                                     {"method": "preset balanced", "material": "m", "environment": "e",
                                      "nrmse": 0.1, "fit_s": 18.0}])
    assert "| `balanced` | 8 | 12-18 s | 0.25x (1 case) |" in after
    assert "| `fast` | 4 | not measured | not measured |" in after


def test_the_stress_table_names_tests_that_exist():
    table = section("Stress and bad input")
    rows = [line for line in table.splitlines() if line.startswith("| ") and not line.startswith("| input")]
    assert len(rows) >= 10
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert len(cells) == 3 and all(cells), row
        files = re.findall(r"`((?:tests/(?:\w+/)*)?test_\w+\.py)`", cells[2])
        assert files, f"no test named: {row}"
        folder = "tests/stress"
        for f in files:
            if "/" in f:
                folder = f.rsplit("/", 1)[0]
            path = ROOT / f if "/" in f else ROOT / folder / f
            assert path.is_file(), f"{row}: {f}"


def test_readme_has_python_blocks():
    assert len(blocks()) >= 1


@pytest.mark.slow
def test_readme_python_blocks_run_as_written(tmp_path, monkeypatch):
    """Every block runs as written, in order, at small sizes: ``load_environment`` and ``factorize``
    default to a 4-texel light resolution, 8-texel textures, 20 000 / 2 000 grid / validation pairs and
    an 8-texel polish sampling (helpers.small_fits); the preset's candidates, votes and polish run as they would. The README's
    own sizes are the bundled default's, run end to end by tests/test_cli.py's default run."""
    small_fits(monkeypatch.setattr)
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    for i, src in enumerate(blocks()):
        exec(compile(src, f"README.md python block {i + 1}", "exec"), ns)
    assert (tmp_path / "out_quickstart" / "factorization.json").is_file()
    assert "homofac_radiance" in ns["glsl"]
    # the example prints both errors; the preset's is below split-sum's (the point of the table)
    assert ns["fac"].metrics["validation"]["float"]["nrmse"] < ns["ref"].metrics["validation"]["float"]["nrmse"]
