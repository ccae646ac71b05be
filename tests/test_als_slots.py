"""The ALS in term slots (:class:`homofac.fit.als.Slots`): the structures a run fits on one set of samples
share one compiled sweep program, and a fit padded into larger slots is the fit in its own."""

from __future__ import annotations

import logging

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import homofac as hf
from homofac.fit import als, sums
from homofac.fit.options import LinearOptions
from homofac.fit.structures import Structure

SUN = np.array([0.5, -0.3, 0.81]) / np.linalg.norm([0.5, -0.3, 0.81])
GRID = {"kind": "grid", "size": 8, "mapper": "dual_paraboloid", "count": 6000, "validation": 500, "cache": False}
OPTS = LinearOptions(iterations=4, tolerance=0.0)
#: Three structures of one product and one highlight term, with and without the reflection term, with
#: no, one or two extra lines.
STRUCTURES = (
    Structure("RO", 1, "fitted", True, reflection=True, highlights={"terms": 1}),
    Structure("RO", 1, "fitted", True, highlights={"terms": 1, "fresnel": True, "cosine": True}),
    Structure("RO", 1, "fitted", True, reflection=True, highlights={"terms": 1, "fresnel": True}),
)


@pytest.fixture(scope="module")
def sun():
    env = hf.light.sun_sky(SUN, sun_radiance=3.0e3, sun_angle_deg=4.0, sky=(0.3, 0.4, 0.6), resolution=8)
    target = hf.light.lighting_target(hf.brdf.ggx(kd=0.3, ks=1.0, roughness=0.3, f0=0.04), env, parametrization="RO")
    return target, hf.fit.draw_samples(target, "RO", GRID)


def _fit(sun, structure, slots=None, opts=OPTS):
    target, samples = sun
    return sums.fit_sum(target, structure, "dual_paraboloid", 8, samples, opts, slots=slots)


def _sweep_compiles(caplog) -> int:
    """Compilations of the sweep's texel normal equations (one per slot shape and block size)."""
    return sum("compilation of jit(_texel_block_normals)" in r.getMessage() for r in caplog.records)


def test_the_slots_hold_every_structure_and_place_terms_by_group():
    flags = als.Flags((True, False, False, False), (False, True, True, False), (False, False, True, True),
                      (False, False, False, True), ((False, False, False, True),))
    assert als.slots_of(flags) == als.Slots(plain=2, lined=1, high=1, extra=1)
    order, masks = als.layout(flags, als.Slots(3, 2, 2, 1))
    assert order.tolist() == [0, 1, -1, 2, -1, 3, -1]
    np.testing.assert_array_equal(masks.t, [1, 1, 0, 1, 0, 1, 0])
    np.testing.assert_array_equal(masks.c, [[0, 0, 0, 0, 0, 1, 0]])
    X = np.arange(4.0)[:, None]
    np.testing.assert_array_equal(als.unpad(als.pad(X, order), order), X)
    with pytest.raises(ValueError):
        als.layout(flags, als.Slots(1, 1, 1, 1))


def test_a_fit_padded_into_larger_slots_is_its_fit_alone(sun):
    """Empty slots are masked out and separate blocks of every system: the same textures to float rounding."""
    slots = als.Slots(plain=2, lined=2, high=2, extra=2)
    for structure in STRUCTURES[1:2]:  # the highlight term with both extra lines, in slots of two of each
        alone, padded = _fit(sun, structure), _fit(sun, structure, slots)
        assert [t.name for t in alone.model.textures] == [t.name for t in padded.model.textures]
        for a, b in zip(alone.model.textures, padded.model.textures):
            scale = float(np.max(np.abs(np.asarray(a.data)))) + 1e-6
            np.testing.assert_allclose(np.asarray(b.data), np.asarray(a.data), atol=2e-4 * scale, rtol=2e-4)
        assert padded.solver["objective"] == pytest.approx(alone.solver["objective"], rel=1e-4)


def test_the_structures_of_a_run_compile_one_sweep_program(sun, caplog):
    """Three structures (and the highlight terms' starts) in the run's slots: one compiled set of ALS sweep
    programs; in their own slots each compiles its own."""
    target, _ = sun
    slots = sums.als_slots(target, STRUCTURES, "dual_paraboloid", 8)
    assert slots == als.Slots(plain=2, extra=2)
    one = LinearOptions(iterations=1, tolerance=0.0)  # the programs compile on the first sweep
    caplog.set_level(logging.WARNING, logger="jax")
    with jax.log_compiles():
        jax.clear_caches()
        for structure in STRUCTURES:
            _fit(sun, structure, slots, one)
        shared = _sweep_compiles(caplog)
        caplog.clear()
        jax.clear_caches()
        for structure in STRUCTURES[:2]:
            _fit(sun, structure, opts=one)
        own = _sweep_compiles(caplog)
    assert shared == 1
    assert own == 2


