"""The same environment on finer light texels: what a converged validation lighting reads.

The pinned light sum (:mod:`.lighting`) converges as the cube face size ``r`` doubles; a vote between
fits needs validation values near that limit (:mod:`homofac.fit.validation`). :func:`at_resolution`
gives the environment of ``env`` at face size ``resolution``, by the most faithful route its
provenance (``env.info``) allows, recorded as ``info["refined"]``:

* ``source``: a file or a bundled map (``info["source"]`` an existing path) is loaded again at the new
  size, with the same highlight boost and extra lights (:func:`~homofac.light.sources.load_environment`);
* ``synthetic``: an analytic sky (:mod:`.synthetic`, :mod:`.sky`) is built again from the parameters
  its ``info`` records;
* ``texels``: anything else (an in-memory image, an edited or culled environment) has no finer source.
  Each texel is split into ``(R / r)^2`` sub-texels that keep its radiance, so the light sum converges
  over the radiance field the environment does hold (constant per texel): the BRDF's quadrature over
  each texel converges, the detail below a texel stays unknown. The power is unchanged exactly.

Culled environments (:func:`~homofac.light.lights.cull_lights`) are refined from their source without
the culling (the culled lights are part of the lighting the fit approximates) where the source can be
reloaded, else split as they are.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import jax.numpy as jnp
import numpy as np

from ..errors import HomofacError
from .clean import check_resolution
from .cubemap import cube_texels, finish
from .environment import Environment, luminance
from .lights import light_corners, light_moments, moments_of
from .sky import preetham_sky
from .sources import load_environment
from .synthetic import gradient_sky, painted_lights, sun_sky, uniform
from .tree import cube_texel, texel_resolution

#: How :func:`at_resolution` refines, in order of faithfulness (``info["refined"]``).
ROUTES = ("source", "synthetic", "texels")


def _synthetic_builders() -> dict[str, Callable[[dict, int, list], Environment]]:
    """The analytic environments rebuilt from their ``info`` at face size ``r`` (with extra ``lights``)."""
    return {
        "uniform": lambda i, r, lights: uniform(i["value"], r, lights=lights),
        "gradient_sky": lambda i, r, lights: gradient_sky(i["a"], i["b"], r, lights=lights),
        "sun_sky": lambda i, r, lights: sun_sky(i["sun_direction"], i["sun_radiance"], i["sun_angle_deg"],
                                                sky=i["sky"], sky_gradient=i["sky_gradient"], resolution=r,
                                                lights=lights),
        "painted_lights": lambda i, r, lights: painted_lights(
            [(p["direction"], p["angular_radius_deg"], p["radiance"]) for p in i["painted"]], r,
            background=i["background"], lights=lights),
        "preetham_sky": lambda i, r, lights: preetham_sky(i["sun_direction"], turbidity=i["turbidity"],
                                                          ground_albedo=i["ground_albedo"], sun=i["sun"],
                                                          night=i["night"], resolution=r, lights=lights),
    }


def route(env: Environment) -> str:
    """How :func:`at_resolution` refines ``env`` (one of :data:`ROUTES`, see the module docstring)."""
    info = env.info or {}
    src = info.get("source")
    if info.get("kind") in ("latlong", "cube") and isinstance(src, str) and Path(src).is_file():
        return "source"
    if info.get("kind") == "synthetic" and src in _synthetic_builders():
        keys = {"uniform": ("value",), "gradient_sky": ("a", "b"),
                "sun_sky": ("sun_direction", "sun_radiance", "sun_angle_deg", "sky", "sky_gradient"),
                "painted_lights": ("painted", "background"),
                "preetham_sky": ("sun_direction", "turbidity", "ground_albedo", "sun", "night")}[src]
        if all(k in info for k in keys):
            return "synthetic"
    return "texels"


def parents(r: int, big: int) -> np.ndarray:
    """The texel of face size ``r`` that holds each texel of face size ``big`` (a multiple of r): pinned
    cube layout, texel k the row-major index into the (S, 6S) texture."""
    f = big // r
    rows, cols = np.divmod(np.arange(6 * big * big), 6 * big)
    return (rows // f) * (6 * r) + cols // f


def bright_texels(env: Environment, share: float) -> np.ndarray:
    """Indices of the fewest cube texels of ``env`` whose power (luminance x solid angle) holds at least
    ``share`` of the texels' total, brightest first."""
    n = 6 * int(env.info["resolution"]) ** 2
    p = np.maximum(np.asarray(luminance(env.radiance[:n]), np.float64), 0.0) * np.asarray(env.solid_angle[:n], np.float64)
    order = np.argsort(p)[::-1]
    k = int(np.searchsorted(np.cumsum(p[order]), share * p.sum())) + 1
    return order[:min(k, n)]


