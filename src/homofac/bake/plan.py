"""The bake's plan: what a preset means, in one place (a small frozen, printable record).

A bake approximates the three integrals of :mod:`homofac.light.integrals` by

    I_d(n, v)     ~ sum_{d < D} E_d(n) w_d(n.v)
    I_A(n, v, r)  ~ sum_{k < K} P_k(r, rho) a_k(n.v, rho)      I_B ~ sum_k P_k(r, rho) b_k(n.v, rho)

with E_d cube maps, P_k cube maps in roughness layers and the weights a_k, b_k, w_d in RGB tables over
(n.v, layer). Lookups per pixel (the pinned count): one per E_d, two per P_k (the two layers around rho,
blended by hand), one per RGB weight table.
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

from ..errors import HomofacError

PRESETS = ("fast", "balanced", "best")
Preset = Literal["fast", "balanced", "best"]


class BakePlan(NamedTuple):
    """What a bake computes: ``terms`` K products P_k W_k for I_A, I_B; ``diffuse`` D products for I_d
    (``diffuse_basis``: E_d as cube textures, ``texture``, or as their 9 SH coefficients, ``sh9``);
    ``layers`` roughness layers spaced geometrically from ``min_roughness`` to 1; ``nv_size`` columns of
    the weight tables; ``max_size`` the largest P face size of the layers with their own maps (and the sharp
    layers' criterion, :func:`homofac.bake.build.sharp`); ``block_size`` the face of the sharp layers' shared
    block (:func:`block_face`; 0: ``max_size``, bakes of schema 7 and older); ``diffuse_size`` the
    face size of the E_d maps; ``later_face``: P_2..P_K are stored at 1 / later_face of their layer's face (at
    least 8; the layer's map box-averaged per face, :func:`homofac.bake.build.map_layouts`); ``shared_gain``: the
    harmonic's one weight h_A scales I_A and I_B by the same gain (one table channel instead of h_A, h_B)."""

    preset: str
    terms: int
    diffuse: int
    layers: int
    nv_size: int
    max_size: int
    diffuse_size: int
    min_roughness: float
    diffuse_basis: str = "texture"
    harmonic: float = 0.0
    mixed: bool = False
    later_face: int = 1
    shared_gain: bool = False
    block_size: int = 0

    @property
    def block(self) -> int:
        """The sharp block's face: ``block_size``, or ``max_size`` when it is 0 (schema 7 and older)."""
        return self.block_size or self.max_size

    @property
    def channels(self) -> int:
        """Weight-table channels: a_1, b_1, ..., a_K, b_K, w_1, ..., w_D (and h_A, h_B with the harmonic, unless
        ``mixed``: then h_A, h_B are a_K, b_K's channels in the harmonic layers; ``shared_gain``: h_A only)."""
        return 2 * self.terms + self.diffuse + ((1 if self.shared_gain else 2) if self.harmonic and not self.mixed else 0)

    @property
    def harmonic_channel(self) -> int:
        """The table channel of h_A (h_B the next, none with ``shared_gain``): 2K + D, or with ``mixed`` 2K - 2 (a_K's)."""
        return 2 * self.terms - 2 if self.mixed else 2 * self.terms + self.diffuse

    def layer_terms(self) -> tuple[int, ...]:
        """The products each layer stores: K, or with ``mixed`` K - 1 in the layers from the harmonic's roughness
        up (the harmonic takes the K-th product's channels) and in the last layer below them (the crossing: the
        bilinear table then never blends a_K with h_A, each layer's channels keep one meaning)."""
        h = self.harmonic_layers()
        first = min(h) if h else self.layers
        return tuple(self.terms - 1 if self.mixed and h and j >= first - 1 else self.terms for j in range(self.layers))

    def harmonic_layers(self) -> tuple[int, ...]:
        """The layers that store the second harmonic: those with roughness >= ``harmonic`` (none if it is 0)."""
        if not self.harmonic:
            return ()
        return tuple(j for j, r in enumerate(self.roughnesses()) if r >= self.harmonic)

    @property
    def tables(self) -> int:
        """RGB weight tables: the :attr:`channels`, three per table."""
        return math.ceil(self.channels / 3)

    @property
    def maps(self) -> int:
        """Specular RGB textures per layer: the K maps P_k; with the harmonic one more, the tensor map's 3
        face-gauge channels (:mod:`homofac.bake.gauge`); ``mixed``: K (the last map holds P_K's RGB below the
        harmonic layers and the tensor's 3 channels in them)."""
        return self.terms + (1 if self.harmonic and not self.mixed else 0)

    @property
    def lookups(self) -> int:
        """Texture fetches per pixel: D (E_d; none with ``diffuse_basis`` sh9) + 2 x the specular maps (two layers
        blended by hand) + the tables."""
        return (self.diffuse if self.diffuse_basis == "texture" else 0) + 2 * self.maps + self.tables

    @staticmethod
    def _span(js) -> str:
        return f"{js[0]}-{js[-1]}" if len(js) > 1 else str(js[0])

    def _later(self) -> str:
        if self.terms < 2 or self.later_face < 2:
            return ""
        return f"P_2{f'..P_{self.terms}' if self.terms > 2 else ''} at 1/{self.later_face} of the face; "

    def roughnesses(self) -> tuple[float, ...]:
        """The layers' roughnesses: min_roughness (1/min_roughness)^(j/(layers-1)) (lobe width alpha = rho^2
        grows by the same factor from layer to layer)."""
        r0, n = self.min_roughness, self.layers
        return tuple(float(r0 * (1.0 / r0) ** (j / (n - 1))) for j in range(n))

    def describe(self) -> str:
        """One printable line."""
        return (f"bake plan {self.preset}: {self.terms} specular term(s) x {self.layers} roughness layers "
                f"({self.min_roughness:g}..1), {self.diffuse} diffuse term(s), {self.tables} weight table(s) of "
                f"{self.nv_size} n.v columns; P up to {self.max_size}^2 x 6 (the sharp block {self.block}^2 x 6), E {self.diffuse_size}^2 x 6"
                f"{' as SH9 constants' if self.diffuse_basis == 'sh9' else ''}; "
                f"{f'second harmonic from roughness {self.harmonic:g}; ' if self.harmonic else ''}"
                f"{self._later()}"
                f"{'one harmonic gain for I_A and I_B; ' if self.shared_gain and self.harmonic else ''}"
                f"{f'mixed: {self.terms - 1} term(s) + the harmonic in layers {self._span(self.harmonic_layers())}, {self.terms - 1} term(s) in the crossing layer {min(self.harmonic_layers()) - 1}; ' if self.mixed and self.harmonic_layers() else ''}"
                f"{self.lookups} lookups per pixel")


#: preset -> (terms, diffuse, layers): 4, 8 and 16 lookups (budgets 4, 8, 16).
_STRUCTURE = {"fast": (1, 1, 10), "balanced": (2, 1, 12), "best": (5, 2, 12)}

#: preset -> the roughness from which layers store the second harmonic (0: none).
_HARMONIC = {"fast": 0.0, "balanced": 0.35, "best": 0.0}

#: preset -> whether the harmonic layers replace the K-th product (``mixed``, :meth:`BakePlan.layer_terms`).
_MIXED = {"fast": False, "balanced": False, "best": False}

#: preset -> whether the harmonic layers' I_B takes I_A's harmonic gain (one table channel h_A, no h_B).
#: balanced: with E_d as SH9 and K = 2 kept in the harmonic layers, 0 + 3 maps x 2 + 2 tables = 8 lookups
#: (docs/notes/bake.md, "From 0.3 up, nineteenth session").
_SHARED_GAIN = {"fast": False, "balanced": True, "best": False}

#: preset -> the diffuse maps' basis (balanced: ``sh9``, 0 lookups, which pays the harmonic's tensor map).
_DIFFUSE_BASIS = {"fast": "texture", "balanced": "sh9", "best": "texture"}

#: preset -> the face size of the E_d maps (balanced: 16, every accuracy cell within 0.0001 of 32's;
#: docs/notes/bake.md, "Memory, sixteenth session").
_DIFFUSE_SIZE = {"fast": 32, "balanced": 16, "best": 32}

#: preset -> P_2..P_K's face divisor (balanced: P_2 at half its layer's face, docs/notes/bake.md "Memory,
#: seventeenth session"; best: not measured, 1).
_LATER_FACE = {"fast": 1, "balanced": 2, "best": 1}


#: Largest face of the sharp block (:func:`block_face`): a 256 face is 1.2 M half-float bytes per map, and its
#: lights (:func:`homofac.bake.build.block_lights`) at most 256 as well.
BLOCK_MAX = 256


#: preset -> the sharp block's face in units of the source's (:func:`block_face`): 1 for every preset. At 2
#: ``balanced`` reads forest < 0.15 at 0.84x the ideal split-sum instead of 0.93x and studio 1.31x instead of 1.48x,
#: within its memory rule (0.89x), but bakes in twice the CPU (2.8-2.9x the sampler's, the goal 2x) and city /
#: interior < 0.15 read 5-11 % worse; ``fast`` at 2 holds 2.18x split-sum's memory at the same sharpness
#: (docs/notes/bake.md, "Forest below 0.15, twenty-first session"). ``block_size`` sets it per bake.
_BLOCK_FACTOR = {"fast": 1, "balanced": 1, "best": 1}


def block_face(source_face: int, min_roughness: float, factor: int = 2) -> int:
    """The sharp block's face for a source whose cube face holds its detail at ``source_face`` (a lat-long of
    width 4 ``source_face``; :func:`homofac.bake.build.source_size`): ``factor`` ``source_face``; at 2 a texel half the source's
    pixel, so that the block's bilinear read reproduces the source's own bilinear image (what the sharp lobes
    see: at roughness 0.045 the lobe, alpha = rho^2 = 0.002 rad, is a tenth of a 256-wide lat-long's pixel);
    no finer than the sharpest lobe asks (pi / alpha, as a layer's face) and at most :data:`BLOCK_MAX`.
    (docs/notes/bake.md, "Forest below 0.15, twenty-first session": forest < 0.15, balanced, 64 -> 128:
    0.1183 -> 0.1063 nrmse, converged.)"""
    lobe = 2 ** int(round(math.log2(math.pi / (min_roughness * min_roughness))))
    return int(min(BLOCK_MAX, factor * source_face, lobe))


def plan(preset: str = "balanced", *, max_size: int = 256, min_roughness: float = 0.045, nv_size: int = 32,
         diffuse_size: int | None = None, layers: int | None = None, terms: int | None = None,
         diffuse_basis: str | None = None, harmonic: float | None = None,
         mixed: bool | None = None, later_face: int | None = None, shared_gain: bool | None = None,
         block_size: int | None = None, source_face: int | None = None) -> BakePlan:
    """The plan of a preset, with the given overrides (validated by :class:`homofac.bake.BakeOptions`); the
    sharp block's face ``block_size`` by default :func:`block_face` of ``source_face`` (default ``max_size``) at the
    preset's factor, at least ``max_size``."""
    k, d, n = _STRUCTURE[preset]
    if mixed and int(terms or k) < 2:
        raise HomofacError("bake: mixed needs at least 2 specular terms (the harmonic layers keep K - 1)")
    h = float(_HARMONIC[preset] if harmonic is None else harmonic)
    mixed = bool(_MIXED[preset] and int(terms or k) >= 2) if mixed is None else mixed
    mixed = bool(mixed and h > 0)  # without a harmonic nothing is mixed
    if shared_gain and mixed:
        raise HomofacError("bake: shared_gain needs the unpacked harmonic (mixed stores h_A, h_B in a_K, b_K's channels)")
    shared = bool(_SHARED_GAIN[preset] if shared_gain is None else shared_gain) and h > 0 and not mixed
    return BakePlan(preset, int(terms or k), d, int(layers or n), int(nv_size), int(max_size),
                    int(diffuse_size or _DIFFUSE_SIZE[preset]), float(min_roughness),
                    str(diffuse_basis or _DIFFUSE_BASIS[preset]), h, mixed, int(later_face or _LATER_FACE[preset]),
                    shared, int(block_size or max(max_size, block_face(source_face or max_size, min_roughness, _BLOCK_FACTOR[preset]))))


__all__ = ["BLOCK_MAX", "BakePlan", "PRESETS", "Preset", "block_face", "plan"]
