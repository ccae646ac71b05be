"""Direction mappers (homofac.param.mappers): pinned table, round trips, masks, bilinear, neighbours, solid angles."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad

from homofac.errors import HomofacError
from homofac.param import mappers as mp

NAMES = ["parabolic", "dual_paraboloid", "cube", "octahedral", "hemispherical", "spherical"]
SIZES = [8, 32]


def random_directions(m: mp.Mapper, n: int, seed: int = 0) -> np.ndarray:
    """Uniform random directions in the mapper's domain (float64)."""
    d = np.random.default_rng(seed).normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    if not m.covers_sphere:
        d[:, 2] = np.abs(d[:, 2])
    if m.name == "spherical":  # singular at -z
        d = d[d[:, 2] > -1 + 1e-6]
    return d


def angle(a, b):
    return np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0))


# --- registry -----------------------------------------------------------------------------------------


def test_registry_and_shapes():
    assert sorted(mp.MAPPERS) == sorted(NAMES + ["line"])  # line: the 1D table of scalar factors
    assert mp.texture_shape("line", 16) == (1, 16) and mp.get("line").scalar
    faces = {"parabolic": 1, "dual_paraboloid": 2, "cube": 6, "octahedral": 1, "hemispherical": 1, "spherical": 1}
    for name, f in faces.items():
        m = mp.get(name)
        assert m.faces == f
        assert mp.texture_shape(m, 16) == (16, 16 * f)
        assert mp.texture_shape(name, 16) == (16, 16 * f)
    assert not mp.get("parabolic").covers_sphere and not mp.get("hemispherical").covers_sphere
    assert all(mp.get(n).covers_sphere for n in ["dual_paraboloid", "cube", "octahedral", "spherical"])


def test_get_unknown_names_known_mappers():
    with pytest.raises(HomofacError) as e:
        mp.get("nope")
    msg = str(e.value)
    assert "nope" in msg and "\n" not in msg
    for name in NAMES:
        assert name in msg


def test_bad_size():
    with pytest.raises(HomofacError):
        mp.texture_shape(mp.get("cube"), 1)
    with pytest.raises(HomofacError):
        mp.valid_mask(mp.get("cube"), 8.0)


# --- pinned values ------------------------------------------------------------------------------------


def uv(name, d):
    f, u, v = mp.get(name).to_face_uv(np.asarray(d, np.float64))
    return int(f), float(u), float(v)


def test_pinned_parabolic():
    assert uv("parabolic", [0, 0, 1]) == (0, 0.5, 0.5)
    assert uv("parabolic", [1, 0, 0]) == (0, 1.0, 0.5)  # equator -> disk border
    s = 1 / np.sqrt(2)
    f, u, v = uv("parabolic", [s, 0, s])  # x/(1+z) = tan(22.5 deg)
    assert u == pytest.approx((np.tan(np.pi / 8) + 1) / 2, abs=1e-12) and v == 0.5
    row, col = mp.continuous_coords("parabolic", jnp.array([0.0, 0.0, 1.0]), 8)
    assert float(row) == pytest.approx(3.5) and float(col) == pytest.approx(3.5)


def test_pinned_dual_paraboloid():
    assert uv("dual_paraboloid", [0, 0, 1]) == (0, 0.5, 0.5)
    assert uv("dual_paraboloid", [0, 0, -1]) == (1, 0.5, 0.5)
    # Face 1 is not mirrored: x > 0 gives u > 0.5 on both halves.
    s = 1 / np.sqrt(2)
    f, u, v = uv("dual_paraboloid", [s, 0, -s])
    assert f == 1 and u == pytest.approx((s / (1 + s) + 1) / 2, abs=1e-12) and v == 0.5
    row, col = mp.continuous_coords("dual_paraboloid", jnp.array([0.0, 0.0, -1.0]), 8)
    assert float(row) == pytest.approx(3.5) and float(col) == pytest.approx(8 + 3.5)  # centre of the right half


