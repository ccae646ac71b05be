"""Computing a bake: per roughness layer, the weights by a truncated SVD of the azimuth-averaged integrals
at the texels of the layer's own map, the maps by filtering the environment with the kernels those weights
combine, with the same lights and the same kernels.

For layer j (roughness rho_j) and view cosines x_i (the weight tables' column centres), the data are
Y[t, (i, lobe)] = the azimuth-averaged I_A, I_B about the axis a = normalize((1 - s) r + s n) at the texel
centres t of a cube (:mod:`.kernels`: the isotropic filters K^A_x, K^B_x of the environment; s per layer,
:func:`shift_candidates`). The best K-term P_k(r) (a_k(x), b_k(x)) in least squares over those data (the
sphere's measure: texels weighted by their solid angle) is the truncated SVD Y ~ U S V^T (Eckart-Young):
(a_k, b_k) = V_k and P_k = Y V_k, the filter of the environment by the combined kernel
kappa_k = sum_i V[(i, A), k] K^A_xi + V[(i, B), k] K^B_xi, evaluated at every texel of layer j's map with the
lights and the kernel smoothing of the data (:func:`layer_fit`): the map is what the weights were fitted to,
so a later term cannot meet a sharper version of a bright source than the one its weights saw. Split-sum's
P(r) (A(x), B(x)) is one such product, so on these data K = 1 is never worse than it. The diffuse part is
the same with the axis n (rank D), on Fibonacci directions.
Successive layers' V are aligned by an orthogonal Procrustes rotation (the products are unchanged), so
blending two layers blends like terms. Layer face sizes follow the lobe width alpha = rho^2 (:func:`layer_size`);
the layers whose lobe is at most half a texel of the largest map share one block (:func:`sharp`).
With the plan's ``harmonic``, each layer from that roughness up also gets the rank-1 product of its lobes' second
azimuthal harmonic about the axis, from the luminance: a tensor map M(a) read as t^T M t and weights h_A, h_B
(:func:`harmonic_maps`, :func:`harmonic_fit`; orthogonal to the azimuth means, so the products are unchanged).
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from ..blas import blas_threads
from ..errors import HomofacError
from ..io.limits import image_info
from ..light import Environment, load_environment
from ..light.environment import LUMINANCE
from ..light.resample import from_cube
from ..light.sh import sh9
from ..light.sources import BUNDLED, bundled
from ..options import validate
from ..param import mappers
from . import kernels as kn
from .filter import normalized, prefilter, two_scale
from .atlas import Atlas, bottom_left
from .gauge import face_gauge
from .model import Bake, diffuse_sh9
from .options import BakeOptions
from .plan import BakePlan, plan as make_plan
from .sources import MAX_SOURCES, Source, brightest_source, core_and_halo, principal_axes, with_boxes, with_cores

#: Roughness from which layers try axis shifts (below it the choice was measured unreliable: forest, fast,
#: rho 0.156 picked s = 2 alpha and read 0.57 nrmse on I_A where s = 0 reads 0.20; at 0.538 s = alpha: 0.33 -> 0.21).
SHIFT_FROM = 0.4

#: Smallest P face size.
MIN_SIZE = 8

#: Largest cube face size at whose texel centres a layer's weights are fitted.
DATA_SIZE = 32

#: (weight of I_A, weight of I_B) in the specular radiance of the materials whose error the layers' fit
#: minimizes: a white metal (f0 = 1) and a dielectric (f0 = 0.04). I_B is ~10x smaller than I_A but carries a
#: dielectric's reflection (measured: no change against fitting (I_A, I_B) as they are, studio 0.3-0.6).
MATERIALS = ((1.0, 1.0), (0.04, 1.0))

#: Measure of the n.v columns x in the layers' fit: ``uniform`` (each column alike) or ``screen`` (density 2 x:
#: the share of a rendered object's pixels at that n.v, the accuracy benchmark's population). Measured on the
#: converged cells 0.15-0.6 of forest, interior, studio (benchmarks/bake_mid_variants.py --variant screen):
#: -0.4 % to +2.4 % nrmse (studio 0.3-0.6 0.2284 -> 0.2339), so uniform.
NV_MEASURE = "uniform"


def nv_measure(x: np.ndarray) -> np.ndarray:
    """The fit's weight of each n.v column x (:data:`NV_MEASURE`), mean 1 over uniform columns."""
    return np.ones_like(x) if NV_MEASURE == "uniform" else 2.0 * x


#: Smallest light resolution a layer's data and map are computed from (and of the far parts' lights).
MIN_LIGHTS = 16

