"""Computing a bake: per roughness layer, the weights by a truncated SVD of the azimuth-averaged integrals,
the maps by filtering the environment with the kernels those weights combine.

For layer j (roughness rho_j) and view cosines x_i (the weight tables' column centres), the data are
Y[m, (i, lobe)] = the azimuth-averaged I_A, I_B about M axes a_m (a = normalize((1 - s) r + s n), s per
layer, :func:`shift_candidates`) (:mod:`.kernels`: the isotropic
filters K^A_x, K^B_x of the environment). The best K-term P_k(r) (a_k(x), b_k(x)) in least squares over
those data is the truncated SVD Y ~ U S V^T (Eckart-Young): (a_k, b_k) = V_k and P_k = Y V_k, which is the
filter of the environment by the combined kernel kappa_k = sum_i V[(i, A), k] K^A_xi + V[(i, B), k] K^B_xi,
evaluated at every texel of layer j's map. Split-sum's P(r) (A(x), B(x)) is one such product, so on these
data K = 1 is never worse than it. The diffuse part is the same with the axis n (rank D).
Successive layers' V are aligned by an orthogonal Procrustes rotation (the products are unchanged), so
blending two layers blends like terms. Layer face sizes follow the lobe width alpha = rho^2
(texel angle <= alpha, at most the source's detail), lights at the same resolution.
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

import numpy as np

from ..errors import HomofacError
from ..io.limits import image_info
from ..light import Environment, load_environment
from ..light.sh import sh9
from ..light.sources import BUNDLED, bundled
from ..options import validate
from ..param import mappers
from . import kernels as kn
from .filter import normalized, prefilter, prefilter_cube
from .model import Bake, diffuse_sh9
from .options import BakeOptions
from .plan import BakePlan, plan as make_plan

#: Roughness from which layers try axis shifts (below it the choice was measured unreliable: forest, fast,
#: rho 0.156 picked s = 2 alpha and read 0.57 nrmse on I_A where s = 0 reads 0.20; at 0.538 s = alpha: 0.33 -> 0.21).
SHIFT_FROM = 0.4

#: Fraction of a map kernel's absolute mass within the cone of lights its texels read (the rest, far tails
#: of grazing views, is skipped; the normalization keeps a constant environment exact).
SUPPORT = 0.99

#: Smallest P face size.
MIN_SIZE = 8


def fibonacci(count: int) -> np.ndarray:
    """``count`` near-uniform unit directions (the Fibonacci sphere), (count, 3)."""
    i = np.arange(count) + 0.5
    z = 1.0 - 2.0 * i / count
    phi = np.pi * (1.0 + 5 ** 0.5) * i
    s = np.sqrt(1.0 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)


def _path(source) -> Path | None:
    if isinstance(source, Environment):
        return None
    p = Path(os.fspath(source)).expanduser()
    if not p.exists():
        stem = str(source)[:-4] if str(source).lower().endswith(".exr") else str(source)
        if os.sep not in str(source) and stem in BUNDLED:
            return bundled(stem)
        raise HomofacError(f"{p}: no such file (bundled environments: {', '.join(BUNDLED)})")
    return p


def source_size(source) -> int:
    """The cube face size that holds the source's detail: lat-long width / 4 (a cube map's face size),
    as a power of two in [16, 256]; an :class:`Environment` its resolution."""
    if isinstance(source, Environment):
        s = int(source.info.get("resolution", 32))
    else:
        p = _path(source)
        if p.is_dir():
            s = 256
        else:
            info = image_info(p)
            w, h = info.width, info.height
            s = h if w == 6 * h else (w if h == 6 * w else w // 4)
    return int(min(256, max(16, 2 ** int(math.floor(math.log2(max(s, 1)))))))


class _Lights:
    """The source resampled at each light resolution the bake needs (loaded once per resolution)."""

    def __init__(self, source):
        self.source = source
        self.cache: dict[int, Environment] = {}

    def __call__(self, resolution: int) -> Environment:
        if isinstance(self.source, Environment):
            return self.source
        if resolution not in self.cache:
            self.cache[resolution] = load_environment(self.source, resolution)
        return self.cache[resolution]


def texel_radius(env: Environment) -> float:
    """The angular size of a light texel (the kernels' smoothing radius: a narrow kernel then always covers
    a few texel centres, and :func:`~homofac.bake.filter.normalized` makes their weights sum to its mass)."""
    r = int(env.info.get("resolution", 32))
    return (math.pi / 2) / r


def layer_size(rho: float, max_size: int) -> int:
    """P face size of a layer: texel angle (pi/2)/S at most the lobe width alpha = rho^2, power of two."""
    s = (math.pi / 2) / (rho * rho)
    return int(min(max_size, max(MIN_SIZE, 2 ** int(math.ceil(math.log2(s))))))


def _svd(y: np.ndarray, rank: int) -> tuple[np.ndarray, float]:
    """V (columns, rank) of the truncated SVD of data (rows, columns, 3) with the channels as rows, and the
    energy it captures (sum of the kept squared singular values)."""
    m = np.moveaxis(y, 2, 1).reshape(-1, y.shape[1])
    _, sv, vt = np.linalg.svd(m, full_matrices=False)
    v = vt[:rank].T
    if np.sum(v[:, 0]) < 0:
        v[:, 0] = -v[:, 0]
    return v, float(np.sum(sv[:rank] ** 2))


def shift_candidates(rho: float) -> tuple[float, ...]:
    """The axis shifts s tried for a layer (axis normalize((1 - s) r + s n)): 0 and multiples of alpha = rho^2
    (the lobe leans towards n by about its width); one per layer is kept, the one whose products capture
    the most of the azimuth-averaged data (the azimuth variance, the rest of the error, is then smallest)."""
    a = rho * rho
    if rho < SHIFT_FROM:
        return (0.0,)
    return tuple(sorted({0.0, min(1.0, 0.5 * a), min(1.0, a)}))


def _align(v: np.ndarray, previous: np.ndarray | None) -> np.ndarray:
    """``v`` rotated (orthogonal Procrustes) to be closest to the previous layer's ``previous``."""
    if previous is None or v.shape[1] == 1:
        return v
    a, _, bt = np.linalg.svd(v.T @ previous)
    return v @ (a @ bt)


