"""homofac.light.environment: energy-preserving resampling, orientation, synthetic skies, bad input."""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import OpenEXR
import pytest

from homofac.errors import HomofacError
from homofac.io.exr import read_exr, write_exr
from homofac.io.hdr import write_hdr
from homofac import light as E
from homofac.light.cubemap import cube_texels
from homofac.light.latlong import latlong_directions, latlong_solid_angles
from homofac.param import mappers as M



def irradiance(env, n):
    """E(n) = sum_k L_k max(n.l_k, 0) dw_k, float64."""
    d = np.asarray(env.directions, np.float64)
    p = np.asarray(env.radiance, np.float64) * np.asarray(env.solid_angle, np.float64)[:, None]
    return np.maximum(d @ np.asarray(n, np.float64), 0.0) @ p


def mean_direction(env):
    """Power-weighted mean light direction (normalised)."""
    p = E.luminance(np.asarray(env.radiance, np.float64)) * np.asarray(env.solid_angle, np.float64)
    s = p @ np.asarray(env.directions, np.float64)
    return s / np.linalg.norm(s)


def latlong_energy(img):
    h, w = img.shape[:2]
    return (np.asarray(img, np.float64) * latlong_solid_angles(h, w)[:, None, None]).sum(axis=(0, 1))


def one_line(excinfo, *needles):
    msg = str(excinfo.value)
    assert "\n" not in msg, msg
    for n in needles:
        assert n in msg, (n, msg)


def angle_deg(a, b):
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    c = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


# ------------------------------------------------------------------------------------ geometry


@pytest.mark.parametrize("r", [2, 7, 32])
def test_cube_texels_match_the_mapper(r):
    d, w = cube_texels(r)
    m = M.get("cube")
    np.testing.assert_allclose(d, M.texel_directions(m, r).reshape(-1, 3), atol=1e-6)
    np.testing.assert_allclose(w, M.texel_solid_angles(m, r).reshape(-1), rtol=1e-10)
    assert abs(w.sum() - 4 * np.pi) < 1e-12
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)


