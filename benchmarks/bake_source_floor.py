"""How much of a cell's error is the analytic source, and what the bake reads with the source shaded exactly.

For the saved bakes of benchmarks/bake_accuracy.py (``--bake-dir DIR`` holding ``NAME-PRESET``), on a cell's
weighted pairs (:mod:`bake_pairs`) against the converged reference (:mod:`homofac.light.reference`):

* the source's pixels: the lat-long's brightest pixel and the pixels within
  :data:`homofac.bake.sources.RADIUS` of it with at least 1/:data:`~homofac.bake.sources.RATIO` of its
  luminance, minus the fill of the ring around them (the rule of :func:`homofac.bake.sources.brightest_source`
  on the reference's own pixels); ``core`` is that excess image, ``rest`` the map without it, and the
  reference is linear in its image: ref = ref(core) + ref(rest) (ref(core) is computed from ``core`` alone,
  rescaled by the full map's bilinear-energy scale so that the two add up to the reference's reading);
* ``e_src`` = L(the bake's analytic term) - L(ref(core)): the source's error; ``e_maps`` = L(the bake without
  its analytic term) - L(ref(rest)): the maps' error; the bake's error is their sum;
* ``bake``, ``src``, ``maps``: sqrt(sum w |e|^2 / sum w |L|^2) of each (``maps`` is the **floor with the source
  shaded exactly**: the bake's maps plus the reference integral of the source's pixels); ``maps_d`` /
  ``maps_AB``: the maps' error in the diffuse term / the two specular terms alone; ``src_A``, ``src_B``, ``src_d``
  likewise; ``cross``: 2 sum w e_src.e_maps / sum w |e|^2 (the share of the squared error in the cross term);
* ``--models``: the bake's maps plus other source models (:func:`source_model`: ``point``, ``widened:k``,
  ``mix:k1:k2``, ``core:k1:k2``) against the reference; ``--core``: the bake's own source (its axes when it has
  them) at other values of :data:`homofac.bake.sources.CORE`. :func:`source_shape` and :func:`aniso_model` are
  the prototypes of the axes (measured on an environment's own core at a given light resolution).

    PYTHONPATH=src python benchmarks/bake_source_floor.py --bake-dir DIR [--envs city ...] [--bands 0] [--pairs 4096]
        [--cache DIR] [--models core:1:1.1 ...] [--core 1.0 1.1 1.2]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import homofac as hf
from homofac.bake import sources
from homofac.bake.kernels import _frame, _local
from homofac.bake.sources import RADIUS, RATIO, source_terms
from homofac.brdf.gltf import DIELECTRIC_F0, gltf_lobes_at
from homofac.io.exr import read_exr
from homofac.light.environment import LUMINANCE
from homofac.light.latlong import latlong_directions, latlong_solid_angles
from homofac.light.reference import reference_integrals, source_map

sys.path.insert(0, str(Path(__file__).parent))
import bake_accuracy as ba  # noqa: E402
from bake_pairs import weighted_pairs  # noqa: E402


def core_and_fill(d: np.ndarray, rad: np.ndarray, dw: np.ndarray, radius: float, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """``(core (N,) bool, fill (3,))`` at unit directions ``d`` (N, 3) of radiance ``rad`` (N, 3) and solid angle
    ``dw`` (N,): the brightest direction's core (within ``radius`` rad of it with >= 1/``ratio`` of its luminance)
    and the mean radiance of the ring around it (radius to 2 radius, at least two texels wide), as
    :func:`homofac.bake.sources.brightest_source` takes them."""
    lum = rad @ np.asarray(LUMINANCE, np.float64)
    seed = int(np.argmax(lum))
    cos = d @ d[seed]
    core = (cos > np.cos(radius)) & (lum >= lum[seed] / ratio)
    outer = max(2 * radius, radius + 2 * float(np.sqrt(dw.max())))
    ring = (cos <= np.cos(radius)) & (cos > np.cos(outer))
    return core, (rad[ring] * dw[ring, None]).sum(0) / dw[ring].sum()


def split_core(image: np.ndarray, radius: float = RADIUS, ratio: float = RATIO) -> tuple[np.ndarray, np.ndarray]:
    """``(core, rest)`` lat-long images (H, 2H, 3), core + rest = image: the brightest pixel's core (pixels within
    ``radius`` rad of it with >= 1/``ratio`` of its luminance) minus the ring's fill (radius to 2 radius, at least
    two pixels wide), as :func:`homofac.bake.sources.brightest_source` does on the bake's lights."""
    img = np.asarray(image, np.float64)[..., :3]
    h, w = img.shape[:2]
    d = latlong_directions(h, w).reshape(-1, 3)
    dw = np.repeat(latlong_solid_angles(h, w), w)
    rad = img.reshape(-1, 3)
    core, fill = core_and_fill(d, rad, dw, radius, ratio)
    rest = rad.copy()
    rest[core] = np.minimum(rad[core], fill)
    return (rad - rest).reshape(img.shape), rest.reshape(img.shape)