def test_pinned_cube():
    assert uv("cube", [1, 0, 0]) == (0, 0.5, 0.5)
    assert uv("cube", [-1, 0, 0]) == (1, 0.5, 0.5)
    assert uv("cube", [0, 1, 0]) == (2, 0.5, 0.5)
    assert uv("cube", [0, -1, 0]) == (3, 0.5, 0.5)
    assert uv("cube", [0, 0, 1]) == (4, 0.5, 0.5)
    assert uv("cube", [0, 0, -1]) == (5, 0.5, 0.5)
    # +Z face: sc = x, tc = -y.
    f, u, v = uv("cube", [0.3, 0.0, 1.0])
    assert f == 4 and u == pytest.approx(0.65) and v == 0.5
    f, u, v = uv("cube", [0.0, 0.3, 1.0])
    assert f == 4 and u == 0.5 and v == pytest.approx(0.35)
    # +X face: sc = -z, tc = -y; -Z face: sc = -x.
    f, u, v = uv("cube", [1.0, 0.2, 0.4])
    assert f == 0 and u == pytest.approx(0.3) and v == pytest.approx(0.4)
    f, u, v = uv("cube", [0.2, 0.0, -1.0])
    assert f == 5 and u == pytest.approx(0.4)
    # Ties in the major axis: x before y before z.
    assert uv("cube", [1, 1, 0])[0] == 0
    assert uv("cube", [0, -1, -1])[0] == 3
    assert uv("cube", [1, 1, 1])[0] == 0
    row, col = mp.continuous_coords("cube", jnp.array([0.0, 0.0, -1.0]), 8)
    assert float(row) == pytest.approx(3.5) and float(col) == pytest.approx(5 * 8 + 3.5)


def test_pinned_octahedral():
    assert uv("octahedral", [0, 0, 1]) == (0, 0.5, 0.5)
    f, u, v = uv("octahedral", [0, 0, -1])  # p = (1, 1) sign(0) = +1: the corner (1, 1)
    assert (u, v) == (1.0, 1.0)
    assert uv("octahedral", [1, 0, 0]) == (0, 1.0, 0.5)
    assert uv("octahedral", [0, -1, 0]) == (0, 0.5, 0.0)
    # Lower hemisphere fold: d = (1, 2, -1)/|.|_1 -> p = (0.25, 0.5) -> (1 - 0.5, 1 - 0.25).
    f, u, v = uv("octahedral", np.array([1.0, 2.0, -1.0]) / np.sqrt(6))
    assert u == pytest.approx((0.5 + 1) / 2) and v == pytest.approx((0.75 + 1) / 2)


def test_pinned_hemispherical_and_spherical():
    f, u, v = uv("hemispherical", np.array([0.6, -0.8, 0.0]))
    assert (u, v) == pytest.approx((0.8, 0.1))
    assert uv("spherical", [0, 0, 1]) == (0, 0.5, 0.5)
    f, u, v = uv("spherical", [1, 0, 0])  # m = 2 sqrt(2)
    assert u == pytest.approx(0.5 + 1 / (2 * np.sqrt(2))) and v == 0.5
    f, u, v = uv("spherical", [0.0, 1e-9, -1.0])  # near -z: the rim of the disk
    assert v == pytest.approx(1.0, abs=1e-6)