def test_a_fit_continued_from_where_it_stopped_is_the_uninterrupted_fit(sun):
    """The race's candidates stop after a few sweeps and the leader continues (``sums.begin``, ``advance``,
    ``finish``): 2 sweeps then 3 more give the textures, objective history and record of 5 sweeps in one
    call, bit for bit; a stopped fit reads as a fit of its sweeps so far, and no fit runs past its budget."""
    target, samples = sun
    opts = LinearOptions(iterations=5, tolerance=0.0)
    structure = STRUCTURES[0]
    whole = sums.fit_sum(target, structure, "dual_paraboloid", 8, samples, opts)
    run = sums.begin(target, structure, "dual_paraboloid", 8, samples, opts)
    two = sums.advance(run, 2)
    short = sums.finish(two)
    assert two.sweeps == 2 and short.solver["iterations"] == 2
    rest = sums.advance(two, None)
    assert rest.sweeps == 5 and sums.advance(rest, 3).sweeps == 5
    cont = sums.finish(rest)
    np.testing.assert_array_equal(rest.hist[:2], two.hist)
    assert cont.solver["objective"] == whole.solver["objective"]
    assert cont.solver["iterations"] == whole.solver["iterations"] == 5
    for a, b in zip(whole.model.textures, cont.model.textures):
        np.testing.assert_array_equal(np.asarray(a.data), np.asarray(b.data))
    assert short.solver["objective"] > cont.solver["objective"]  # the two sweeps' fit is a fit of its own


def test_a_fit_in_blocks_is_the_fit_in_one_and_reuses_the_short_fits_programs(sun, caplog):
    """The sweep sums its normal equations over blocks of pairs (``block``): on every pair in blocks of a
    quarter of them it is the fit in one block to float rounding, and after a fit on every 4th pair (the
    race's short fit) it compiles none of the blocks' normal-equation programs again."""
    target, samples = sun
    structure = STRUCTURES[2]
    quarter = sums.strided(samples, 4)
    opts = LinearOptions(iterations=3, tolerance=0.0)
    caplog.set_level(logging.WARNING, logger="jax")

    def normals_compiles() -> int:
        return sum("compilation of jit(_texel_block_normals)" in r.getMessage()
                   or "compilation of jit(_line_block_normals)" in r.getMessage() for r in caplog.records)

    with jax.log_compiles():
        jax.clear_caches()
        sums.fit_sum(target, structure, "dual_paraboloid", 8, quarter, opts)
        assert normals_compiles() >= 2
        caplog.clear()
        blocked = sums.fit_sum(target, structure, "dual_paraboloid", 8, samples, opts, block=len(quarter.a))
        assert normals_compiles() == 0
    whole = sums.fit_sum(target, structure, "dual_paraboloid", 8, samples, opts)
    assert len(samples.a) > 3 * len(quarter.a)
    for a, b in zip(whole.model.textures, blocked.model.textures):
        scale = float(np.max(np.abs(np.asarray(a.data)))) + 1e-6
        np.testing.assert_allclose(np.asarray(b.data), np.asarray(a.data), atol=2e-4 * scale, rtol=2e-4)
    assert blocked.solver["objective"] == pytest.approx(whole.solver["objective"], rel=1e-4)


@pytest.mark.parametrize("per_term", [False, True])
def test_the_line_normal_equations_are_the_dense_products_of_the_lines_coefficients(per_term):
    """The line blocks' normal equations (shared footprint: sums into the line's texels, by scatter-adds for
    few term pairs and matrix products for many; per-term footprints: each line's own block so, the blocks
    between two lines by scatter-adds) equal ``A^T A``, ``A^T y`` of the dense coefficient matrix A (N, K S_w)
    whose row holds ``c_t(i) vw`` at each term's two texels, for every first slot ``lo`` and a slot without
    the line."""
    rng = np.random.default_rng(3)
    N, K, Sw = 3000, 5, 16  # at most MATMUL_TEXELS: both sums (K - lo lines > 3: matrix products)
    feet = [als.line_footprint(rng.uniform(0, 1, N).astype(np.float32), Sw) for _ in range(K if per_term else 1)]
    vi, vw = (np.stack([np.asarray(f[j]) for f in feet], 1) for j in (0, 1))  # (N, K or 1, 2)
    if not per_term:
        vi, vw = vi[:, 0], vw[:, 0]
    pq = rng.normal(size=(K, N, 3)).astype(np.float32)
    y = rng.normal(size=(N, 3)).astype(np.float32)
    use = np.array([1, 1, 0, 1, 1], np.float32)
    for lo in range(K):
        G, h = als._w_normals(jnp.asarray(pq), jnp.asarray(y), jnp.asarray(vi), jnp.asarray(vw), jnp.asarray(use),
                              lo, Sw)
        k = K - lo
        E = np.zeros((N, k, Sw))
        for t in range(k):
            ti, tw = (vi[:, lo + t], vw[:, lo + t]) if per_term else (vi, vw)
            for j in range(2):
                np.add.at(E, (np.arange(N), t, ti[:, j]), tw[:, j])
        A = ((pq[lo:] * use[lo:, None, None]).transpose(1, 0, 2)[:, :, None, :] * E[..., None]).reshape(N, k * Sw, 3)
        want_G = np.einsum("nac,nbc->abc", A, A).reshape(-1, 3)
        want_h = np.einsum("nac,nc->ac", A, y)
        np.testing.assert_allclose(np.asarray(G), want_G, atol=2e-6 * np.max(np.abs(want_G)))
        np.testing.assert_allclose(np.asarray(h), want_h, atol=2e-6 * np.max(np.abs(want_h)))
