"""The bake's two-scale filter: near part with the fine lights, far part with the coarse ones."""

from __future__ import annotations

import numpy as np

import homofac as hf
from homofac.bake import kernels as kn
from homofac.bake.build import filtered, texel_radius
from homofac.bake.filter import prefilter, prefilter_cube, taper, two_scale
from homofac.param import mappers


def _kernels(env):
    x = np.array([0.05, 0.5, 0.95])
    k = kn.calibrate(kn.specular_kernels(0.3, x), kn.albedos(0.3, x)).reshape(6, -1)
    k = kn.smooth(k, texel_radius(env))
    return np.concatenate([k, k.sum(0, keepdims=True)])


def test_taper_is_a_partition_of_unity():
    w = taper(1024, 0.2)
    gamma = 2 * np.arcsin(kn.q_grid(1024))
    assert np.all(w[gamma <= 0.2] == 1) and np.all(w[gamma >= 0.4] == 0) and np.all(np.diff(w) <= 1e-12)


def test_two_scale_equals_the_fine_filter():
    """Near part with the fine lights + far part with lights at half their resolution reads what the fine
    lights read everywhere: I_A's kernels within 1 %, I_B's (up to 30x smaller) within 1 % of I_A's."""
    fine, coarse = hf.light.load_environment("city", 16), hf.light.load_environment("city", 8)
    kp = _kernels(fine)
    own = np.ones(len(kp) - 1, bool)
    got = filtered(kp, 8, fine, coarse, own)
    num, den = prefilter(kp, np.asarray(mappers.texel_directions("cube", 8)).reshape(-1, 3), fine)
    m = kn.mass(kp)
    exact = num[:, :-1] * (m[:-1] / den[:, :-1])[..., None]
    diff, size = np.linalg.norm(got - exact, axis=(0, 2)), np.linalg.norm(exact, axis=(0, 2))
    assert np.all(diff[:3] < 0.01 * size[:3]) and np.all(diff[3:6] < 0.01 * size[:3]), (diff, size)
    assert len(two_scale(kp, 8, fine, coarse)) == 2 and len(two_scale(kp, 8, fine, None)) == 1


def test_two_scale_reads_a_constant_environment_exactly():
    """Each part is normalized by its discrete mass, so constant radiance 1 reads every kernel's mass."""
    fine, coarse = hf.light.uniform(1.0, 16), hf.light.uniform(1.0, 8)
    kp = _kernels(fine)
    got = filtered(kp, 8, fine, coarse, np.ones(len(kp) - 1, bool))
    np.testing.assert_allclose(got[..., 0], np.broadcast_to(kn.mass(kp)[:-1], got.shape[:2]), rtol=1e-4)


def test_a_call_reads_each_table_alone():
    """The filter reads each kernel table independently of the others in the call (the tables are padded to a
    fixed count so that calls share compiled programs): a subset gives the same values, in the all-lights and
    the culled (per-block) filter, and more tables than one padding step still work."""
    env = hf.light.load_environment("city", 8)
    dirs = mappers.texel_directions("cube", 8).reshape(-1, 3)
    tables = np.random.default_rng(0).random((45, kn.TABLE_NODES))
    num, den = prefilter(tables, dirs, env)
    sub, sub_den = prefilter(tables[[3, 44]], dirs, env)
    assert num.shape == (len(dirs), 45, 3) and sub.shape == (len(dirs), 2, 3)
    assert np.allclose(sub, num[:, [3, 44]], rtol=1e-5, atol=0) and np.allclose(sub_den, den[:, [3, 44]], rtol=1e-5, atol=0)
    fine = hf.light.load_environment("city", 32)
    near, _ = prefilter_cube(tables[:5], 8, fine, 0.05, tile=2)
    one, _ = prefilter_cube(tables[2:3], 8, fine, 0.05, tile=2)
    assert near.shape == (len(dirs), 5, 3) and np.allclose(one[:, 0], near[:, 2], rtol=1e-5, atol=0)


def test_the_culled_filter_sums_every_light_inside_the_kernels_support():
    """prefilter_cube reads, per tile, only the light bins within the tile's cone (filter._groups): for kernels
    that are 0 beyond ``support`` it gives the all-lights sums, at tile sizes 4 and 8, and the bins do hold fewer
    lights than the whole map (the culled path runs)."""
    from homofac.bake.filter import _groups

    env = hf.light.load_environment("city", 32)
    size, support = 16, 0.2
    tables = np.stack([taper(kn.TABLE_NODES, support / 2), taper(kn.TABLE_NODES, support / 4)])  # 0 beyond support
    dirs = mappers.texel_directions("cube", size).reshape(-1, 3)
    full, full_den = prefilter(tables, dirs, env)
    groups, centres, radius = _groups(np.asarray(env.directions))
    assert groups.shape[1] == 16 and 0 < radius < 0.15, (groups.shape, radius)
    for tile in (4, 8):
        culled, den = prefilter_cube(tables, size, env, support, tile=tile)
        scale = np.abs(full).max()
        assert np.allclose(culled, full, rtol=1e-4, atol=1e-5 * scale), np.abs(culled - full).max() / scale
        assert np.allclose(den, full_den, rtol=1e-4, atol=1e-6)


def test_both_reads_are_the_direct_sum_of_the_interpolated_tables():
    """F_j(d) = sum_k L_k dw_k K_j(q(d.l_k)) with K_j read linearly at sqrt(q) (float64 numpy here): the binned
    read (more than filter.GATHER_TABLES tables) and the table-by-table one (fewer) both give it."""
    env = hf.light.load_environment("city", 8)
    dirs = np.asarray(mappers.texel_directions("cube", 4), np.float64).reshape(-1, 3)
    tables = np.random.default_rng(1).random((7, kn.TABLE_NODES))
    lights = np.asarray(env.directions, np.float64)
    power = np.asarray(env.radiance, np.float64) * np.asarray(env.solid_angle, np.float64)[:, None]
    g = kn.TABLE_NODES
    pos = np.sqrt(np.sqrt(np.clip((1.0 - dirs @ lights.T) * 0.5, 0.0, 1.0))) * (g - 1)
    i0 = np.minimum(np.floor(pos).astype(int), g - 2)
    f = pos - i0
    exact = np.einsum("jdl,lc->djc", (1.0 - f) * tables[:, i0] + f * tables[:, i0 + 1], power)
    for rows in ([0, 1, 2, 3, 4, 5, 6], [2, 5]):
        got, _ = prefilter(tables[rows], dirs, env)
        want = exact[:, rows]
        np.testing.assert_allclose(got, want, rtol=2e-4, atol=1e-6 * np.abs(want).max())