def share(e: np.ndarray, L: np.ndarray, w: np.ndarray) -> float:
    """sqrt(sum w |e|^2 / sum w |L|^2), |.| over RGB."""
    return float(np.sqrt(np.sum(w * np.sum(e * e, 1)) / np.sum(w * np.sum(L * L, 1))))


def radiance(parts, c, m) -> np.ndarray:
    """:func:`homofac.light.integrals.material_radiance` in float64 NumPy: (N, 3)."""
    p, c, m = np.asarray(parts, np.float64), np.asarray(c, np.float64), np.asarray(m, np.float64)[:, None]
    f0 = (1.0 - m) * DIELECTRIC_F0 + m * c
    return (1.0 - m) * (1.0 - DIELECTRIC_F0) * c * p[:, 0] + f0 * p[:, 1] + p[:, 2]


def term(parts: np.ndarray, t: int) -> np.ndarray:
    """``parts`` with every term but ``t`` zeroed (one term's contribution to L)."""
    out = np.zeros_like(parts)
    out[:, t] = parts[:, t]
    return out


def core_reference(image, n, v, rho, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """``(ref(image), ref(core))`` (N, 3, 3) on the pairs, ref(core) in the full map's scale (module docstring)."""
    core, _ = split_core(image)
    full = source_map(image)
    cm = source_map(core)
    ref = reference_integrals(full, n, v, rho, samples=samples)
    refc = reference_integrals(cm, n, v, rho, samples=samples) * (np.asarray(full.scale) / np.asarray(cm.scale))[None, None, :]
    return ref, refc


def profile_lobes(sources, n, v, rho, ratio) -> np.ndarray:
    """(N, 3, 3): :func:`homofac.bake.sources.source_terms` with D'/D given by ``ratio(a2, s2, nh, sin2)``, s2 =
    radius^2 / (4 n.v) (the source's extent in half vectors)."""
    n, v = jnp.asarray(n, jnp.float32), jnp.asarray(v, jnp.float32)
    rho = jnp.broadcast_to(jnp.asarray(rho, jnp.float32), n.shape[:1])
    t, b = _frame(n)
    wo = _local(v, t, b, n)
    a2 = rho ** 4
    out = np.zeros((n.shape[0], 3, 3))
    for s in sources:
        wi = _local(jnp.broadcast_to(jnp.asarray(s.direction, jnp.float32), n.shape), t, b, n)
        above = (wi[2] > 0) & (wo[2] > 0)
        wi = tuple(jnp.where(above, c, 0.0 if i < 2 else 1.0) for i, c in enumerate(wi))
        wo_ = (wo[0], wo[1], jnp.where(above, wo[2], 1.0))
        d, la, lb = gltf_lobes_at(rho, wi, wo_)
        h = [a + c for a, c in zip(wi, wo_)]
        hn2 = h[0] * h[0] + h[1] * h[1] + h[2] * h[2]
        k = ratio(a2, s.radius ** 2 / 4 / wo_[2], jnp.maximum(h[2], 0.0) * jax.lax.rsqrt(hn2), (h[0] * h[0] + h[1] * h[1]) / hn2)
        lobes = jnp.stack([d, la * k, lb * k], 1)
        lobes = jnp.where(above[:, None], lobes * wi[2][:, None], 0.0)
        out = out + np.asarray(lobes, np.float64)[:, :, None] * np.asarray(s.power)[None, None, :]
    return out


def ggx(a2, nh, sin2):
    """GGX D at alpha^2 ``a2`` (cos, sin^2 of theta_h)."""
    q = a2 * nh * nh + sin2
    return a2 / (np.pi * q * q)


def beckmann(m2, nh, sin2):
    """Beckmann D at m^2 ``m2``: exp(-tan^2 / m^2) / (pi m^2 cos^4) (peak 1 / (pi m^2), GGX's at alpha^2 = m^2)."""
    c2 = jnp.maximum(nh * nh, 1e-12)
    return jnp.exp(-sin2 / (c2 * m2)) / (np.pi * m2 * c2 * c2)


def source_model(sources, n, v, rho, model: str) -> np.ndarray:
    """The analytic term under a named model: ``widened:k`` (GGX at alpha^2 + k^2 s2, the built rule at k = 1.25),
    ``mix:k1:k2``: S = k1^2 s2, w = S / (alpha^2 + S); D' = w Beckmann(m^2 = alpha^2 + k2^2 s2) + (1 - w)
    GGX(alpha^2 + S) (a compact core where the source is wider than the lobe, GGX's own tail alpha^2 / (pi t^4)
    exactly: (1 - w)(alpha^2 + S) = alpha^2), ``point``."""
    kind, *ks = model.split(":")
    ks = [float(k) for k in ks]
    if kind == "point":
        return profile_lobes(sources, n, v, rho, lambda a2, s2, nh, sin2: 1.0)
    if kind == "widened":
        return profile_lobes(sources, n, v, rho, lambda a2, s2, nh, sin2: ggx(a2 + ks[0] ** 2 * s2, nh, sin2) / ggx(a2, nh, sin2))
    if kind == "mix":
        def ratio(a2, s2, nh, sin2):
            S = ks[0] ** 2 * s2
            wg = S / (a2 + S)
            return (wg * beckmann(a2 + ks[1] ** 2 * s2, nh, sin2) + (1 - wg) * ggx(a2 + S, nh, sin2)) / ggx(a2, nh, sin2)
        return profile_lobes(sources, n, v, rho, ratio)
    if kind == "core":
        return core_model(sources, n, v, rho, ks[0], ks[1])
    raise ValueError(f"unknown source model {model!r}")


def core_and_tail(src, n, v, rho, k1: float, x, a2, blob) -> np.ndarray:
    """``(I_d, I_A, I_B)`` (N, 3, 3) of one source as the weighted sum of the module's two parts: with S = (k1
    radius)^2 / (4 n.v) and w = S / (alpha^2 + S), w of the core ``blob`` (N,) (the source's density read at the
    mirror direction, already divided by 1 + 2 Lambda(n.v)) times the mirror's albedos (I_A: 1 - (1 - n.v)^5,
    I_B: (1 - n.v)^5), and 1 - w of the point light's lobe with D at alpha^2 + S; I_d the point light's. ``x``
    (N,) is n.v, ``a2`` alpha^2."""
    S = (k1 * src.radius) ** 2 / (4 * x)
    wg = S / (a2 + S)
    part = profile_lobes((src._replace(radius=k1 * src.radius),), n, v, rho,
                         lambda a2_, s2, nh, sin2: ggx(a2_ + s2, nh, sin2) / ggx(a2_, nh, sin2))
    s5 = (1 - x) ** 5
    core = np.stack([np.zeros_like(x), (1 - s5) * blob, s5 * blob], 1)[:, :, None] * np.asarray(src.power)[None, None, :]
    part = part.copy()
    part[:, 1:] *= (1 - wg)[:, None, None]
    part[:, 1:] += wg[:, None, None] * core[:, 1:]
    return part


def core_model(sources, n, v, rho, k1: float, k2: float) -> np.ndarray:
    """``core:k1:k2``: S = (k1 radius)^2 / (4 n.v), w = S / (alpha^2 + S); w of the source as a Gaussian blob about
    its direction in light space, read at the reflected direction r with the mirror's albedos
    (I_A: 1 - (1 - n.v)^5, I_B: (1 - n.v)^5, times 1 / (1 + 2 Lambda(n.v))): Phi exp(-t^2 / s^2) / (pi s^2), t the
    angle of r from the source, s^2 = (k2 radius)^2 + 4 n.v alpha^2 (the source's radial RMS^2 and the lobe's in
    light space); 1 - w of it as the point light's lobe with D at alpha^2 + S (GGX's own tail exactly)."""
    n64, v64 = np.asarray(n, np.float64), np.asarray(v, np.float64)
    x = np.maximum(np.sum(n64 * v64, 1), 1e-6)
    r = 2 * x[:, None] * n64 - v64
    a2 = np.asarray(rho, np.float64) ** 4
    out = np.zeros((len(x), 3, 3))
    for src in sources:
        ell = np.asarray(src.direction, np.float64)
        nl = n64 @ ell
        t2 = np.arccos(np.clip(r @ ell, -1, 1)) ** 2
        s2 = (k2 * src.radius) ** 2 + 4 * x * a2
        lam = 0.5 * (np.sqrt(1 + a2 * (1 - x * x) / (x * x)) - 1)
        blob = np.exp(-t2 / s2) / (np.pi * s2) / (1 + 2 * lam) * ((nl > 0) & (np.sum(n64 * v64, 1) > 0))
        out += core_and_tail(src, n, v, rho, k1, x, a2, blob)
    return out


def breakdown(maps, analytic, ref, refc, c, m, w) -> dict:
    """The figures of the module docstring for the bake's ``maps`` and ``analytic`` terms (N, 3, 3)."""
    L = radiance(ref, c, m)
    e_src = radiance(analytic - refc, c, m)
    e_maps = radiance(maps - (ref - refc), c, m)
    e = e_src + e_maps
    tot = float(np.sum(w * np.sum(e * e, 1)))
    return {"bake": share(e, L, w), "src": share(e_src, L, w), "maps": share(e_maps, L, w),
            "cross": float(2 * np.sum(w * np.sum(e_src * e_maps, 1)) / tot),
            "maps_d": share(radiance(term(maps - (ref - refc), 0), c, m), L, w),
            "maps_AB": share(radiance(maps - (ref - refc) - term(maps - (ref - refc), 0), c, m), L, w),
            **{f"src_{k}": share(radiance(term(analytic - refc, t), c, m), L, w) for t, k in enumerate("dAB")}}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bake-dir", required=True)
    ap.add_argument("--preset", default="balanced")
    ap.add_argument("--envs", nargs="+", default=["city", "forest", "interior", "studio"])
    ap.add_argument("--bands", nargs="+", type=int, default=[0])
    ap.add_argument("--pairs", type=int, default=4096)
    ap.add_argument("--samples", type=int, default=4096)
    ap.add_argument("--cache", help="directory keeping each cell's pairs and references (.npz) between runs")
    ap.add_argument("--models", nargs="*", default=[], help="source models (source_model's names) to read beside the bake's")
    ap.add_argument("--core", nargs="*", type=float, default=[], help="values of sources.CORE to read the bake's source at")
    args = ap.parse_args(argv)
    for name in args.envs:
        b = hf.load(Path(args.bake_dir) / f"{name}-{args.preset}")
        image = read_exr(hf.light.bundled(name))
        for bi in args.bands:
            band = ba.BANDS[bi]
            kept = Path(args.cache) / f"{name}-{bi}-{args.pairs}-{args.samples}.npz" if args.cache else None
            if kept is not None and kept.exists():
                z = np.load(kept)
                n, v, c, m, rho, w, ref, refc = (z[k] for k in ("n", "v", "c", "m", "rho", "w", "ref", "refc"))
            else:
                n, v, c, m, rho, w = weighted_pairs(image, band, args.pairs, ba.cell_seed(name, bi))
                ref, refc = core_reference(image, n, v, rho, args.samples)
                if kept is not None:
                    kept.parent.mkdir(parents=True, exist_ok=True)
                    np.savez(kept, n=n, v=v, c=c, m=m, rho=rho, w=w, ref=ref, refc=refc)
            analytic = np.asarray(source_terms(b.sources, n, v, rho), np.float64)
            maps = np.asarray(b.terms(n, v, rho), np.float64) - analytic
            row = {"env": name, "band": band, "pairs": args.pairs,
                   "source": b.sources[0].describe() if b.sources else None,
                   **{k: round(x, 4) for k, x in breakdown(maps, analytic, ref, refc, c, m, w).items()}}
            for core in args.core:
                default, sources.CORE = sources.CORE, core
                alt = np.asarray(source_terms(b.sources, n, v, rho), np.float64)
                sources.CORE = default
                row[f"CORE {core:g}"] = {k: round(x, 4) for k, x in breakdown(maps, alt, ref, refc, c, m, w).items()
                                         if k in ("bake", "src")}
            for model in args.models:
                alt = source_model(b.sources, n, v, rho, model)
                row[model] = {k: round(x, 4) for k, x in breakdown(maps, alt, ref, refc, c, m, w).items()
                              if k in ("bake", "src")}
            print(json.dumps(row), flush=True)




def source_shape(env, source) -> tuple[np.ndarray, np.ndarray]:
    """``(axes (2, 3), sigma2 (2,))``: the principal axes of the source's power-weighted covariance in the plane
    normal to its direction, over the core of :func:`homofac.bake.sources.brightest_source` on ``env``, and
    2 x the variance along each (a Gaussian exp(-sum (t.e_i)^2 / sigma2_i) has that covariance)."""
    d = np.asarray(env.directions, np.float64)
    rad = np.asarray(env.radiance, np.float64)
    dw = np.asarray(env.solid_angle, np.float64)
    core, fill = core_and_fill(d, rad, dw, RADIUS, RATIO)
    wgt = np.maximum(rad[core] - fill, 0.0) * dw[core, None] @ np.asarray(LUMINANCE, np.float64)
    ell = np.asarray(source.direction, np.float64)
    p = d[core] - (d[core] @ ell)[:, None] * ell
    cov = (p * wgt[:, None]).T @ p / wgt.sum()
    val, vec = np.linalg.eigh(cov)
    return vec[:, 1:].T, 2 * val[1:]


def aniso_model(sources, shapes, n, v, rho, k1: float, k2: float, extra: float = 0.0) -> np.ndarray:
    """:func:`core_model` with the blob an anisotropic Gaussian of the source's covariance (``shapes``: per source
    (axes, sigma2) of :func:`source_shape`), each sigma2 times k2^2 plus ``extra`` radius^2."""
    n64, v64 = np.asarray(n, np.float64), np.asarray(v, np.float64)
    x = np.maximum(np.sum(n64 * v64, 1), 1e-6)
    r = 2 * x[:, None] * n64 - v64
    a2 = np.asarray(rho, np.float64) ** 4
    out = np.zeros((len(x), 3, 3))
    for src, (axes, sig2) in zip(sources, shapes):
        ell = np.asarray(src.direction, np.float64)
        nl = n64 @ ell
        b = 4 * x * a2
        s2a = k2 ** 2 * sig2[0] + extra * src.radius ** 2 + b
        s2b = k2 ** 2 * sig2[1] + extra * src.radius ** 2 + b
        q = (r @ axes[0]) ** 2 / s2a + (r @ axes[1]) ** 2 / s2b
        lam = 0.5 * (np.sqrt(1 + a2 * (1 - x * x) / (x * x)) - 1)
        blob = np.exp(-q) / (np.pi * np.sqrt(s2a * s2b)) / (1 + 2 * lam) * ((nl > 0) & (r @ ell > 0))
        out += core_and_tail(src, n, v, rho, k1, x, a2, blob)
    return out


if __name__ == "__main__":
    main()