#: The sharp block's lights per face texel side (:func:`block_lights`): 4 x the bundled maps' 64 face is 256,
#: a light texel a quarter of the source's lat-long pixel (city below 0.15, balanced: 1x 0.0402, 2x 0.0244, 4x 0.022).
BLOCK_OVERSAMPLE = 4

#: Largest light resolution of the sharp block (a 256 face is 393 216 lights; the block reads a few thousand
#: of them per 8 x 8 texels).
BLOCK_LIGHTS_MAX = 256


class _Clock:
    """Per-stage wall and CPU (``time.process_time``: every thread of the process) seconds: ``timings[stage_s]``
    and ``timings[stage_cpu_s]``, summed over the stage's intervals. CPU is what compares across machine loads
    (docs/notes/bake.md, "Bake time, eighteenth session")."""

    def __init__(self):
        self.timings: dict[str, float] = {}
        self._wall0, self._cpu0 = time.perf_counter(), time.process_time()
        self._stage: str | None = None

    def __call__(self, stage: str | None) -> None:
        """End the running stage (if any) and start ``stage`` (None: stop)."""
        wall, cpu = time.perf_counter(), time.process_time()
        if self._stage is not None:
            for key, now, then in ((f"{self._stage}_s", wall, self._wall), (f"{self._stage}_cpu_s", cpu, self._cpu)):
                self.timings[key] = self.timings.get(key, 0.0) + now - then
        self._stage, self._wall, self._cpu = stage, wall, cpu

    def total(self) -> dict[str, float]:
        """The timings with ``total_s`` and ``total_cpu_s`` since the clock was made."""
        self(None)
        return {**self.timings, "total_s": time.perf_counter() - self._wall0,
                "total_cpu_s": time.process_time() - self._cpu0}


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
    """The source resampled at each light resolution the bake needs (loaded once per resolution); after
    :meth:`take_source`, the map without its brightest compact source, resampled from the resolution it was
    found at (a resolution above it, from the finer lights it was also taken from, box-averaged)."""

    def __init__(self, source):
        self.source = source
        self.cache: dict[int, Environment] = {}
        self.strip: np.ndarray | None = None
        self.fine: dict[int, Environment] = {}

    def __call__(self, resolution: int) -> Environment:
        if isinstance(self.source, Environment):
            return self.source
        if resolution in self.fine:
            return self.fine[resolution]
        finer = [f for f in self.fine if f % resolution == 0 and self.strip is not None and resolution > len(self.strip)]
        if finer and resolution not in self.cache:  # above the coarse map's detail: box-averaged from the finer lights
            fine = self.fine[min(finer)]
            self.cache[resolution] = from_cube(np.asarray(fine.radiance, np.float32)[: 6 * min(finer) ** 2].reshape(
                min(finer), 6 * min(finer), 3), resolution, source=str(self.source))
        if resolution not in self.cache:
            self.cache[resolution] = (load_environment(self.source, resolution) if self.strip is None
                                      else from_cube(self.strip, resolution, source=str(self.source)))
        return self.cache[resolution]

    def take_source(self, resolution: int, finer: int | None = None) -> tuple[tuple[Source, ...], float]:
        """Find the brightest compact source at light ``resolution`` (:func:`~homofac.bake.sources.brightest_source`)
        and remove it from every resolution served afterwards; ``(its Gaussians, its power share)``, () when there
        is none. ``finer`` (a multiple of ``resolution``): that resolution is loaded from the source itself and the
        same core removed from it (its texels under the core's texels clipped to the same fill), so it keeps the
        source's detail instead of being resampled from the coarser map (the sharp block's lights,
        :func:`block_lights`); the source's direction and shape are measured on those texels, as its core and halo
        (:func:`~homofac.bake.sources.core_and_halo`). Without ``finer``: one Gaussian of the coarse texels."""
        env = self(resolution)
        rest, found, share = brightest_source(env)
        if found is None:
            return (), share
        if isinstance(self.source, Environment):
            self.source = rest
        else:
            r = int(env.info["resolution"]) if "resolution" in env.info else resolution
            before = np.asarray(env.radiance, np.float32)[: 6 * r * r].reshape(r, 6 * r, 3)
            self.strip = np.asarray(rest.radiance, np.float32)[: 6 * r * r].reshape(r, 6 * r, 3)
            self.cache = {resolution: rest}
            if finer is not None and finer > r and finer % r == 0:
                core = np.any(self.strip != before, axis=-1)  # (r, 6r): the texels the core took out
                fill = self.strip[core].max(0)  # their values are min(L, fill); the seed's is the fill
                k = finer // r
                fine = self.fine[finer] if finer in self.fine else load_environment(self.source, finer)
                rad = np.array(np.asarray(fine.radiance, np.float32)[: 6 * finer * finer].reshape(finer, 6 * finer, 3))
                under = np.repeat(np.repeat(core, k, 0), k, 1)  # the strip's rows and columns scale with the face
                excess = np.maximum(rad[under] - fill, 0.0) @ np.asarray(LUMINANCE, np.float32)
                rad[under] = np.minimum(rad[under], fill)
                self.fine[finer] = from_cube(rad, finer, source=str(self.source))
                # the core's direction and shape from the finer texels (the coarse face's texels are about a sun's
                # own size: their centres place it up to a third of a degree off and round it)
                dirs = np.asarray(fine.directions, np.float64)[: 6 * finer * finer].reshape(finer, 6 * finer, 3)[under]
                dw = np.asarray(fine.solid_angle, np.float64)[: 6 * finer * finer].reshape(finer, 6 * finer)[under]
                weight = excess * dw
                if float(np.sum(weight)) > 0:
                    mean = weight @ dirs
                    direction = tuple(float(c) for c in mean / np.linalg.norm(mean))
                    found = found._replace(direction=direction, axes=principal_axes(dirs, weight, direction))
                    return core_and_halo(found, dirs, weight), share
        return (found,), share