def mixture(coarse: Environment, fine: Environment, texels: np.ndarray) -> Environment:
    """The lights of ``coarse`` with its cube ``texels`` replaced by the texels of ``fine`` (the same map at a
    face size that is a multiple) that lie inside them; extra directional lights once. ``info["max_visible"]``
    bounds the lights above any horizon (every fine one, half the coarse cube's plus its straddlers)."""
    r, big = int(coarse.info["resolution"]), int(fine.info["resolution"])
    n, nb = 6 * r * r, 6 * big * big
    chosen = np.zeros(n, bool)
    chosen[np.asarray(texels, np.int64)] = True
    fine_idx = np.flatnonzero(chosen[parents(r, big)])
    keep = np.flatnonzero(~chosen)
    extra = np.arange(n, coarse.num_lights)
    corners_c, moments_c = light_corners(coarse), light_moments(coarse)
    corners_f, moments_f = light_corners(fine), light_moments(fine)

    def cat(c, f):  # on the host (jnp here compiled a program per op and light count)
        c = np.asarray(c, np.float32)
        return jnp.asarray(np.concatenate([np.asarray(f, np.float32)[fine_idx], c[keep], c[extra]]))

    visible = len(fine_idx) + min(len(keep), 3 * r * r + 6 * r) + len(extra)
    info = {**coarse.info, "mixture": {"fine_resolution": big, "fine_texels": int(len(fine_idx)),
                                       "coarse_texels": int(len(keep))}, "max_visible": int(visible)}
    return Environment(cat(coarse.directions, fine.directions), cat(coarse.radiance, fine.radiance),
                       cat(coarse.solid_angle, fine.solid_angle), info, cat(corners_c, corners_f),
                       tuple(cat(c, f) for c, f in zip(moments_c, moments_f)))


def difference_blocks(coarse: Environment, refined: Environment, size: int) -> list[Environment]:
    """The lights whose sum is the lighting of ``refined`` (a :func:`mixture` of ``coarse``) minus that of
    ``coarse``: the mixture's fine texels and the coarse texels they replace with their radiance negated
    (the pinned light sum is linear in the lights; the kept texels and extra directional lights cancel). In
    blocks of at most ``size`` lights, each padded with dark lights of zero solid angle (no weight: never
    above a horizon) to ``coarse``'s light count and given ``coarse``'s ``info``, so that the compiled
    lighting program of ``coarse`` evaluates every block. That program's static bounds (its visible lights
    and horizon straddlers per normal) are ``coarse``'s: a caller checks that each block keeps within them
    (:func:`homofac.fit.levels.refined`)."""
    r = int(coarse.info["resolution"])
    f = int(refined.info["mixture"]["fine_texels"])  # the mixture's first lights (mixture)
    coarse_idx = np.unique(cube_texel(np.asarray(refined.directions[:f], np.float64), r))
    mc, sc = light_moments(coarse)
    mf, sf = light_moments(refined)

    def cat(c, m, sign=1.0):  # on the host: the fine texels, then the coarse ones they replace
        return np.concatenate([np.asarray(m, np.float32)[:f], sign * np.asarray(c, np.float32)[coarse_idx]])

    d, rad = cat(coarse.directions, refined.directions), cat(coarse.radiance, refined.radiance, -1.0)
    w, corners = cat(coarse.solid_angle, refined.solid_angle), cat(light_corners(coarse), light_corners(refined))
    m, sr = cat(mc, mf), cat(sc, sf)
    n, total = len(d), coarse.num_lights
    size = int(min(size, total))
    out = []
    for i in range(0, n, size):
        k = min(size, n - i)

        def padded(a, fill):
            pad = np.broadcast_to(np.asarray(fill, np.float32), (total - k,) + a.shape[1:])
            return jnp.asarray(np.concatenate([a[i:i + k], pad]))

        out.append(Environment(padded(d, [0.0, 0.0, 1.0]), padded(rad, 0.0), padded(w, 0.0), dict(coarse.info),
                               padded(corners, 0.0), (padded(m, 0.0), padded(sr, -1.0))))
    return out


