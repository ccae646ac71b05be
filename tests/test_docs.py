"""The documentation site (docs/, mkdocs.yml): generated tables, links, and the build itself.

The reference tables of the docs are generated at build time from homofac's registries by
docs/hooks.py; these tests call its generators and check that every registered name appears (and no
other), that every relative link and image of the pages exists, that no file points readers to the
old design notes, and (slow) that ``mkdocs build --strict`` succeeds.
"""

from __future__ import annotations

import importlib.util
import os
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from homofac import baselines, brdf
from homofac.fit import solvers
from homofac.param import mappers, parametrizations, projections
from homofac.shader import languages

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def _load_hooks():
    spec = importlib.util.spec_from_file_location("homofac_docs_hooks", DOCS / "hooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


hooks = _load_hooks()


def _first_column(markdown: str) -> list[str]:
    """The code-span names in the first column of a generated Markdown table (header rows skipped)."""
    names = []
    for line in markdown.splitlines()[2:]:
        m = re.match(r"^\| \[?`([^`]+)`", line)
        if m:
            names.append(m.group(1))
    return names


# --------------------------------------------------------------------------------------------------
# (1) the generated tables list exactly the registered names


@pytest.mark.parametrize("generator, registry", [
    ("mappers_table", mappers.MAPPERS),
    ("projections_table", projections.PROJECTIONS),
    ("parametrizations_table", parametrizations.PARAMETRIZATIONS),
    ("solvers_table", solvers.SOLVERS),
    ("languages_table", languages.LANGUAGES),
    ("baselines_table", baselines.BASELINES),
    ("models_summary", brdf.MODELS),
])
def test_registry_tables_list_exactly_the_registered_names(generator, registry):
    names = _first_column(getattr(hooks, generator)())
    assert names == list(registry), f"{generator}: {names} != {list(registry)}"


def test_models_page_has_one_section_per_model_with_its_parameters():
    page = hooks.models_page()
    assert re.findall(r"^## `([^`]+)`", page, re.M) == list(brdf.MODELS)
    sections = re.split(r"^## ", page, flags=re.M)[1:]
    for name, section in zip(brdf.MODELS, sections):
        spec = brdf.MODELS[name]
        params = list(spec.schema or {}) + list(spec.defaults)
        for p in params:
            assert f"| `{p}` |" in section, f"model {name}: parameter {p} missing"
        assert (spec.energy_conserving or "not guaranteed") in section
        assert ("Reciprocal" in section) and (("yes" if spec.reciprocal else "no") in section)


def test_mapper_figures_cover_every_mapper():
    text = hooks.mapper_figures()
    assert re.findall(r"^### `([^`]+)`", text, re.M) == list(mappers.MAPPERS)
    for name in mappers.MAPPERS:
        assert (DOCS / "img" / f"mapper_{name}.png").is_file(), f"run python docs/make_figures.py ({name})"


def test_config_reference_lists_every_field_of_every_option_model():
    text = hooks.config_reference()
    keys = set(re.findall(r"^\| `([^`]+)` \|", text, re.M))
    for model, key in hooks.config_sections():
        for field in model.model_fields:
            full = f"{key}.{field}" if key else field
            assert full in keys, f"config reference: {full} ({model.__name__}) missing"
    for b in baselines.BASELINES.values():
        for field in b.options.model_fields:
            assert f"advanced.baseline.{field}" in keys
    for name in solvers.SOLVERS:
        assert f"| `{name}` |" in text
    documented = set(hooks.config_models())
    from homofac.app.config import Config, LimitsOptions, TargetOptions
    from homofac.fit.options import FitOptions, SamplingOptions
    from homofac.light.options import BoostOptions, EnvironmentOptions, LightOptions
    from homofac.output import OutputOptions
    for model in (Config, TargetOptions, LimitsOptions, SamplingOptions, BoostOptions, EnvironmentOptions,
                  LightOptions, OutputOptions, solvers.SolverOptions):
        assert model in documented, model.__name__
    assert issubclass(Config, FitOptions)


def test_brdf_config_keys_and_default_config():
    text = hooks.brdf_config_keys()
    assert re.findall(r"`model: ([a-z_]+)`", text) == list(brdf.MODELS)
    default = (ROOT / "src" / "homofac" / "data" / "default.yaml").read_text()
    assert default.rstrip() in hooks.default_config()


def test_cli_help_and_layers_are_generated():
    assert "usage: python -m homofac.fit" in hooks.cli_fit()
    assert "usage: python -m homofac.preview" in hooks.cli_preview()
    text = hooks.layers_table()
    for layer in hooks.layer_contract():
        for module in layer:
            assert f"`{module}`" in text


def test_api_pages_render_every_module_once():
    for page in sorted((DOCS / "api").glob("*.md")):
        markers = re.findall(r"<!-- homofac:api (\S+)((?: \S+)*) -->", page.read_text())
        assert markers, f"{page.name}: no api marker"
        for package, args in markers:
            text = hooks.api(package, *args.split())
            directives = re.findall(r"^::: (\S+)", text, re.M)
            assert directives == [package] + hooks.submodules(package)
    packages = {p.stem for p in (DOCS / "api").glob("*.md")}
    for name in ("brdf", "param", "target", "factorization", "light", "shader", "fit", "output", "gl", "app"):
        assert name in packages


def test_every_marker_names_a_generator():
    for page in sorted(DOCS.rglob("*.md")):
        for name in re.findall(r"<!--\s*homofac:([a-z_0-9]+)", page.read_text()):
            assert name in hooks.GENERATORS, f"{page.relative_to(ROOT)}: unknown generator {name}"


# --------------------------------------------------------------------------------------------------
# (2) every relative link and image of docs/*.md exists

LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
#: Generators that run homofac (a fit); their output holds no links to files.
EXPENSIVE = {"example_json", "example_two_terms", "example_files", "example_shader", "example_metric"}


def _page_text(page: Path) -> str:
    """The page with its cheap generated parts expanded (they hold links too, e.g. the mapper figures)."""
    text = page.read_text()

    def one(m):
        name, args = m.group(1), m.group(2).split()
        return "" if name in EXPENSIVE else hooks.GENERATORS[name](*args)

    return hooks.MARKER.sub(one, text)


@pytest.mark.parametrize("page", sorted(p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md")))
def test_relative_links_and_images_exist(page):
    path = DOCS / page
    missing = []
    for target in LINK.findall(_page_text(path)):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue  # external (https:, mailto:) or an anchor on the same page
        file = target.split("#", 1)[0]
        if not (path.parent / file).exists():
            missing.append(target)
    assert not missing, f"{page}: missing {missing}"


def _nav() -> list:
    import yaml

    return yaml.safe_load((ROOT / "mkdocs.yml").read_text())["nav"]


def _nav_files(node):
    if isinstance(node, str):
        yield node
    elif isinstance(node, list):
        for x in node:
            yield from _nav_files(x)
    elif isinstance(node, dict):
        for x in node.values():
            yield from _nav_files(x)


def test_nav_pages_exist():
    for f in _nav_files(_nav()):
        assert (DOCS / f).is_file(), f


def test_every_page_is_in_the_nav_and_the_notes_come_last():
    """The research log is kept but out of the user's path: docs/notes/ pages only in the nav's last section,
    "Notes", and every other page in the sections before it."""
    nav = _nav()
    files = list(_nav_files(nav))
    pages = sorted(p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md"))
    assert sorted(set(files)) == pages, set(pages) ^ set(files)
    assert list(nav[-1]) == ["Notes"], nav[-1]
    notes = list(_nav_files(nav[-1]))
    assert notes and all(f.startswith("notes/") for f in notes)
    assert not [f for f in _nav_files(nav[:-1]) if f.startswith("notes/")]


def test_user_pages_keep_to_what_a_user_sets_and_gets():
    """docs/sums.md is the user part (the structure keys and how a sum is fitted); its experiments are the notes."""
    sums = (DOCS / "sums.md").read_text()
    assert len(sums.splitlines()) <= 200
    assert "notes/sums-research.md" in sums
    research = (DOCS / "notes" / "sums-research.md").read_text()
    for heading in ("## Where the error lives: grazing angles", "### The sun's disc at grazing views"):
        assert heading in research and heading not in sums


def test_section_citations_name_the_page_that_holds_the_section():
    """Docstrings and scripts cite docs by page and section title (``docs/x.md, "Title"``): the page exists
    and has a heading that starts with the title, so a moved section is not cited at its old page."""
    cite = re.compile(r'(docs/[\w/.-]+\.md),\s+"([^"]+)"')
    bad, seen = [], 0
    for top in ("src", "benchmarks", "notebooks", "tests"):
        for path in (ROOT / top).rglob("*.py"):
            if path == Path(__file__).resolve():
                continue
            for page, title in cite.findall(re.sub(r"\n\s*#?:?\s*", " ", path.read_text())):
                seen += 1
                doc = ROOT / page
                headings = re.findall(r"^#+ (.+)$", doc.read_text(), re.M) if doc.is_file() else []
                if not any(h.startswith(title) for h in headings):
                    bad.append(f"{path.relative_to(ROOT)}: {page}, {title!r}")
    assert seen >= 10 and not bad, bad


def _bench(name: str):
    import sys

    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        spec = importlib.util.spec_from_file_location(f"homofac_bench_{name}", ROOT / "benchmarks" / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))


def test_benchmark_pages_are_generated_from_the_committed_results(tmp_path):
    """docs/benchmarks/*.md are what benchmarks/pages.py makes of the committed JSON (run it after a benchmark)."""
    report, pages = _bench("report"), _bench("pages")
    results = ROOT / "benchmarks" / "results.json"
    report.write_pages(results, tmp_path, *report.tables(results))
    pages.accuracy.write_page(pages.load_rows(ROOT / "benchmarks" / "accuracy.json"), tmp_path)
    (tmp_path / "presets.md").write_text(pages.preset_page(pages.load_rows(ROOT / "benchmarks" / "accuracy.json"),
                                                           pages.load_rows(ROOT / "benchmarks" / "presets.json")))
    (tmp_path / "threejs.md").write_text(pages.threejs_page(*pages.threejs_runs()))
    (tmp_path / "bake.md").write_text(pages.bake_page(json.loads((ROOT / "benchmarks" / "bake_accuracy.json").read_text()),
                                                      *pages.threejs_runs(), fits=pages.fit_runs()))
    made = sorted(p.name for p in tmp_path.glob("*.md"))
    assert made == sorted(p.name for p in (DOCS / "benchmarks").glob("*.md"))
    for name in made:
        assert (tmp_path / name).read_text() == (DOCS / "benchmarks" / name).read_text(), \
            f"docs/benchmarks/{name} is stale: run python benchmarks/pages.py"


# --------------------------------------------------------------------------------------------------
# (3) the docs replace the old design notes: nothing points to them

OLD_NOTES = "DESIGN" + ".md"


def test_no_file_mentions_the_old_design_notes():
    paths = [ROOT / "README.md"]
    for top in ("src", "tests", "notebooks", "docs"):
        paths += [p for p in (ROOT / top).rglob("*") if p.is_file() and "__pycache__" not in p.parts]
    bad = []
    for p in paths:
        try:
            data = p.read_bytes()
        except OSError:
            continue
        if OLD_NOTES.encode() in data:
            bad.append(str(p.relative_to(ROOT)))
    assert not bad, bad


# --------------------------------------------------------------------------------------------------
# (4) the site builds with warnings as errors

#: The build's packages (mkdocs-material, mkdocstrings[python]) by import name.
_MISSING = [m for m in ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers")
            if importlib.util.find_spec(m) is None]


@pytest.mark.slow
@pytest.mark.skipif(bool(_MISSING), reason=f"the docs tools are not installed ({', '.join(_MISSING)}): "
                                           "pip install mkdocs-material 'mkdocstrings[python]'")
def test_mkdocs_build_strict(tmp_path):
    site = tmp_path / "site"
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
                       cwd=ROOT, capture_output=True, text=True, timeout=600,
                       env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-6000:]
    for page in ("index.html", "conventions/index.html", "format/index.html", "models/index.html",
                 "config/index.html", "cli/index.html", "api/fit/index.html"):
        assert (site / page).is_file(), page
    models = (site / "models" / "index.html").read_text()
    for name in brdf.MODELS:
        assert f'id="{name}"' in models
