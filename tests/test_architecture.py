"""The structure holds: one-way layers, no function-local imports of homofac, one record per plugin.

The layer contract is import-linter's (pyproject.toml, ``[tool.importlinter]``); the AST walk below
also refuses function-local imports of homofac's own modules and import cycles between files, which
the contract alone does not see. The registry tests make a plugin that lacks a half (a mapper
without traceable shader math, a solver without options or memory class, a BRDF model without an
option model) fail.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from homofac import brdf
from homofac.fit import solvers
from homofac.fit.options import FitOptions, SamplingOptions
from homofac.options import validate
from homofac.param import mappers, projections
from homofac.param import parametrizations as pz
from homofac.shader import LANGUAGES, generate, languages

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "homofac"


def _imports(path: Path):
    """(line, target module, function-local?) of every import of a homofac module in a file."""
    tree = ast.parse(path.read_text())
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = list(rel.parts)
    package = parts[:-1] if parts[-1] != "__init__" else parts[:-1]
    if parts[-1] == "__init__":
        package = parts[:-1]
    top = {id(n) for n in tree.body}
    for n in tree.body:
        if isinstance(n, (ast.If, ast.Try)):
            top |= {id(s) for s in ast.walk(n)}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            targets = [mod] if mod.startswith("homofac") else []
        elif isinstance(node, ast.Import):
            targets = [a.name for a in node.names if a.name.startswith("homofac")]
        else:
            continue
        for t in targets:
            yield node.lineno, t, id(node) not in top


def test_layers_contract_is_kept():
    """import-linter's layers contract (pyproject.toml): lower layers never import higher ones."""
    exe = Path(sys.executable).with_name("lint-imports")
    r = subprocess.run([str(exe)], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert "KEPT" in r.stdout and "BROKEN" not in r.stdout


def test_no_function_local_imports_of_homofac():
    bad = [f"{p.relative_to(ROOT)}:{line} imports {t}" for p in PACKAGE.rglob("*.py")
           for line, t, local in _imports(p) if local]
    assert not bad, "\n".join(bad)


def test_no_import_cycles_between_files():
    mods = {}
    for p in PACKAGE.rglob("*.py"):
        parts = list(p.relative_to(PACKAGE.parent).with_suffix("").parts)
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        mods[name] = p
    edges = {}
    for name, p in mods.items():
        if p.name == "__init__.py":
            continue  # package faces re-export; they are not dependencies of their own modules
        out = set()
        for _, t, _ in _imports(p):
            while t and t not in mods:
                t = t.rsplit(".", 1)[0] if "." in t else ""
            if t and t != name and mods[t].name != "__init__.py":
                out.add(t)
        edges[name] = out
    # depth-first search for a back edge
    state, cycles = {}, []

    def visit(v, path):
        state[v] = 1
        for w in edges.get(v, ()):
            if state.get(w) == 1:
                cycles.append(path[path.index(w):] + [w])
            elif w not in state:
                visit(w, path + [w])
        state[v] = 2

    for v in edges:
        if v not in state:
            visit(v, [v])
    assert not cycles, cycles[:3]


# --------------------------------------------------------------------------------------------------
# One record per plugin: every registered plugin has every half


@pytest.mark.parametrize("name", sorted(mappers.MAPPERS))
def test_mapper_records_are_complete(name):
    m = mappers.get(name)
    assert m.doc and m.faces >= 1
    S = 4
    H, W = mappers.texture_shape(m, S)
    assert mappers.valid_mask(m, S).shape == (H, W)
    assert mappers.neighbours(m, S).shape == (H * W, 4)
    for lang in LANGUAGES:
        src, _ = generate.mapper_function(languages.get(lang), name)
        assert f"hf_map_{name}" in src


@pytest.mark.parametrize("name", sorted(projections.PROJECTIONS))
def test_projection_records_are_complete(name):
    p = projections.get(name)
    assert p.doc and p.kind in projections.KINDS
    for lang in LANGUAGES:
        src, _ = generate.projection_function(languages.get(lang), name, projections.example_context())
        assert f"hf_proj_{name}" in src


@pytest.mark.parametrize("name", sorted(pz.PARAMETRIZATIONS))
def test_parametrization_records_are_complete(name):
    p = pz.get(name)
    assert p.doc and p.J >= 1 and all(p.uses(k) for k in range(p.T))


@pytest.mark.parametrize("name", sorted(solvers.SOLVERS))
def test_solver_records_are_complete(name):
    s = solvers.get(name)
    assert s.doc and callable(s.run) and s.memory(10_000, 1_000, 8) > 0
    opts = validate(FitOptions, {"solver": {"method": name}}, "").solver
    assert isinstance(opts, s.options) and opts.method == name


@pytest.mark.parametrize("name", sorted(brdf.MODELS))
def test_brdf_records_have_option_models(name):
    spec = brdf.MODELS[name]
    model = brdf.options_model(name)
    assert spec.doc and "model" in model.model_fields
    assert set(model.model_fields) - {"model"} == set(spec.schema or spec.defaults)


@pytest.mark.parametrize("name", sorted(LANGUAGES))
def test_language_records_are_complete(name):
    lang = languages.get(name)
    assert lang.file.startswith("shader") and set(lang.types) == {"float", "int", "bool", "vec3"}


def test_the_config_takes_exactly_the_registered_names():
    """The config's allowed values derive from the registries: every registered name is accepted."""
    for name, m in mappers.MAPPERS.items():
        if m.scalar:  # the 1D line mapper holds scalar factors: never a sampling grid of directions
            with pytest.raises(Exception, match="sampling.mapper"):
                validate(SamplingOptions, {"mapper": name}, "sampling")
        else:
            assert validate(SamplingOptions, {"mapper": name}, "sampling").mapper == name
    with pytest.raises(Exception, match="mapper"):
        validate(SamplingOptions, {"mapper": "nope"}, "sampling")