def test_numpy_and_jax_bilinear_agree():
    """The one bilinear lookup gives the same footprint for NumPy (environment resampling) and JAX."""
    rng = np.random.default_rng(0)
    d = rng.normal(size=(2000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    i1, w1 = M.bilinear("cube", d, 9)
    i2, w2 = jax.jit(lambda x: M.bilinear("cube", x, 9))(jnp.asarray(d, jnp.float32))
    assert isinstance(i1, np.ndarray)
    assert np.array_equal(i1, np.asarray(i2))
    np.testing.assert_allclose(w1, np.asarray(w2), atol=1e-5)


def test_latlong_layout_is_pinned():
    d = latlong_directions(4, 8)
    th0 = np.pi * 0.5 / 4
    np.testing.assert_allclose(d[0, 0], [np.sin(th0) * np.cos(np.pi / 8), np.sin(th0) * np.sin(np.pi / 8), np.cos(th0)])
    w = latlong_solid_angles(4, 8)
    np.testing.assert_allclose(w[0], (2 * np.pi / 8) * (1 - np.cos(np.pi / 4)))
    assert abs(w.sum() * 8 - 4 * np.pi) < 1e-12


# ------------------------------------------------------------------------------------ synthetic


def test_uniform_power_and_irradiance():
    env = E.uniform(1.0, 32)
    assert env.directions.shape == (6 * 32 * 32, 3) and env.solid_angle.shape == (6 * 32 * 32,)
    assert env.radiance.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(E.total_power(env)), 4 * np.pi, rtol=1e-5)
    for n in ([0, 0, 1], [1, 0, 0], np.array([1, -2, 3]) / np.sqrt(14)):
        np.testing.assert_allclose(irradiance(env, n), np.pi, rtol=1e-3)
    c = E.uniform([0.5, 1.0, 2.0], 8)
    np.testing.assert_allclose(np.asarray(E.total_power(c)), 4 * np.pi * np.array([0.5, 1, 2]), rtol=1e-5)


def test_gradient_sky_irradiance():
    a, b = np.array([1.0, 2.0, 0.8]), np.array([0.6, -1.5, 0.3])
    env = E.gradient_sky(a, b, 32)
    for n in ([0, 0, 1], [0, 0, -1], [1, 0, 0], np.array([0.3, 0.4, np.sqrt(0.75)])):
        n = np.asarray(n, np.float64)
        np.testing.assert_allclose(irradiance(env, n), np.pi * (a + 2.0 / 3.0 * b * n[2]), rtol=1e-3)
    np.testing.assert_allclose(np.asarray(E.total_power(env)), 4 * np.pi * a, rtol=1e-5)


def test_sun_sky_dominant_direction_points_at_the_sun():
    sun = np.array([0.4, -0.3, 0.5])
    env = E.sun_sky(sun, 2.0e4, 0.53, sky=[0.1, 0.2, 0.4], sky_gradient=0.05, resolution=32)
    # a uniform sky cancels in eq. 66; a sky gradient pulls towards +z in proportion to its power
    assert angle_deg(E.dominant_direction(E.sun_sky(sun, 2.0e4, 0.53, sky=[0.1, 0.2, 0.4])), sun) < 2.0
    assert angle_deg(E.dominant_direction(E.sun_sky(sun, 1.0e6, 0.53, sky=0.3, sky_gradient=0.1)), sun) < 2.0
    assert angle_deg(E.dominant_direction(env), sun) > 2.0  # here the gradient weighs 15 % of the sun
    # the disc power is exact
    disc = 2.0e4 * 2 * np.pi * (1 - np.cos(np.radians(0.53 / 2)))
    sky = E.gradient_sky([0.1, 0.2, 0.4], 0.05, 32)
    np.testing.assert_allclose(
        np.asarray(E.total_power(env), np.float64) - np.asarray(E.total_power(sky), np.float64), disc, rtol=1e-4
    )
    # a big sun (resolved by coverage, not splatted) also points right
    big = E.sun_sky([0, 1, 1], 100.0, 20.0, sky=0.0, resolution=16)
    assert angle_deg(E.dominant_direction(big), [0, 1, 1]) < 0.5


def test_painted_lights_power_and_direction():
    env = E.painted_lights([((1, 0, 0), 10.0, (5, 5, 5)), ((0, 0, 1), 2.0, (1, 2, 3))], 32)
    cap = lambda deg: 2 * np.pi * (1 - np.cos(np.radians(deg)))  # noqa: E731
    np.testing.assert_allclose(np.asarray(E.total_power(env)), 5 * cap(10) + np.array([1, 2, 3]) * cap(2), rtol=1e-5)
    single = E.painted_lights([((0.2, 0.9, -0.3), 15.0, 1.0)], 16)
    assert angle_deg(mean_direction(single), [0.2, 0.9, -0.3]) < 0.5
    with pytest.raises(HomofacError):
        E.painted_lights([], 8)
    with pytest.raises(HomofacError) as e:
        E.painted_lights([((1, 0, 0), 10.0)], 8)
    one_line(e, "painted_lights")


def test_dominant_direction_of_isotropic_lighting_raises():
    with pytest.raises(HomofacError) as e:
        E.dominant_direction(E.uniform(1.0, 16))
    one_line(e, "uniform", "dominant")
    g = E.gradient_sky(1.0, 0.5, 16)
    assert angle_deg(E.dominant_direction(g), [0, 0, 1]) < 1e-3


# ------------------------------------------------------------------------------------ lat-long maps


def test_bundled_maps_exist_and_are_small():
    for name in E.BUNDLED:
        p = E.bundled(name)
        assert p.exists() and p.stat().st_size < 400_000
        img = read_exr(p)
        assert img.shape == (128, 256, 3) and img.min() >= 0.0
    lic = (E.bundled("forest").parent / "LICENSE.txt").read_text()
    assert "CC0" in lic and "256x128" in lic
    with pytest.raises(HomofacError) as e:
        E.bundled("desert")
    one_line(e, "desert", "forest")


def test_bundled_map_energy_is_preserved():
    env = E.load_environment("forest", 32)
    info = env.info
    assert Path(info["source"]) == E.bundled("forest")
    assert info["kind"] == "latlong" and info["resolution"] == 32 and info["n_texels"] == 6 * 32 * 32
    before, after = np.array(info["energy_before"]), np.array(info["energy_after"])
    np.testing.assert_allclose(after, before, rtol=1e-6)
    # energy_before is the energy of the cleaned source map, computed independently here
    np.testing.assert_allclose(before, latlong_energy(np.maximum(read_exr(E.bundled("forest")), 0)), rtol=1e-9)
    np.testing.assert_allclose(np.asarray(E.total_power(env), np.float64), before, rtol=1e-6)
    # bare name with extension resolves too, and the info is JSON-friendly
    import json

    env2 = E.load_environment("forest.exr", 8)
    json.dumps(env2.info)


@pytest.mark.parametrize(("h", "r"), [(64, 8), (64, 16), (100, 7), (9, 32)])
def test_synthetic_latlong_energy_is_preserved(h, r):
    rng = np.random.default_rng(h + r)
    img = np.exp(rng.normal(0, 2, (h, 2 * h, 3))).astype(np.float32)
    env = E.from_latlong(img, r)
    before = latlong_energy(img)
    np.testing.assert_allclose(env.info["energy_before"], before, rtol=1e-12)
    np.testing.assert_allclose(env.info["energy_after"], before, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(E.total_power(env), np.float64), before, rtol=1e-6)
    assert abs(np.log(env.info["energy_scale"])).max() < 0.05  # the supersampled average is already close


def test_resampled_map_approximates_the_source():
    """A smooth map is reproduced texel by texel (not only in total)."""
    h = 128
    d = latlong_directions(h, 2 * h)
    img = (1.5 + d[..., 0] + 0.5 * d[..., 2] ** 2)[..., None] * np.array([1.0, 0.5, 0.25])
    env = E.from_latlong(img, 16)
    ld = np.asarray(env.directions, np.float64)
    exact = (1.5 + ld[:, 0] + 0.5 * ld[:, 2] ** 2)[:, None] * np.array([1.0, 0.5, 0.25])
    np.testing.assert_allclose(np.asarray(env.radiance), exact, rtol=0.02)


def test_orientation_row0_is_up_and_column0_is_plus_x():
    h = 32
    up = np.zeros((h, 2 * h, 3), np.float32)
    up[0] = 1.0
    env = E.from_latlong(up, 16)
    assert mean_direction(env)[2] > 0.99
    lit = np.asarray(env.radiance)[:, 0] > 0
    assert np.asarray(env.directions)[lit][:, 2].min() > 0.9
    east = np.zeros((h, 2 * h, 3), np.float32)
    east[h // 2 - 1 : h // 2 + 1, 0] = 1.0
    env = E.from_latlong(east, 16)
    assert angle_deg(mean_direction(env), [1, 0, 0]) < 6.0
    # phi grows towards +y: a quarter turn along the row is +y
    north = np.zeros((h, 2 * h, 3), np.float32)
    north[h // 2 - 1 : h // 2 + 1, h // 2] = 1.0
    assert angle_deg(mean_direction(E.from_latlong(north, 16)), [0, 1, 0]) < 6.0


def test_negative_and_nonfinite_pixels_are_cleaned_and_counted():
    rng = np.random.default_rng(7)
    img = rng.uniform(0.5, 1.0, (16, 32, 3)).astype(np.float32)
    img[3, 4, 1] = -0.2
    img[5, 6] = -1.0
    img[7, 8, 0] = np.nan
    img[9, 10, 2] = np.inf
    img[11, 12, 1] = -np.inf
    with pytest.warns(RuntimeWarning, match="3 non-finite"):
        env = E.from_latlong(img, 8, source="test-map")
    assert env.info["clamped_negative"] == 2
    assert env.info["nonfinite"] == 3
    clean = img.copy()
    clean[~np.isfinite(clean).all(axis=-1)] = 0
    clean = np.maximum(clean, 0)
    np.testing.assert_allclose(env.info["energy_before"], latlong_energy(clean), rtol=1e-12)
    np.testing.assert_allclose(env.info["energy_after"], latlong_energy(clean), rtol=1e-6)
    assert np.isfinite(np.asarray(env.radiance)).all() and np.asarray(env.radiance).min() >= 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert E.from_latlong(clean, 8).info["nonfinite"] == 0


def test_highlight_boost():
    img = np.full((16, 32, 3), 0.1, np.float32)
    img[2, 3] = 1.0
    img[2, 4] = 0.95
    img[2, 5] = 0.5
    plain = E.from_latlong(img, 8)
    boosted = E.from_latlong(img, 8, boost={"threshold": 0.9, "factor": 10})
    assert boosted.info["boost"] == {"threshold": 0.9, "factor": 10.0, "pixels": 2}
    expect = img.astype(np.float64).copy()
    expect[2, 3:5] *= 10
    np.testing.assert_allclose(boosted.info["energy_before"], latlong_energy(expect), rtol=1e-12)
    assert plain.info["boost"] is None
    with pytest.raises(HomofacError) as e:
        E.from_latlong(img, 8, boost={"threshold": 0.9, "gain": 3})
    one_line(e, "gain")


def test_extra_lights_are_appended():
    lights = [
        {"type": "directional", "direction": [0, 0, 2], "irradiance": [3.0, 2.0, 1.0]},
        {"type": "point", "position": [0, 4, 0], "intensity": 32.0},
        {"direction": [1, 0, 0]},
    ]
    base = E.uniform(0.5, 8)
    env = E.uniform(0.5, 8, lights=lights)
    n = 6 * 64
    assert env.directions.shape == (n + 3, 3)
    np.testing.assert_allclose(np.asarray(env.directions[n:]), [[0, 0, 1], [0, 1, 0], [1, 0, 0]], atol=1e-7)
    np.testing.assert_allclose(np.asarray(env.radiance[n:]), [[3, 2, 1], [2, 2, 2], [1, 1, 1]])
    np.testing.assert_allclose(np.asarray(env.solid_angle[n:]), 1.0)
    np.testing.assert_allclose(
        np.asarray(E.total_power(env)) - np.asarray(E.total_power(base)), [6, 5, 4], rtol=1e-5
    )
    assert [lt["type"] for lt in env.info["lights"]] == ["directional", "point", "directional"]
    # the map's energies do not include the extra lights
    assert env.info["energy_after"] == base.info["energy_after"]
    # a file plus a sun
    sun = E.load_environment("studio", 8, lights=[{"type": "directional", "direction": [0, 1, 1], "irradiance": 50}])
    assert angle_deg(E.dominant_direction(sun), [0, 1, 1]) < 5
    for bad, word in [
        ({"type": "spot", "direction": [0, 0, 1]}, "spot"),
        ({"direction": [0, 0, 0]}, "direction"),
        ({"direction": [0, 0, 1], "irradiance": -1}, "irradiance"),
        ({"direction": [0, 0, 1], "colour": 1}, "colour"),
    ]:
        with pytest.raises(HomofacError) as e:
            E.uniform(1.0, 4, lights=[bad])
        one_line(e, word)


def test_environment_is_a_differentiable_pytree():
    env = E.gradient_sky(1.0, 0.5, 8)
    n = jnp.array([[0.0, 0.0, 1.0]])

    def e_up(env):
        p = env.radiance * env.solid_angle[:, None]
        return jnp.sum(jnp.maximum(n @ env.directions.T, 0.0) @ p)

    g = jax.grad(e_up)(env)
    assert isinstance(g, E.Environment)
    expect = np.maximum(np.asarray(env.directions) @ [0, 0, 1.0], 0)[:, None] * np.asarray(env.solid_angle)[:, None]
    np.testing.assert_allclose(np.asarray(g.radiance), np.broadcast_to(expect, g.radiance.shape), rtol=1e-6)
    assert float(jax.jit(lambda e: E.total_power(e).sum())(env)) == pytest.approx(3 * 4 * np.pi, rel=1e-5)
    d = jax.jit(E.dominant_direction)(env)
    assert angle_deg(d, [0, 0, 1]) < 1e-3


def test_loading_a_full_size_map_preserves_energy(tmp_path):
    """A 1024 x 512 map (the originals' size, made from the bundled one) with negative pixels, as DWAB
    compression leaves them: clamped, counted, resampled with its energy kept."""
    small = read_exr(E.bundled("city"))
    big = np.repeat(np.repeat(small, 4, axis=0), 4, axis=1)
    big[::97, ::89] = -0.01
    p = write_exr(tmp_path / "city_1k.exr", big)
    env = E.load_environment(p, 32)
    assert env.info["source_shape"] == [512, 1024] and env.info["clamped_negative"] > 0
    np.testing.assert_allclose(env.info["energy_after"], env.info["energy_before"], rtol=1e-6)


def test_hdr_latlong_file(tmp_path):
    img = np.maximum(read_exr(E.bundled("studio")), 1e-4)
    p = write_hdr(tmp_path / "studio.hdr", img)
    env = E.load_environment(p, 8)
    assert env.info["kind"] == "latlong"
    np.testing.assert_allclose(env.info["energy_before"], latlong_energy(img), rtol=4e-3)  # RGBE precision


# ------------------------------------------------------------------------------------ cube maps


def test_cube_map_round_trip_and_layouts(tmp_path):
    env = E.load_environment("forest", 16)
    img = np.asarray(E.to_cube_image(env))
    assert img.shape == (16, 96, 3)
    rad = np.asarray(env.radiance)
    # horizontal strip with envmap=cube
    p = write_exr(tmp_path / "cube.exr", img, header={"envmap": OpenEXR.ENVMAP_CUBE})
    back = E.load_environment(p, 16)
    assert back.info["kind"] == "cube"
    np.testing.assert_array_equal(np.asarray(back.radiance), rad)
    # vertical strip
    vert = img.reshape(16, 6, 16, 3).transpose(1, 0, 2, 3).reshape(96, 16, 3)
    p = write_exr(tmp_path / "vert.exr", vert, header={"envmap": OpenEXR.ENVMAP_CUBE})
    np.testing.assert_array_equal(np.asarray(E.load_environment(p, 16).radiance), rad)
    # directory of six faces, and the same six as a list
    (tmp_path / "faces").mkdir()
    files = [write_exr(tmp_path / "faces" / f"{n}.exr", img[:, 16 * i : 16 * (i + 1)]) for i, n in enumerate(E.FACE_NAMES)]
    np.testing.assert_array_equal(np.asarray(E.load_environment(tmp_path / "faces", 16).radiance), rad)
    np.testing.assert_array_equal(np.asarray(E.load_environment(files, 16).radiance), rad)
    # the face +Z of the cube is the sky: the cube map keeps the orientation
    assert angle_deg(mean_direction(back), mean_direction(env)) < 1e-3


@pytest.mark.parametrize("r", [8, 12, 24])
def test_cube_map_resampling_preserves_energy(r):
    env = E.load_environment("interior", 16)
    img = np.asarray(E.to_cube_image(env))
    res = E.from_cube(img, r)
    before = np.asarray(env.info["energy_after"])
    np.testing.assert_allclose(res.info["energy_before"], before, rtol=1e-6)
    np.testing.assert_allclose(res.info["energy_after"], before, rtol=1e-6)
    assert res.directions.shape == (6 * r * r, 3)
    assert angle_deg(mean_direction(res), mean_direction(env)) < 3.0  # texel centres move at r = 8


def test_latlong_and_cube_agree():
    """The same sky loaded as lat-long and as a cube map gives the same lights."""
    h = 64
    d = latlong_directions(h, 2 * h)
    ll = np.stack([1 + d[..., 2], 1 + d[..., 0], np.ones(d.shape[:2])], axis=-1)
    cd, _ = cube_texels(32)
    cube = np.stack([1 + cd[:, 2], 1 + cd[:, 0], np.ones(len(cd))], axis=-1).reshape(32, 192, 3)
    a, b = E.from_latlong(ll, 8), E.from_cube(cube, 8)
    np.testing.assert_allclose(np.asarray(a.radiance), np.asarray(b.radiance), rtol=0.01, atol=2e-3)


# ------------------------------------------------------------------------------------ bad input


def test_bad_input_raises_one_line_errors(tmp_path):
    cases = []
    with pytest.raises(HomofacError) as e:
        E.load_environment(tmp_path / "missing.exr")
    cases.append((e, "missing.exr"))

    cut = tmp_path / "cut.exr"
    data = E.bundled("studio").read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(HomofacError) as e:
        E.load_environment(cut)
    cases.append((e, "cut.exr"))

    txt = tmp_path / "notes.exr"
    txt.write_text("not\nan image\n")
    with pytest.raises(HomofacError) as e:
        E.load_environment(txt)
    cases.append((e, "notes.exr"))

    other = tmp_path / "photo.png"
    other.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(40))
    with pytest.raises(HomofacError) as e:
        E.load_environment(other)
    cases.append((e, "photo.png"))

    wrong = write_exr(tmp_path / "wide.exr", np.ones((600, 1000, 3), np.float32))
    with pytest.raises(HomofacError) as e:
        E.load_environment(wrong)
    cases.append((e, "wide.exr"))
    assert "lat-long map must be 2:1 (W = 2 H), got 1000x600" in str(e.value)

    (tmp_path / "faces").mkdir()
    for i, n in enumerate(E.FACE_NAMES):
        s = 8 if n != "py" else 4
        write_exr(tmp_path / "faces" / f"{n}.exr", np.ones((s, s, 3), np.float32))
    with pytest.raises(HomofacError) as e:
        E.load_environment(tmp_path / "faces")
    cases.append((e, "faces"))
    assert "equal size" in str(e.value)

    (tmp_path / "few").mkdir()
    write_exr(tmp_path / "few" / "px.exr", np.ones((8, 8, 3), np.float32))
    with pytest.raises(HomofacError) as e:
        E.load_environment(tmp_path / "few")
    cases.append((e, "few"))

    zero = write_exr(tmp_path / "black.exr", np.zeros((8, 16, 3), np.float32))
    with pytest.raises(HomofacError) as e:
        E.load_environment(zero)
    cases.append((e, "black.exr"))
    assert "all zero" in str(e.value)

    neg = write_exr(tmp_path / "negative.exr", np.full((8, 16, 3), -1.0, np.float32))
    with pytest.raises(HomofacError) as e:
        E.load_environment(neg)
    cases.append((e, "negative.exr"))

    with pytest.raises(HomofacError) as e:
        E.load_environment("forest", 0)
    cases.append((e, "forest"))

    for excinfo, name in cases:
        one_line(excinfo, name)


def test_in_memory_bad_shapes():
    with pytest.raises(HomofacError) as e:
        E.from_latlong(np.ones((10, 30, 3)), 4)
    one_line(e, "got 30x10")
    with pytest.raises(HomofacError) as e:
        E.from_cube(np.ones((8, 40, 3)))
    one_line(e, "6:1")
    with pytest.raises(HomofacError) as e:
        E.from_cube([np.ones((4, 4, 3))] * 5)
    one_line(e, "six faces")
    with pytest.raises(HomofacError) as e:
        E.from_latlong(np.zeros((8, 16, 3)), 4)
    one_line(e, "all zero")
    # an all-black map with an extra light is fine: the light has power
    env = E.from_latlong(np.zeros((8, 16, 3)), 4, lights=[{"direction": [0, 0, 1], "irradiance": 1}])
    np.testing.assert_allclose(np.asarray(E.total_power(env)), 1.0)
