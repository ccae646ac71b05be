"""The programs' XLA compiler options (homofac.compiling) and the programs a grouped evaluation compiles."""

from __future__ import annotations

import numpy as np
from jax._src import compiler

import homofac as hf
from homofac.compiling import LOOP_EMITTERS, PROGRAM_KINDS, compiler_options
from homofac.fit import sampling
from homofac.fit import samples as S


def test_every_kind_names_xla_options_and_a_caller_cannot_change_the_table():
    for kind, options in PROGRAM_KINDS.items():
        assert all(k.startswith("xla_") for k in options), kind
    assert PROGRAM_KINDS["lighting rows"] == LOOP_EMITTERS and PROGRAM_KINDS["lighting grid"] == {}
    got = compiler_options("lookup")
    got["xla_cpu_use_fusion_emitters"] = True
    assert compiler_options("lookup") == LOOP_EMITTERS


def test_a_grouped_evaluation_compiles_its_lighting_programs_and_nothing_else(monkeypatch):
    """The packing, blocks and valid-pair selection are numpy: no op-by-op program (``concatenate``,
    ``dynamic_slice``, ``gather``, ...) per shape; the values are those of the pairs one by one."""
    names = []
    backend_compile = compiler.backend_compile_and_load

    def recording(backend, module, *args, **kwargs):
        names.append(str(module.operation.attributes["sym_name"]).strip('"'))
        return backend_compile(backend, module, *args, **kwargs)

    brdf = hf.brdf.cook_torrance(kd=0.2, ks=1.0, roughness=0.3, f0=0.5)
    target = hf.light.lighting_target(brdf, hf.light.load_environment("forest", 4))
    g = sampling.grouped_grid("dual_paraboloid", 8, 1000, 0)  # rows of 16+ views: the grid's program
    monkeypatch.setattr(compiler, "backend_compile_and_load", recording)
    out = S.evaluate_grouped(target, g)
    assert isinstance(out, np.ndarray) and out.shape == (int(g.mask.sum()), 3)
    assert names and all(n.startswith("jit__eval_groups") for n in names), names
    pairs = g.flatten()
    pick = np.random.default_rng(0).choice(len(pairs.a), 200, replace=False)
    direct = np.asarray(hf.target.evaluate(target, pairs.a[pick], pairs.b[pick]))
    np.testing.assert_allclose(out[pick], direct, rtol=2e-4, atol=1e-6)