def test_reverse_eq46():
    m = mp.get("parabolic")
    d = m.from_face_uv(np.zeros(3, np.int32), np.array([0.5, 1.0, 0.75]), np.array([0.5, 0.5, 0.5]))
    np.testing.assert_allclose(d[0], [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(d[1], [1, 0, 0], atol=1e-15)
    x = 0.5
    np.testing.assert_allclose(d[2], np.array([x, 0, 0.5 - x * x / 2]) / np.hypot(x, 0.5 - x * x / 2))
    # Extrapolated outside the disk: below the horizon.
    assert m.from_face_uv(np.int32(0), 1.05, 0.5)[2] < 0


# --- round trips --------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("S", SIZES)
def test_round_trip_texel_centres(name, S, x64):
    m = mp.get(name)
    face, u, v = mp.texel_centers(m, S)
    assert face.shape == u.shape == v.shape == mp.texture_shape(m, S)
    valid = mp.valid_mask(m, S)
    def trip(face, u, v):
        d = m.from_face_uv(face, u, v)
        return d, m.from_face_uv(*m.to_face_uv(d))

    # The numpy path (static tables) and the jax path, both float64.
    for d, d2 in (trip(face, u, v), jax.jit(trip)(jnp.asarray(face), jnp.asarray(u), jnp.asarray(v))):
        assert d.dtype == np.float64 and d2.dtype == np.float64
        err = np.linalg.norm(np.asarray(d) - np.asarray(d2), axis=-1)
        assert err[valid].max() < 1e-5
        np.testing.assert_allclose(np.linalg.norm(np.asarray(d), axis=-1), 1.0, atol=1e-12)
    # Texel centres inside the domain come back to the same face and (u, v).
    ins = mp.inside_mask(m, S)
    f2, u2, v2 = m.to_face_uv(m.from_face_uv(face, u, v))
    assert np.array_equal(f2[ins], face[ins])
    np.testing.assert_allclose(u2[ins], u[ins], atol=1e-9)
    np.testing.assert_allclose(v2[ins], v[ins], atol=1e-9)
    # texel_directions is the float32 copy of the same reverse projection.
    td = mp.texel_directions(m, S)
    assert td.dtype == np.float32 and td.shape == mp.texture_shape(m, S) + (3,)
    np.testing.assert_allclose(td, m.from_face_uv(face, u, v), atol=1e-6)


@pytest.mark.parametrize("name", NAMES)
def test_round_trip_random_directions(name, x64):
    m = mp.get(name)
    d = random_directions(m, 20000, seed=1)
    f, u, v = jax.jit(m.to_face_uv)(jnp.asarray(d))
    assert f.dtype == jnp.int32 and u.dtype == jnp.float64
    assert np.all((np.asarray(f) >= 0) & (np.asarray(f) < m.faces))
    assert np.all(np.asarray(m.inside(f, u, v)))
    assert float(jnp.min(u)) >= 0 and float(jnp.max(u)) <= 1 and float(jnp.min(v)) >= 0 and float(jnp.max(v)) <= 1
    d2 = np.asarray(jax.jit(m.from_face_uv)(f, u, v))
    assert np.abs(d2 - d).max() < 1e-5


# --- masks --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("S", SIZES)
def test_masks(name, S):
    m = mp.get(name)
    valid, ins = mp.valid_mask(m, S), mp.inside_mask(m, S)
    assert valid.dtype == bool and valid.shape == mp.texture_shape(m, S)
    assert np.all(valid[ins])
    if name in ("cube", "octahedral"):
        assert valid.all() and ins.all()
    else:
        # The disk plus a ring: a texel with its centre outside the disk but within a texel of it is
        # valid; one whose whole 2x2 bilinear neighbourhood lies outside is not.
        face, u, v = mp.texel_centers(m, S)
        r = np.hypot(2 * u - 1, 2 * v - 1)
        assert np.array_equal(ins, r <= 1)
        assert valid[(r > 1) & (r < 1 + 1 / S)].all()
        if S >= 32:
            assert not valid[r > 1 + 2 * np.sqrt(2) * 1.5 / S].any()
            assert (valid & ~ins).any()


@pytest.mark.parametrize("S", [7, 8, 32])
def test_disk_valid_mask_exact(S):
    """Disk mappers: a texel is valid iff its (clamped) bilinear neighbourhood, the open square of
    +-1 texel around its centre, reaches into the unit disk (closed form)."""
    j = np.arange(S)
    lo = np.where(j == 0, -np.inf, (j - 0.5) / S)
    hi = np.where(j == S - 1, np.inf, (j + 1.5) / S)
    gap = np.maximum(0, np.maximum(lo - 0.5, 0.5 - hi))
    exact = np.hypot(gap[None, :], gap[:, None]) < 0.5
    for name in ["parabolic", "hemispherical", "spherical"]:
        assert np.array_equal(mp.valid_mask(name, S), exact)
    assert np.array_equal(mp.valid_mask("dual_paraboloid", S), np.tile(exact, (1, 2)))


# --- bilinear and lookup ------------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("S", SIZES)
def test_bilinear_weights(name, S):
    m = mp.get(name)
    d = jnp.asarray(random_directions(m, 100_000, seed=2), jnp.float32)
    idx, w = jax.jit(lambda d: mp.bilinear(m, d, S))(d)
    assert idx.dtype == jnp.int32 and idx.shape == d.shape[:-1] + (4,) and w.shape == idx.shape
    idx, w = np.asarray(idx), np.asarray(w)
    np.testing.assert_allclose(w.sum(-1), 1.0, atol=1e-5)
    assert w.min() >= 0
    H, W = mp.texture_shape(m, S)
    assert idx.min() >= 0 and idx.max() < H * W
    assert mp.valid_mask(m, S).reshape(-1)[idx].all()
    # The four texels share the face of the direction (clamp-to-edge per face).
    face = np.asarray(jax.jit(m.to_face_uv)(d)[0])
    assert np.all(idx % W // S == face[:, None])


@pytest.mark.parametrize("name", NAMES)
def test_lookup_reproduces_linear_texture(name, x64):
    """A texture linear in the texel coordinates comes back exactly (clamped per face): the footprint
    is plain eq. 33-34 for every in-domain direction, no renormalisation needed."""
    m = mp.get(name)
    S = 16
    H, W = mp.texture_shape(m, S)
    row, col = np.mgrid[0:H, 0:W].astype(np.float64)
    tex = jnp.asarray(np.stack([row, col % S, np.ones_like(row), 2 * row - 3 * (col % S)], axis=-1))
    d = jnp.asarray(random_directions(m, 20000, seed=3))
    run = jax.jit(lambda t, d: (mp.lookup(m, t, d), mp.continuous_coords(m, d, S), m.to_face_uv(d)))
    out, (r, c), (face, _, _) = run(tex, d)
    out, r, c, face = (np.asarray(a) for a in (out, r, c, face))
    rc, cc = np.clip(r, 0, S - 1), np.clip(c - face * S, 0, S - 1)
    np.testing.assert_allclose(out[:, 0], rc, atol=1e-9)
    np.testing.assert_allclose(out[:, 1], cc, atol=1e-9)
    np.testing.assert_allclose(out[:, 2], 1.0, atol=1e-12)
    np.testing.assert_allclose(out[:, 3], 2 * rc - 3 * cc, atol=1e-8)
    interior = (r > 0) & (r < S - 1) & (c - face * S > 0) & (c - face * S < S - 1)
    assert interior.mean() > 0.5
    np.testing.assert_allclose(out[interior, 1], c[interior] - face[interior] * S, atol=1e-9)


def test_lookup_at_texel_centres_returns_texels():
    m = mp.get("cube")
    S = 8
    tex = jnp.asarray(np.random.default_rng(0).normal(size=mp.texture_shape(m, S) + (3,)), jnp.float32)
    d = jnp.asarray(mp.texel_directions(m, S)).reshape(-1, 3)
    out = jax.jit(lambda t, d: mp.lookup(m, t, d))(tex, d)
    np.testing.assert_allclose(np.asarray(out), np.asarray(tex).reshape(-1, 3), atol=1e-4)
    # 2-D textures (no channel axis) work too; a texture of the wrong width is refused.
    assert jax.eval_shape(lambda t, d: mp.lookup(m, t, d), tex[..., 0], d).shape == (d.shape[0],)
    with pytest.raises(HomofacError):
        mp.lookup(m, tex[:, :S], d)


def test_bilinear_out_of_domain_stays_valid():
    """A direction below the horizon of the parabolic map still only reads valid texels."""
    m = mp.get("parabolic")
    S = 32
    d = jnp.asarray(random_directions(mp.get("cube"), 5000, seed=4), jnp.float32)
    idx, w = jax.jit(lambda d: mp.bilinear(m, d, S))(d)
    assert mp.valid_mask(m, S).reshape(-1)[np.asarray(idx)].all()
    np.testing.assert_allclose(np.asarray(w).sum(-1), 1.0, atol=1e-5)
    assert np.isfinite(np.asarray(w)).all()


@pytest.mark.parametrize("name", NAMES)
def test_jit_vmap_grad(name):
    m = mp.get(name)
    S = 8
    tex = jnp.asarray(np.random.default_rng(5).uniform(1, 2, size=mp.texture_shape(m, S) + (3,)), jnp.float32)
    d = jnp.asarray(random_directions(m, 64, seed=6), jnp.float32)
    look = lambda t, x: mp.lookup(m, t, x)  # noqa: E731
    foot = lambda x: mp.bilinear(m, x, S)  # noqa: E731

    @jax.jit
    def everything(t, x):  # one compilation: batched and vmapped lookups and footprints, gradient
        grad = jax.grad(lambda x: jnp.sum(look(t, x)))(x)
        return look(t, x), jax.vmap(look, in_axes=(None, 0))(t, x), foot(x), jax.vmap(foot)(x), grad

    batched, mapped, (i1, w1), (i2, w2), g = everything(tex, d)
    np.testing.assert_allclose(mapped, batched, rtol=1e-6)
    assert np.array_equal(i1, i2)
    np.testing.assert_allclose(w1, w2, rtol=1e-6)
    assert g.shape == d.shape and bool(jnp.isfinite(g).all()) and bool(jnp.any(g != 0))
    # Eager (no jit) gives the same as jit.
    np.testing.assert_allclose(mp.lookup(m, tex, d[:4]), batched[:4], rtol=1e-6)


def test_gradient_matches_finite_differences(x64):
    m = mp.get("dual_paraboloid")
    S = 8
    tex = jnp.asarray(np.random.default_rng(7).uniform(size=mp.texture_shape(m, S)))
    d0 = jnp.array([0.3, -0.2, 0.5])
    f = jax.jit(lambda d: mp.lookup(m, tex, d / jnp.linalg.norm(d, axis=-1, keepdims=True)))
    g = np.asarray(jax.jit(jax.grad(f))(d0))
    eps = 1e-6
    fd = (f(d0 + eps * jnp.eye(3)) - f(d0 - eps * jnp.eye(3))) / (2 * eps)
    np.testing.assert_allclose(g, np.asarray(fd), rtol=1e-5, atol=1e-8)
    idx, w = mp.bilinear(m, d0 / jnp.linalg.norm(d0), S)
    assert w.dtype == jnp.float64


# --- neighbours ---------------------------------------------------------------------------------------


def links(nb):
    a = np.repeat(np.arange(nb.shape[0]), 4)
    b = nb.reshape(-1)
    return {(int(x), int(y)) for x, y in zip(a[b >= 0], b[b >= 0])}


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("S", SIZES)
def test_neighbours(name, S):
    m = mp.get(name)
    nb = mp.neighbours(m, S)
    H, W = mp.texture_shape(m, S)
    assert nb.shape == (H * W, 4) and nb.dtype == np.int32
    valid = mp.valid_mask(m, S).reshape(-1)
    assert (nb[~valid] == -1).all()
    assert valid[nb[nb >= 0]].all()
    pairs = links(nb)
    assert all((b, a) in pairs for a, b in pairs)  # symmetric
    assert all(a != b for a, b in pairs)
    row, col = np.divmod(np.arange(H * W), W)
    # Within a face the usual grid: left, right, up, down.
    for k, (dr, dc) in enumerate([(0, -1), (0, 1), (-1, 0), (1, 0)]):
        r2, c2 = row + dr, col + dc
        same = valid & (r2 >= 0) & (r2 < H) & (c2 // S == col // S) & (c2 >= 0) & (c2 < W)
        same &= valid[np.clip(r2, 0, H - 1) * W + np.clip(c2, 0, W - 1)]
        assert np.array_equal(nb[same, k], (r2 * W + c2)[same])
    d = mp.texel_directions(m, S).reshape(-1, 3).astype(np.float64)
    a, b = np.array(sorted(pairs)).T
    across = col[a] // S != col[b] // S
    across |= (np.abs(row[a] - row[b]) + np.abs(col[a] - col[b])) != 1
    if name in ("cube", "octahedral"):
        assert ((nb >= 0).sum(axis=1) == 4).all()  # no seams: every texel has 4 neighbours
        inface = angle(d[a[~across]], d[b[~across]]).max()
        assert angle(d[a[across]], d[b[across]]).max() < 2 * inface
        if name == "cube":
            assert angle(d[a[across]], d[b[across]]).max() < 2 * (np.pi / 2) / S
            # each edge texel has exactly one neighbour on each adjacent face
            per = np.zeros(H * W, int)
            np.add.at(per, a[across & (col[a] // S != col[b] // S)], 1)
            corner = ((col % S == 0) | (col % S == S - 1)) & ((row == 0) | (row == S - 1))
            edge = ((col % S == 0) | (col % S == S - 1) | (row == 0) | (row == S - 1)) & ~corner
            assert (per[edge] == 1).all() and (per[corner] == 2).all() and (per[~edge & ~corner] == 0).all()
    else:
        assert not across.any()  # only within a face (half) for the other mappers


def test_cube_across_edge_examples():
    S = 8
    nb = mp.neighbours("cube", S)
    W = 6 * S
    # +Z face (4), top row: up (-v = +y) leads onto +Y (face 2), whose bottom-side row (tc = z = 1) is row S-1.
    t = 0 * W + 4 * S + 3
    up = nb[t, 2]
    r, c = divmod(int(up), W)
    assert c // S == 2 and r == S - 1 and c % S == 3
    # +X face (0), left column (sc = -z -> z = +1 side) leads onto +Z (face 4), right column (x = +1).
    t = 5 * W + 0
    left = nb[t, 0]
    r, c = divmod(int(left), W)
    assert c // S == 4 and c % S == S - 1 and r == 5


def test_octahedral_mirror_links():
    S = 8
    nb = mp.neighbours("octahedral", S)
    for r in range(S):
        assert nb[r * S + 0, 0] == (S - 1 - r) * S + 0  # left edge: mirror on the same edge
        assert nb[r * S + S - 1, 1] == (S - 1 - r) * S + S - 1  # right edge
        assert nb[0 * S + r, 2] == 0 * S + (S - 1 - r)  # top edge
        assert nb[(S - 1) * S + r, 3] == (S - 1) * S + (S - 1 - r)  # bottom edge


# --- solid angles -------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("S", SIZES)
def test_solid_angles_sum(name, S):
    m = mp.get(name)
    sa = mp.texel_solid_angles(m, S)
    assert sa.dtype == np.float64 and sa.shape == mp.texture_shape(m, S)
    total = 4 * np.pi if m.covers_sphere else 2 * np.pi
    assert sa.sum() == pytest.approx(total, rel=1e-6)
    assert sa.min() >= 0
    assert not (sa > 0)[~mp.valid_mask(m, S)].any()
    assert (sa > 0)[mp.inside_mask(m, S)].all()


def test_cube_solid_angles_closed_form():
    S = 8
    F = lambda x, y: np.arctan2(x * y, np.sqrt(1 + x * x + y * y))  # noqa: E731
    e = 2 * np.arange(S + 1) / S - 1
    x0, x1, y0, y1 = e[None, :-1], e[None, 1:], e[:-1, None], e[1:, None]
    face = F(x1, y1) - F(x0, y1) - F(x1, y0) + F(x0, y0)
    np.testing.assert_allclose(mp.texel_solid_angles("cube", S), np.tile(face, (1, 6)), rtol=1e-11)


def _disk_texel_reference(name, S, i, j):
    """Solid angle of texel (i, j) of a disk mapper as a 2-D integral over s = (2u-1, 2v-1):
    parabolic d omega = 4/(1+|s|^2)^2 ds, hemispherical ds/sqrt(1-|s|^2), sphere map 4 ds."""

    def inner(x, y0, y1):
        a = np.sqrt(max(1 - x * x, 0.0))
        lo, hi = max(y0, -a), min(y1, a)
        if hi <= lo:
            return 0.0
        if name == "hemispherical":
            return np.arcsin(min(hi / a, 1)) - np.arcsin(max(lo / a, -1))
        if name == "spherical":
            return 4 * (hi - lo)
        c = 1 + x * x
        G = lambda y: 4 * (y / (2 * c * (c + y * y)) + np.arctan(y / np.sqrt(c)) / (2 * c**1.5))  # noqa: E731
        return G(hi) - G(lo)

    x0, x1, y0, y1 = 2 * j / S - 1, 2 * (j + 1) / S - 1, 2 * i / S - 1, 2 * (i + 1) / S - 1
    kinks = [k * np.sqrt(max(0, 1 - y * y)) for y in (y0, y1) for k in (-1, 1)]
    kinks = [k for k in kinks if x0 < k < x1] or None
    return quad(lambda x: inner(x, y0, y1), max(x0, -1), min(x1, 1), points=kinks, limit=200, epsabs=1e-14)[0]


@pytest.mark.parametrize("name", ["parabolic", "hemispherical", "spherical"])
def test_disk_solid_angles_per_texel(name):
    S = 8
    ref = np.array([[_disk_texel_reference(name, S, i, j) for j in range(S)] for i in range(S)])
    sa = mp.texel_solid_angles(name, S)
    assert np.array_equal(sa > 0, ref > 0)
    np.testing.assert_allclose(sa, ref, rtol=2e-5, atol=1e-12)
    # dual_paraboloid: two parabolic halves, the lower one the same by symmetry.
    if name == "parabolic":
        np.testing.assert_allclose(mp.texel_solid_angles("dual_paraboloid", S), np.tile(sa, (1, 2)), rtol=1e-12)


def test_tables_are_cached_and_read_only():
    a = mp.valid_mask("cube", 8)
    assert a is mp.valid_mask(mp.get("cube"), 8)
    with pytest.raises(ValueError):
        a[0, 0] = False
