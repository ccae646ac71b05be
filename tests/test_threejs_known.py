"""The three.js benchmark's reuse of a saved exact lighting (tests/threejs/scene.py ``known_exact``): taken only
when the G-buffer is the same bit for bit, so a reused figure is the one the reference would compute."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent / "threejs"))
from scene import GBUFFER, known_exact  # noqa: E402  (tests/threejs is not a package)


def _gbuffer(rng: np.random.Generator, count: int = 50) -> dict:
    n = rng.normal(size=(count, 3)).astype(np.float32)
    return {"n": n, "v": n[::-1].copy(), "base": rng.uniform(size=(count, 3)).astype(np.float32),
            "metallic": rng.uniform(size=count).astype(np.float32), "roughness": rng.uniform(size=count).astype(np.float32)}


def test_a_saved_exact_lighting_is_reused_only_for_the_same_gbuffer():
    rng = np.random.default_rng(0)
    out = _gbuffer(rng)
    exact = rng.uniform(size=(50, 3))
    known = {**{k: out[k].copy() for k in GBUFFER}, "exact": exact, "reference": {"samples": 8192, "converged": True}}
    got, info = known_exact(known, out)
    np.testing.assert_array_equal(got, exact)
    assert info == {"samples": 8192, "converged": True, "reused": True}
    assert known_exact(None, out) is None
    for k in GBUFFER:  # one value of any G-buffer input moved by one float32 step: computed again
        moved = {**known, k: known[k].copy()}
        flat = moved[k].reshape(-1)
        flat[7] = np.nextafter(flat[7], np.float32(2))
        assert known_exact(moved, out) is None, k
