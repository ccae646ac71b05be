"""The accuracy benchmark's dense pair set and saved-fit layout (benchmarks/accuracy.py)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from homofac.fit import sampling

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
import accuracy as acc  # noqa: E402


def test_dense_pairs_have_many_normals_and_the_validation_distribution():
    g = acc.dense_pairs()
    assert g.normals.shape[0] == acc.DENSE_NORMALS and g.views.shape[1] == acc.DENSE_VIEWS
    f = g.flatten()
    nv = np.sum(f.a * f.b, axis=1)
    assert len(nv) > 0.99 * acc.DENSE_NORMALS * acc.DENSE_VIEWS and np.all(nv > 0)
    # v uniform on n's hemisphere: n.v uniform on [0, 1]
    assert abs(np.mean(nv) - 0.5) < 0.01 and abs(np.mean(nv < 0.1) - 0.1) < 0.01


def test_dense_parts_are_whole_normals():
    """An error at the pairs of one normal shows in exactly the part that holds that normal."""
    g = sampling.grouped_random(3000, 5, views=10)
    f = g.flatten()
    rng = np.random.default_rng(0)
    exact = rng.uniform(0.5, 1.5, size=(len(f.a), 3))
    per = g.mask.sum(axis=1)
    for normal in (0, g.normals.shape[0] // 2, g.normals.shape[0] - 1):
        start = int(per[:normal].sum())
        approx = exact.copy()
        approx[start:start + per[normal]] += 1.0
        e = acc.dense_errors(approx, exact, g)
        part = normal * acc.DENSE_PARTS // g.normals.shape[0]
        hit = [k for k, x in enumerate(e["nrmse_dense_parts"]) if x > 0]
        assert hit == [part], (normal, e["nrmse_dense_parts"])
        assert e["nrmse_dense"] > 0 and e["dense_normals"] == g.normals.shape[0] and e["dense_pairs"] == len(f.a)


def test_saved_fit_directories_are_distinct_per_row():
    names = {acc.fit_dir(Path("/x"), m, e, method) for m in acc.MATERIALS for e in acc.ENVIRONMENTS
             for method in acc.METHODS}
    assert len(names) == len(acc.MATERIALS) * len(acc.ENVIRONMENTS) * len(acc.METHODS)
    assert all(p.parent == Path("/x") and p.name.isascii() and " " not in p.name for p in names)