def bake(environment, options: BakeOptions | dict | None = None, **kwargs) -> Bake:
    """Bake ``environment`` (a lat-long EXR/HDR path, a cube map, a bundled name such as ``"forest"``, or an
    :class:`Environment`) for every glTF metallic-roughness material (see the module docstring)."""
    opts = options if isinstance(options, BakeOptions) else validate(BakeOptions, {**(options or {}), **kwargs}, "bake")
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    max_size = int(opts.max_size or source_size(environment))
    pl = make_plan(opts.preset, max_size=max_size, min_roughness=opts.min_roughness, nv_size=opts.nv_size,
                   diffuse_size=opts.diffuse_size, layers=opts.layers, terms=opts.terms, diffuse_basis=opts.diffuse)
    lights = _Lights(environment)
    x = kn.nv_centres(pl.nv_size)
    data_env = lights(opts.data_resolution)
    dirs = fibonacci(opts.samples)
    timings["load_s"] = time.perf_counter() - t0

    # diffuse: I_d ~ sum_d E_d(n) w_d(n.v)
    t = time.perf_counter()
    kd = kn.diffuse_kernels(x)
    kds = kn.smooth(kd, texel_radius(data_env))
    yd = normalized(*prefilter(kds, dirs, data_env), kn.mass(kds))  # (M, X, 3)
    vd, _ = _svd(yd, pl.diffuse)  # (X, D)
    env_e = lights(min(pl.diffuse_size, max_size))
    e_dirs = mappers.texel_directions("cube", pl.diffuse_size).reshape(-1, 3)
    ke = kn.smooth(vd.T @ kd, texel_radius(env_e))
    e, den = prefilter(ke, e_dirs, env_e)  # (T, D, 3)
    e = normalized(e, den[:, 0], kn.mass(ke)[0])
    E = e.reshape(pl.diffuse_size, 6 * pl.diffuse_size, pl.diffuse, 3).astype(np.float32)
    timings["diffuse_s"] = time.perf_counter() - t

    # specular layers
    roughness = pl.roughnesses()
    P, W, previous = [], [], None
    timings["kernels_s"] = timings["weights_s"] = timings["maps_s"] = 0.0
    sizes = []
    shifts = []
    for rho in roughness:
        ks, v, shift, captured = None, None, 0.0, -1.0
        t = time.perf_counter()
        exact = kn.albedos(rho, x)
        timings["kernels_s"] += time.perf_counter() - t
        for cand in shift_candidates(rho):
            t = time.perf_counter()
            k_c = kn.calibrate(kn.specular_kernels(rho, x, shift=cand), exact).reshape(2 * len(x), -1)  # rows (A, x..), (B, x..)
            timings["kernels_s"] += time.perf_counter() - t
            t = time.perf_counter()
            k_s = kn.smooth(k_c, texel_radius(data_env))
            y = normalized(*prefilter(k_s, dirs, data_env), kn.mass(k_s))  # (M, 2X, 3)
            v_c, energy = _svd(y, pl.terms)
            timings["weights_s"] += time.perf_counter() - t
            if energy > captured:
                ks, v, shift, captured = k_c, v_c, cand, energy
        v = _align(v, previous)
        previous = v
        shifts.append(float(shift))
        t = time.perf_counter()
        s = layer_size(rho, max_size)
        env_j = lights(s)
        # the maps' kernels and, last, a positive reference (the A lobe summed over n.v) whose discrete mass
        # against its exact mass corrects every map's quadrature (a rotated term's kernel may have ~0 mass)
        # Terms after the first are smoothed as their data were (the data's light texel): the SVD never saw
        # their finer detail, and a signed kernel's sharp core that the data's texels averaged out would
        # otherwise come back at full strength on a bright small source (city's sun: P_2 10x P_1).
        kk = v.T @ ks
        fine = kn.smooth(np.concatenate([kk[:1], ks[: len(x)].sum(0, keepdims=True)]), texel_radius(env_j))
        coarse = kn.smooth(kk[1:], max(texel_radius(env_j), texel_radius(data_env)))
        kp = np.concatenate([fine[:1], coarse, fine[1:]])
        p, den = prefilter_cube(kp, s, env_j, kn.support(kp, SUPPORT))
        p = normalized(p[:, :-1], den[:, -1], kn.mass(kp)[-1])
        P.append(p.reshape(s, 6 * s, pl.terms, 3).astype(np.float32))
        sizes.append(s)
        timings["maps_s"] += time.perf_counter() - t
        # table channels of this layer: a_k = V[x, k] (A rows), b_k = V[X + x, k]
        a, b = v[: len(x)], v[len(x):]
        W.append(np.stack([a, b], axis=-1).reshape(len(x), 2 * pl.terms))
    w = np.stack(W)  # (L, X, 2K)
    wd = np.broadcast_to(vd[None], (pl.layers, len(x), pl.diffuse))
    table = np.concatenate([w, wd], axis=-1).astype(np.float32)
    t = time.perf_counter()
    sh = sh9(lights(opts.data_resolution))
    timings["sh9_s"] = time.perf_counter() - t
    timings["total_s"] = time.perf_counter() - t0
    info = {"sh9": sh.document(), "source": str(getattr(environment, "info", {}).get("source", environment)) if isinstance(environment, Environment)
            else str(_path(environment)), "options": opts.model_dump(), "sizes": sizes,
            "data_resolution": int(data_env.info.get("resolution", 0)), "timings": timings}
    return Bake(pl, roughness, tuple(shifts), tuple(P), E, table, info,
                diffuse_sh9(E) if pl.diffuse_basis == "sh9" else None)


__all__ = ["bake", "fibonacci", "layer_size", "source_size"]