def texel_radius(env: Environment) -> float:
    """The angular size of a light texel (the kernels' smoothing radius: a narrow kernel then always covers
    a few texel centres, and :func:`~homofac.bake.filter.normalized` makes their weights sum to its mass)."""
    r = int(env.info.get("resolution", 32))
    return (math.pi / 2) / r


def layer_size(rho: float, max_size: int) -> int:
    """P face size of a layer: the power of two nearest (in log2) to pi / alpha, alpha = rho^2 the lobe width:
    a texel angle (pi/2)/S of about alpha / 2, the sharpness of an engine's prefiltered mip chain at that
    roughness (level rho (levels - 1): texel angle 0.35-0.6 alpha from roughness 0.3 up); in [MIN_SIZE, max_size]."""
    s = math.pi / (rho * rho)
    return int(min(max_size, max(MIN_SIZE, 2 ** int(round(math.log2(s))))))


def sharp(rho: float, max_size: int) -> bool:
    """True when the layer's lobe (width alpha = rho^2) is at most half a texel of the largest map: the bilinear
    read's own blur (a texel) then dominates its filtered map whatever the kernel, so all such layers share
    one block (only their weights, the lobes' albedos, differ). (A lobe up to a whole texel measured worse: the
    three.js test's sphere read 0.075 nrmse against 0.032 with each layer's own map at max_size 32.)"""
    return math.pi / (rho * rho) >= 4 * max_size


def layer_face(rho: float, max_size: int, block: int) -> int:
    """P face size of a layer in a bake whose sharp block has face ``block`` (>= ``max_size``,
    :func:`homofac.bake.plan.block_face`): ``block`` for the layers that share it (:func:`sharp` at ``block``);
    :func:`layer_size` up to ``block`` for the other layers whose lobe is at most half a texel of ``max_size`` (they
    read the source below its pixel, as the reference reads it, bilinearly: their maps need the source's detail
    above ``max_size``, from the block's finer lights, :class:`_Lights`); :func:`layer_size` up to ``max_size`` for
    the rest."""
    if sharp(rho, block):
        return block
    return layer_size(rho, block if sharp(rho, max_size) else max_size)


def block_lights(size: int) -> int:
    """Light resolution the sharp layers' shared block of face ``size`` is filtered from: BLOCK_OVERSAMPLE x its
    face (at most max(BLOCK_LIGHTS_MAX, size)). Its lobes are narrower than half a texel, so the block should
    hold the source read at its texel centres (what the reference integrates: the source read bilinearly);
    lights at the face's own size box-average a texel and the kernel's smoothing by a light texel blurs by
    another, before the shader's bilinear read blurs by a third (docs/notes/bake.md, "Accuracy, sixteenth
    session": city below 0.15, 0.0402 -> 0.0220 nrmse)."""
    return int(max(size, min(BLOCK_OVERSAMPLE * size, BLOCK_LIGHTS_MAX)))


def compress(kernels: np.ndarray, tolerance: float = 1e-2) -> tuple[np.ndarray, np.ndarray]:
    """``(basis (J', G), coef (J, J'))`` with ``kernels ~ coef @ basis``: the truncated SVD of the kernel tables
    (rows scaled to unit absolute mass), J' the smallest rank whose every row's absolute error (the sphere's
    measure, :func:`~homofac.bake.kernels.mass` of |K - K'|) is within ``tolerance`` of its absolute mass.
    The filter's cost grows with the tables it reads: 2X kernels of one roughness are a handful of shapes."""
    scale = np.maximum(kn.mass(np.abs(kernels)), 1e-300)
    kn_ = kernels / scale[:, None]
    vals, u = np.linalg.eigh(kn_ @ kn_.T)  # the left singular vectors (a J x J problem, not J x G)
    u = u[:, ::-1][:, vals[::-1] > vals.max() * 1e-14]
    for rank in range(1, u.shape[1] + 1):
        coef = u[:, :rank]
        if np.max(kn.mass(np.abs(coef @ (coef.T @ kn_) - kn_))) <= tolerance:
            break
    return coef.T @ kn_, coef * scale[:, None]