#: Lights per block of :func:`blocks` (one compiled lighting program serves every environment).
LIGHT_BLOCK = 4096
#: The ``info`` of every block (the same static data, so the compiled program is shared).
BLOCK_INFO = {"source": "light block", "kind": "block"}


def blocks(env: Environment, size: int | None = None) -> list[Environment]:
    """``env``'s lights in blocks of ``size`` (default :data:`LIGHT_BLOCK`, or the power of 2 from 256 that
    holds fewer lights), the last padded with dark delta lights, each an Environment of the same shapes and
    ``info``. The pinned light sum is a sum over lights, so the lighting of ``env`` is the sum of its
    blocks' lighting (a clamp applies to that sum); evaluated block by block, environments of any light
    count share a few compiled programs (one per block size and texel size). Each block records the face
    size of ``env``'s smallest texels (:func:`texel_resolution`), so that only the texels that can straddle a
    horizon are clipped exactly (a block is a subset of the lights: the same bound holds)."""
    n = env.num_lights
    size = int(size or (LIGHT_BLOCK if n >= LIGHT_BLOCK else max(256, 1 << int(np.ceil(np.log2(max(n, 1)))))))
    pad = (-n) % size
    up = np.tile(np.array([[0.0, 0.0, 1.0]]), (pad, 1))
    pm, ps = moments_of(up, np.ones(pad), np.zeros((pad, 4, 3)))
    m, sr = light_moments(env)

    def cat(a, b):  # on the host (jnp here compiled a program per op and light count)
        return np.concatenate([np.asarray(a, np.float32), np.asarray(b, np.float32)])

    d, rad = cat(env.directions, up), cat(env.radiance, np.zeros((pad, 3)))
    w, corners = cat(env.solid_angle, np.ones(pad)), cat(light_corners(env), np.zeros((pad, 4, 3)))
    m, sr = cat(m, pm), cat(sr, ps)
    j = jnp.asarray
    info = {**BLOCK_INFO, "texel_resolution": texel_resolution(env)}
    return [Environment(j(d[i:i + size]), j(rad[i:i + size]), j(w[i:i + size]), dict(info), j(corners[i:i + size]),
                        (j(m[i:i + size]), j(sr[i:i + size]))) for i in range(0, n + pad, size)]



def split_texels(env: Environment, resolution: int) -> Environment:
    """``env``'s cube texels of face size r split into the texels of face size ``resolution`` (a multiple
    of r), each keeping its texel's radiance (so the power of every texel, and the total, is unchanged);
    extra directional lights are kept as they are."""
    r = int(env.info.get("resolution", 0))
    n = 6 * r * r
    big = int(resolution)
    if r <= 0 or env.num_lights < n or big % r:
        raise HomofacError(f"{env.info.get('source', 'environment')}: cannot split texels of face size {r} "
                           f"into face size {big} (a multiple of it)")
    parent = parents(r, big)
    rad = np.asarray(env.radiance, np.float64)[:n][parent]
    _, w_small = cube_texels(r)
    before = (np.asarray(env.radiance, np.float64)[:n] * w_small[:, None]).sum(axis=0)
    info = {k: v for k, v in env.info.items() if k not in ("resolution", "n_texels", "lights")}
    return finish(rad, big, info, list(env.info.get("lights", [])), before)


def at_resolution(env: Environment, resolution: int) -> Environment:
    """``env`` on cube texels of face size ``resolution`` by the route of :func:`route` (module
    docstring); ``info["refined"]`` records the route and ``info["refined_from"]`` the face size it
    started from. ``env`` itself where the size is its own."""
    r = int(env.info.get("resolution", 0))
    big = check_resolution(resolution, str(env.info.get("source", "environment")))
    if big == r:
        return env
    how = route(env)
    info = env.info
    lights = list(info.get("lights", []))
    if how == "source":
        boost = info.get("boost")
        out = load_environment(info["source"], big, lights=lights,
                               boost=None if not boost else {"threshold": boost["threshold"], "factor": boost["factor"]})
    elif how == "synthetic":
        out = _synthetic_builders()[info["source"]](info, big, lights)
    else:
        out = split_texels(env, big)
    return Environment(out.directions, out.radiance, out.solid_angle,
                       {**out.info, "refined": how, "refined_from": r}, out.corners, out.moments)


__all__ = ["BLOCK_INFO", "LIGHT_BLOCK", "ROUTES", "at_resolution", "blocks", "bright_texels", "difference_blocks", "mixture", "parents", "route",
           "split_texels"]