def filtered(kp: np.ndarray, size: int, env: Environment, coarse: Environment | None, own: np.ndarray) -> np.ndarray:
    """``(T, J - 1, 3)``: the kernels ``kp[:-1]`` applied at the texels of a cube of face ``size``
    (:func:`homofac.bake.filter.two_scale`: near part with ``env``'s lights, far part with ``coarse``'s,
    :data:`MIN_LIGHTS` in the bake),
    each part normalized by a discrete mass (Karis' normalized prefilter): kernel j by its own where ``own[j]``
    and the part is mostly positive, else by the reference kernel ``kp[-1]``'s (scaled by mass ratio); a
    constant environment reads every kernel's mass."""
    out = 0.0
    for num, den, t in two_scale(kp, size, env, coarse):
        mass, absolute = kn.mass(t), kn.mass(np.abs(t))
        mine = own & (np.abs(mass[:-1]) > 0.5 * absolute[:-1])
        ref = np.where(np.abs(den[:, -1:]) > 1e-30, mass[-1] / np.where(np.abs(den[:, -1:]) > 1e-30, den[:, -1:], 1.0), 0.0)
        self_ = np.where(np.abs(den[:, :-1]) > 1e-30, mass[:-1] / np.where(np.abs(den[:, :-1]) > 1e-30, den[:, :-1], 1.0), 0.0)
        out = out + num[:, :-1] * np.where(mine[None], self_, ref)[..., None]
    return out


def layer_fit(kernels: np.ndarray, size: int, env: Environment, rank: int, data_size: int = 32,
              masses: np.ndarray | None = None, coarse: Environment | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """``(V (J, rank), weights (J, rank), P (6 size^2, rank, 3), energy)`` of one layer.

    The data Y[t, j]: the environment ``env`` filtered by kernel j at the texel centres t of a cube of face
    min(size, data_size), normalized per texel by the positive reference kernel sum_j K_j (Karis' normalized
    prefilter). The error is measured on the specular radiance of the materials :data:`MATERIALS` (Z = Y R^T,
    R mixing each n.v's I_A and I_B columns): V is the truncated SVD of Z weighted by the texels' solid angles
    (Eckart-Young in the sphere's L2 norm; computed on :func:`compress`'s basis kernels, Y = Y_b coef^T), the
    weights of I_A, I_B are R^-1 V; P: the environment filtered by the combined kernels (R^T V)^T K at every
    texel of the map, with the same lights and the same kernels as the data, so the map is what the weights
    were fitted to (a mostly positive term normalized by its own discrete mass, a signed one by the
    reference's). ``masses`` given: V is their direction (rank 1, no data: the kernels of a layer whose lobe
    is at most half a texel differ only in mass)."""
    ref = kernels.sum(0, keepdims=True)
    if masses is not None:
        v = weights = (masses / np.linalg.norm(masses))[:, None]
        coef_v, energy = v, 0.0
    else:
        basis, coef = compress(kernels)
        d = min(size, data_size)
        pad = np.zeros(((-len(basis) - 1) % 8, basis.shape[1]))  # table counts in steps of 8: fewer XLA compilations
        tables = np.concatenate([basis, pad, ref])
        yb = filtered(tables, d, env, coarse, np.zeros(len(tables) - 1, bool))[:, :len(basis)]  # (T, J', 3)
        w = mappers.texel_solid_angles("cube", d).reshape(-1)
        mix = np.kron(np.asarray(MATERIALS, np.float64) / np.sqrt(len(MATERIALS)),
                      np.diag(np.sqrt(nv_measure(kn.nv_centres(len(kernels) // 2)))))
        gram = mix @ coef @ np.einsum("t,tic,tjc->ij", w, yb, yb) @ coef.T @ mix.T
        vals, vecs = np.linalg.eigh(0.5 * (gram + gram.T))
        v, energy = vecs[:, ::-1][:, :rank], float(np.sum(vals[::-1][:rank]))
        weights = np.linalg.solve(mix, v)
        if np.sum(weights[:, 0]) < 0:
            v[:, 0], weights[:, 0] = -v[:, 0], -weights[:, 0]
        coef_v = mix.T @ v
    kp = np.concatenate([coef_v.T @ kernels, ref])
    # a term whose kernel is mostly positive is normalized by its own discrete mass (a constant environment then
    # reads its mass exactly); a signed one (mass ~ 0) by the reference kernel's
    return v, weights, filtered(kp, size, env, coarse, np.ones(len(kp) - 1, bool)), energy


def _luminance_lights(env: Environment | None) -> tuple[Environment, Environment] | None:
    """The environment's luminance times l l^T as two 3-channel light lists, ``(l_x^2, l_y^2, l_z^2)`` and
    ``(l_x l_y, l_x l_z, l_y l_z)`` (the channels the tensor map's filter reads, :func:`harmonic_maps`)."""
    if env is None:
        return None
    d = np.asarray(env.directions, np.float64)
    lum = np.asarray(env.radiance, np.float64) @ np.asarray(LUMINANCE, np.float64)
    diag = lum[:, None] * d * d
    off = lum[:, None] * np.stack([d[:, 0] * d[:, 1], d[:, 0] * d[:, 2], d[:, 1] * d[:, 2]], -1)
    return tuple(Environment(env.directions, jnp.asarray(c, jnp.float32), env.solid_angle, env.info) for c in (diag, off))


def harmonic_maps(kernels: np.ndarray, ref: np.ndarray, size: int, env: Environment,
                  coarse: Environment | None) -> np.ndarray:
    """``(6 size^2, J, 5)``: the tensor maps M_j(a) of the second-harmonic kernels ``kernels`` (J, G) (k_2(gamma),
    :func:`~homofac.bake.kernels.harmonic_kernels`) of the environment's luminance at the texel centres a of a cube
    of face ``size``, stored as (M_xx, M_yy, M_xy, M_xz, M_yz) (M_zz = -M_xx - M_yy).

    With omega the light's azimuth about a from the unit tangent t (t perpendicular to a) and gamma its angle
    from a, cos(2 omega) sin^2(gamma) = 2 (l.t)^2 - sin^2(gamma), so
    sum_l Y(l) dw k_2(gamma) cos(2 omega) = t^T M(a) t with
    M(a) = P (2 A - B I) P,  A = sum_l Y(l) dw k~(gamma) l l^T,  B = tr A - a^T A a,  P = I - a a^T,
    k~ = k_2 / sin^2(gamma): six isotropic filters of the luminance times l_i l_j (the filter of
    :func:`filtered`, normalized by the reference kernel ``ref``'s discrete mass). M is symmetric, traceless and
    M a = 0 (5 numbers)."""
    gamma = 2.0 * np.arcsin(kn.q_grid(kernels.shape[-1]))
    s2 = np.sin(gamma) ** 2
    kt = np.where(s2 > 0, kernels / np.where(s2 > 0, s2, 1.0), 0.0)
    kt[:, 0] = kt[:, 1]  # the limit at the axis (k_2 ~ gamma^2 there)
    pad = np.zeros(((-len(kt) - 1) % 8, kt.shape[1]))
    tables = np.concatenate([kt, pad, ref[None]])
    own = np.zeros(len(tables) - 1, bool)
    fine, far = _luminance_lights(env), _luminance_lights(coarse)
    parts = [filtered(tables, size, fine[i], None if far is None else far[i], own)[:, :len(kt)] for i in range(2)]
    xx, yy, zz = parts[0][..., 0], parts[0][..., 1], parts[0][..., 2]
    xy, xz, yz = parts[1][..., 0], parts[1][..., 1], parts[1][..., 2]
    A = np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1), np.stack([xz, yz, zz], -1)], -1)  # (T, J, 3, 3)
    a = np.asarray(mappers.texel_directions("cube", size), np.float64).reshape(-1, 3)
    B = np.trace(A, axis1=-2, axis2=-1) - np.einsum("ti,tjik,tk->tj", a, A, a)
    proj = np.eye(3)[None] - a[:, :, None] * a[:, None, :]  # (T, 3, 3)
    M = np.einsum("tik,tjkl,tlm->tjim", proj, 2.0 * A, proj) - B[..., None, None] * proj[:, None]
    return np.stack([M[..., 0, 0], M[..., 1, 1], M[..., 0, 1], M[..., 0, 2], M[..., 1, 2]], -1)


#: The Frobenius inner product of two stored tensors (M_xx, M_yy, M_xy, M_xz, M_yz) (M_zz = -M_xx - M_yy): over
#: the unit tangents t, mean (t^T M t)^2 is proportional to it.
TENSOR_METRIC = np.array([[2.0, 1, 0, 0, 0], [1, 2, 0, 0, 0], [0, 0, 2, 0, 0], [0, 0, 0, 2, 0], [0, 0, 0, 0, 2]])


def harmonic_fit(kernels: np.ndarray, ref: np.ndarray, size: int, env: Environment, data_size: int = 32,
                 coarse: Environment | None = None, previous: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(v (2X,), weights (2X,) = (h_A(x_i)..., h_B(x_i)...), M (6 size^2, 5))`` of one layer's second harmonic:
    the rank-1 product M(a) (t^T M t) h(n.v) closest, in the materials' metric (:data:`MATERIALS`, as
    :func:`layer_fit`) and the sphere's measure, to the harmonic's data, the tensor maps of the rows of
    ``kernels`` (2X, G) (:func:`harmonic_maps`) at the texels of a cube of face min(size, data_size)
    (Eckart-Young; computed on :func:`compress`'s basis). The sign is the one closest to ``previous`` (the
    layer below's v): blending two layers then blends like harmonics."""
    basis, coef = compress(kernels)
    d = min(size, data_size)
    mb = harmonic_maps(basis, ref, d, env, coarse)  # (T, J', 5)
    w = mappers.texel_solid_angles("cube", d).reshape(-1)
    # sum_t w_t mb[t, i] . METRIC mb[t, j] as one (J', 5 T) @ (5 T, J') product (a 4-operand einsum loops over t i j a b)
    left = np.moveaxis(w[:, None, None] * mb, 1, 0).reshape(mb.shape[1], -1)
    gram_b = left @ np.moveaxis(mb @ TENSOR_METRIC, 1, 0).reshape(mb.shape[1], -1).T
    mix = np.kron(np.asarray(MATERIALS, np.float64) / np.sqrt(len(MATERIALS)), np.eye(len(kernels) // 2))
    gram = mix @ coef @ gram_b @ coef.T @ mix.T
    vals, vecs = np.linalg.eigh(0.5 * (gram + gram.T))
    v = vecs[:, -1]
    if (previous is not None and v @ previous < 0) or (previous is None and np.sum(np.linalg.solve(mix, v)) < 0):
        v = -v
    weights = np.linalg.solve(mix, v)
    m = harmonic_maps(((mix.T @ v) @ kernels)[None], ref, size, env, coarse)[:, 0]
    return v, weights, m


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
    """The orthogonal rotation R (K, K) that brings ``v`` closest to the previous layer's ``previous``
    (orthogonal Procrustes); the weights and maps rotated alike leave the products unchanged, and blending two
    layers then blends like terms."""
    if previous is None or v.shape[1] == 1:
        return np.eye(v.shape[1])
    a, _, bt = np.linalg.svd(v.T @ previous)
    return a @ bt


def bake(environment, options: BakeOptions | dict | None = None, **kwargs) -> Bake:
    """Bake ``environment`` (a lat-long EXR/HDR path, a cube map, a bundled name such as ``"forest"``, or an
    :class:`Environment`) for every glTF metallic-roughness material (see the module docstring). numpy's BLAS runs
    on one thread meanwhile (its problems are small: :mod:`homofac.blas`)."""
    with blas_threads(1):
        return _bake(environment, options, **kwargs)


def _bake(environment, options: BakeOptions | dict | None = None, **kwargs) -> Bake:
    """:func:`bake`'s work."""
    opts = options if isinstance(options, BakeOptions) else validate(BakeOptions, {**(options or {}), **kwargs}, "bake")
    clock = _Clock()
    clock("load")
    max_size = int(opts.max_size or source_size(environment))
    pl = make_plan(opts.preset, max_size=max_size, min_roughness=opts.min_roughness, nv_size=opts.nv_size,
                   diffuse_size=opts.diffuse_size, layers=opts.layers, terms=opts.terms, diffuse_basis=opts.diffuse,
                   harmonic=opts.harmonic, mixed=opts.mixed, later_face=opts.later_face,
                   shared_gain=opts.shared_gain, source_face=source_size(environment),
                   block_size=opts.block_size or (max_size if opts.max_size else None))  # max_size given: the largest face
    original = _Lights(environment)
    lights = _Lights(environment)
    roughness = pl.roughnesses()
    shared = [sharp(rho, pl.block) for rho in roughness]
    sizes = [layer_face(rho, max_size, pl.block) for rho in roughness]
    # the brightest compact source leaves the map before every filter (the sharp block's finer lights included)
    # and is shaded as a point light
    # (each next source from the map the previous ones left, while it holds MIN_SHARE of that map's power)
    # (each light one or two Gaussians, its core and halo: sources.core_and_halo)
    sources, share, taken = (), None, 0
    while opts.analytic_source and taken < MAX_SOURCES:
        found, s = lights.take_source(max(max_size, opts.data_resolution, MIN_LIGHTS),
                                      block_lights(pl.block) if any(shared) else None)
        share = s if share is None else share
        if not found:
            break
        sources, taken = sources + found, taken + 1
    # each core's width from its own texels against the source map's pixel (sources.core_factor), then a box blurred
    # by a Gaussian where it is wider than the source map's pixels (sources.box_widths)
    pixel = np.pi / (2 * source_size(environment))
    sources = with_boxes(with_cores(sources, pixel), pixel)
    x = kn.nv_centres(pl.nv_size)
    data_env = lights(opts.data_resolution)
    dirs = fibonacci(opts.samples)

    # diffuse: I_d ~ sum_d E_d(n) w_d(n.v)
    clock("diffuse")
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

    # specular layers
    P, W, shifts, previous = [None] * pl.layers, [None] * pl.layers, [0.0] * pl.layers, None
    H, Hw, previous_h = [None] * pl.layers, [np.zeros(2 * len(x))] * pl.layers, None
    # the sharp layers (lobe at most half a texel of the largest map) share one block, computed at the sharpest
    # (the environment at the block's detail, as a mip chain's level 0)
    order = ([0] if shared[0] else []) + [j for j in range(pl.layers) if not shared[j]]
    kept = pl.layer_terms()  # K, or K - 1 in a mixed plan's harmonic layers and the crossing
    for j in order:
        rho, s = roughness[j], sizes[j]
        env_j = lights(block_lights(s) if shared[j] else max(s, MIN_LIGHTS))
        clock("kernels")
        exact = kn.albedos(rho, x)
        best = None
        for cand in (0.0,) if shared[j] else shift_candidates(rho):
            clock("kernels")
            k_s, k_2 = kn.lobe_kernels(rho, x, shift=cand)
            k_c = kn.calibrate(k_s, exact).reshape(2 * len(x), -1)  # rows (A, x..), (B, x..)
            clock("maps")
            fit = layer_fit(kn.smooth(k_c, texel_radius(env_j)), s, env_j, kept[j], DATA_SIZE,
                            np.concatenate([exact[0], exact[1]]) if shared[j] else None,
                            coarse=None if shared[j] else lights(MIN_LIGHTS))
            if best is None or fit[3] > best[2][3]:
                best = (cand, k_c, fit, k_2)
        shift, _, (v, wt, p, _), _ = best
        if kept[j] < pl.terms:  # the K-th product's channels stay 0 (the harmonic's in a mixed plan)
            v, wt = (np.concatenate([a, np.zeros((len(a), pl.terms - kept[j]))], 1) for a in (v, wt))
            p = np.concatenate([p, np.zeros((len(p), pl.terms - kept[j], 3))], 1)
        clock("weights")
        rot = _align(v, previous) if kept[j] == pl.terms else np.eye(pl.terms)
        v, wt, p = v @ rot, wt @ rot, np.einsum("tkc,kl->tlc", p, rot)
        previous = v
        if shared[j]:
            # P_0 = Y v reads m.v under a constant environment (m the kernels' masses): layer i's weights are its
            # albedos over m.v, so P_0 w_i reads the albedos of layer i exactly; further terms 0
            m = np.concatenate([exact[0], exact[1]])
            scale = float(m @ v[:, 0])
            block = np.concatenate([p, np.zeros(p.shape[:1] + (pl.terms - 1, 3))], axis=1).reshape(s, 6 * s, pl.terms, 3).astype(np.float32)
            for i in (i for i in range(pl.layers) if shared[i]):
                a_i = (m if i == j else np.concatenate(kn.albedos(roughness[i], x))) / scale
                vi = np.zeros((2 * len(x), pl.terms))
                vi[:, 0] = a_i
                P[i], W[i], shifts[i] = block, vi, 0.0
            previous = None
            continue
        P[j] = p.reshape(s, 6 * s, pl.terms, 3).astype(np.float32)
        W[j], shifts[j] = wt, float(shift)
        if j in pl.harmonic_layers():
            clock("harmonic")
            k2 = best[3].reshape(2 * len(x), -1)  # the chosen shift's second harmonics (:func:`kn.lobe_kernels`)
            ref = kn.smooth(best[1], texel_radius(env_j)).sum(0)
            previous_h, Hw[j], m = harmonic_fit(k2, ref, s, env_j, DATA_SIZE, lights(MIN_LIGHTS), previous_h)
            H[j] = m.reshape(s, 6 * s, 5).astype(np.float32)
    clock("weights")
    W = [np.stack([v[: len(x)], v[len(x):]], axis=-1).reshape(len(x), 2 * pl.terms) for v in W]  # a_k, b_k interleaved
    w = np.stack(W)  # (L, X, 2K)
    wd = np.broadcast_to(vd[None], (pl.layers, len(x), pl.diffuse))
    hw = [np.stack([h[: len(x)], h[len(x):]], axis=-1) for h in Hw] if pl.harmonic else []  # h_A, h_B
    if pl.shared_gain:  # h_A alone: its gain scales I_B too
        hw = [h[:, :1] for h in hw]
    if pl.mixed and hw:  # h_A, h_B in a_K, b_K's channels of the harmonic layers (those are 0 there)
        w = w.copy()
        for j in pl.harmonic_layers():
            w[j, :, 2 * pl.terms - 2:] = hw[j]
    table = np.concatenate([w, wd] + ([np.stack(hw)] if hw and not pl.mixed else []), axis=-1).astype(np.float32)
    clock("sh9")
    sh = sh9(original(opts.data_resolution))  # the environment's irradiance, source included
    timings = clock.total()
    info = {"sh9": sh.document(), "source": str(getattr(environment, "info", {}).get("source", environment)) if isinstance(environment, Environment)
            else str(_path(environment)), "options": opts.model_dump(), "sizes": sizes,
            "data_resolution": int(data_env.info.get("resolution", 0)), "timings": timings,
            "analytic_source": {"share": share, "found": bool(sources), "count": len(sources), "lights": taken}}
    blocks = tuple(int(np.argmax(shared)) if shared[j] else j for j in range(pl.layers))
    return stored(Bake(pl, roughness, tuple(shifts), tuple(P), E, table, info,
                       sh=diffuse_sh9(E) if pl.diffuse_basis == "sh9" else None, blocks=blocks, sources=sources,
                       H=tuple(H) if pl.harmonic else ()))


def stored(fitted: Bake) -> Bake:
    """The fitted bake in the layout it is stored and read in (after the fit): each layer's tensor map
    (S, 6 S, 5) in the 3 channels of the face gauge (:func:`homofac.bake.gauge.face_gauge`), each specular map
    in its own atlas (:func:`map_layouts`)."""
    H = tuple(None if h is None else face_gauge(h, h.shape[0]) for h in fitted.H)
    layouts = map_layouts(fitted.plan, [int(p.shape[0]) for p in fitted.P], fitted.blocks or tuple(range(len(fitted.P))),
                          [sharp(r, fitted.plan.block) for r in fitted.roughness],
                          [h is not None for h in H] if H else [False] * len(fitted.P))
    return dataclasses.replace(fitted, H=H, layouts=layouts)


def map_layouts(pl: BakePlan, sizes, blocks, shared, harmonic) -> tuple[Atlas, ...]:
    """Each specular RGB map's atlas (:func:`homofac.bake.atlas.bottom_left`), its blocks sized by what the map
    holds in each layer (``sizes`` the layers' faces, ``blocks`` the layers' shared blocks, ``shared[j]`` whether
    layer j is in the sharp block, :func:`sharp`; ``harmonic[j]`` whether it has a tensor map):

    * map 0, P_1: the layer's face, the sharp layers one shared block;
    * map k >= 1, P_(k+1), in the layers that keep k + 1 products (:meth:`~homofac.bake.plan.BakePlan.layer_terms`;
      not the sharp block, whose further products are 0): the layer's face / ``pl.later_face``, at least
      :data:`MIN_SIZE` (the map box-averaged per face: docs/notes/bake.md, "Memory, sixteenth session");
    * the map holding the tensor (K, or K - 1 with ``mixed``), in the layers with one: the layer's face;
    * every other layer of a map reads 0 (the sharp layers' P_2.., the crossing, the layers without the
      harmonic): one block of zeros of face :data:`MIN_SIZE`, shared by all of them."""
    kept = pl.layer_terms()
    g = pl.terms - 1 if pl.mixed else pl.terms  # the map holding the tensor
    out = []
    for i in range(pl.maps):
        own, zero = [], None
        for j, s in enumerate(sizes):
            if i == 0:
                own.append((s, blocks[j]))
            elif i == g and harmonic[j]:
                own.append((s, j))
            elif i < pl.terms and kept[j] > i and not shared[j] and not (pl.mixed and harmonic[j]):
                own.append((min(s, max(MIN_SIZE, s // pl.later_face)), j))
            else:
                zero = j if zero is None else zero
                own.append((min(s, MIN_SIZE), zero))
        out.append(bottom_left([s for s, _ in own], [b for _, b in own]))
    return tuple(out)


__all__ = ["bake", "compress", "map_layouts", "stored", "fibonacci", "harmonic_fit", "harmonic_maps", "layer_face", "layer_fit", "layer_size", "sharp", "source_size"]
