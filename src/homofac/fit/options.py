"""Option models of the fit layer: sampling, solver and the factorization itself.

``hf.fit.factorize(target, "NR", texture_size=32, sampling={...}, solver={...})`` validates its keywords
with :class:`FitOptions`, the very model the YAML config's top level extends
(:class:`homofac.app.config.Config`), so a misspelt key or a bad value is refused with the same
one-line message from the Python API and from the CLI. Allowed names derive from the registries
(mappers, solvers).
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal, Optional

from pydantic import Field, model_validator

from .. import baselines
from ..options import Options
from ..param import mappers
from ..param import parametrizations as pz
from ..param import projections as pj
from . import solvers
from .structures import Structure

#: Direction mapper names, from the registry (the scalar ``line`` mapper is for 1D factors only).
MapperName = Literal[tuple(n for n, m in mappers.MAPPERS.items() if not m.scalar)]  # type: ignore[valid-type]
#: Everything ``parametrization`` may name: the registered parametrizations and the baselines.
ParametrizationName = Literal[tuple(pz.PARAMETRIZATIONS) + tuple(baselines.BASELINES)]  # type: ignore[valid-type]
#: Texture sizes accepted (a 1024 cube has 6.3M texels per texture: far beyond anything that finishes here).
MIN_TEXTURE_SIZE, MAX_TEXTURE_SIZE = 4, 1024


#: A finite scene coordinate (metres or any unit: only directions matter to the lighting).
Coordinate = Annotated[float, Field(ge=-1e6, le=1e6, allow_inf_nan=False)]
#: Largest camera image side, and most pixels of all cameras of a scene together.
MAX_CAMERA_SIDE, MAX_SCENE_PIXELS = 2048, 1 << 22
#: Most cameras of a scene.
MAX_CAMERAS = 16


class CameraOptions(Options):
    """One camera of ``sampling.kind: scene``: a pinhole at ``position`` looking at ``look_at``, ``up``
    the image's up direction (default +z, homofac's up; docs/conventions.md), ``fov`` the vertical
    field of view in degrees, ``width`` x ``height`` pixels (rays through the pixel centres)."""

    position: list[Coordinate] = Field(min_length=3, max_length=3)
    look_at: list[Coordinate] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3)
    up: list[Coordinate] = Field(default_factory=lambda: [0.0, 0.0, 1.0], min_length=3, max_length=3)
    fov: float = Field(40.0, gt=1, lt=170)
    width: int = Field(160, ge=1, le=MAX_CAMERA_SIDE)
    height: int = Field(120, ge=1, le=MAX_CAMERA_SIDE)

    @model_validator(mode="after")
    def _frame(self):
        f = [a - b for a, b in zip(self.look_at, self.position)]
        nf = sum(x * x for x in f) ** 0.5
        if nf < 1e-9:
            raise ValueError("camera look_at equals its position")
        u = self.up
        nu = sum(x * x for x in u) ** 0.5
        c = [f[1] * u[2] - f[2] * u[1], f[2] * u[0] - f[0] * u[2], f[0] * u[1] - f[1] * u[0]]
        if nu < 1e-9 or sum(x * x for x in c) ** 0.5 < 1e-6 * nf * nu:
            raise ValueError("camera up is zero or parallel to the view direction")
        return self


#: Validation pairs where ``sampling.validation`` is not given (and not the quality mode's).
DEFAULT_VALIDATION = 20_000


class SamplingOptions(Options):
    """``sampling``: the training pairs (thesis §4.2) and the seeded validation set.

    ``kind``: ``texels`` (reverse-projected texel grids of ``mapper``, default parabolic for BRDFs and
    dual_paraboloid for lighting, of ``size`` and ``view_size``), ``latlong`` (a lat-long grid),
    ``random`` (``count`` uniform pairs) or ``grid`` (lighting: ``count`` pairs, default 300000, 600000 for a
    the preset's where it sets one (:func:`homofac.fit.plan.grid_count`), of texel
    centres (n, r) of the fitted textures' own grid, drawn by solid angle, so alternating least squares
    decouples per texel; :func:`homofac.fit.sampling.grouped_grid`). ``auto`` (the default) is ``grid``
    for linear-space sums of lighting products and ``texels`` otherwise. ``validation``: the number of
    random validation pairs (seed ``seed + 1``; not given: :data:`DEFAULT_VALIDATION`, 80000 for a
    the preset's where it sets one, :func:`homofac.fit.plan.validation_count`; a recorded config keeps it
    unset, so a refit from disk draws what the fit drew). ``cache``: reuse the samples of an identical (target,
    sampling) from disk.

    ``scene`` (lighting): the (n, v) pairs that ``cameras`` see of the mesh ``mesh`` (an OBJ, glTF/GLB
    or PLY file, or a bundled scene name such as ``demo``, whose cameras are the default), drawn
    uniformly over all covered pixels (``count`` of them, default every covered pixel once; the
    validation pairs likewise with seed ``seed + 1``); the result's metrics gain ``scene``, the
    image-space error over every covered pixel (:mod:`homofac.fit.scene`). ``mesh_up``: the mesh
    file's up axis (``y`` for glTF's convention; turned into homofac's +z).
    """

    kind: Literal["auto", "texels", "latlong", "random", "grid", "scene"] = "auto"
    size: int = Field(24, ge=2, le=512)
    view_size: Optional[int] = Field(None, ge=2, le=512)
    validation: Optional[int] = Field(None, ge=0, le=10_000_000)
    seed: int = Field(0, ge=0, le=2**31 - 2)
    count: int = Field(0, ge=0, le=100_000_000)
    mapper: Optional[MapperName] = None
    cache: bool = True
    mesh: Optional[str] = Field(None, min_length=1, max_length=4096)
    mesh_up: Literal["z", "y"] = "z"
    cameras: Optional[list[CameraOptions]] = Field(None, min_length=1, max_length=MAX_CAMERAS)

    @model_validator(mode="after")
    def _scene(self):
        if self.kind != "scene":
            if self.mesh is not None or self.cameras is not None:
                raise ValueError("mesh and cameras are for kind: scene")
            return self
        if self.mesh is None:
            raise ValueError("kind: scene needs a mesh (a file or a bundled scene name such as demo)")
        pixels = sum(c.width * c.height for c in self.cameras or ())
        if pixels > MAX_SCENE_PIXELS:
            raise ValueError(f"the cameras have {pixels} pixels together, more than {MAX_SCENE_PIXELS}")
        return self


class AnalysisOptions(Options):
    """``analysis``: Mahajan et al. 2008's in-out analysis of the target (homofac.baselines.svd), recorded
    beside the result: the rank-K error curve of the target gridded on (n, r) or (n, v)."""

    pair: Literal["nr", "nv"] = "nr"
    mapper: Literal["dual_paraboloid", "cube", "octahedral"] = "dual_paraboloid"
    size: int = Field(12, ge=4, le=32)


class LinearOptions(Options):
    """``linear``: the linear-space fit of sums of products (:mod:`homofac.fit.sums`), the objective a GPU
    sees: ``sum_i ||(model(a_i, b_i) - y_i) / sigma||^2`` plus first-difference smoothing of every texture.

    ``method``: ``als`` (exact block alternating least squares on ``grid`` samples, per-texel K x K
    solves; :mod:`homofac.fit.als`), ``levenberg_marquardt`` / ``gauss_newton`` (matrix-free, LSMR
    inner solves, any parametrization and sampling; :mod:`homofac.fit.refine`), or ``auto`` (als when
    the samples are grid-aligned, else levenberg_marquardt). ``backend``: ``optimistix`` (core) or
    ``jaxopt`` (the optional extra ``homofac[jaxopt]``; unmaintained upstream, for comparisons).
    ``iterations``: ALS sweeps or outer LM / GN steps; ``inner_iterations``: LSMR steps per LM / GN step.
    ``tolerance``: ALS stops when a sweep lowers the objective by less than this fraction of it
    (converged; 0: always run ``iterations`` sweeps; None: the preset's, else :data:`DEFAULT_TOLERANCE`);
    the solver record holds the sweeps run and whether it converged, and a long fit logs its progress
    every few seconds.
    ``laplacian``: the smoothing weight lambda, scaled by samples per texel (mu = lambda N / texels).
    ``start``: ``split_sum`` (term 1 = the split sum; microfacet lighting targets), ``product`` (term 1
    = the log-space product of the parametrization) or ``auto`` (split_sum where it exists).
    ``nv_balance``: beta of the sample weights ``(mean of y^2 over the sample's n.v bin)^-beta``
    (8 bins of equal width, weights scaled to mean 1): 0 is the plain objective, where the bright
    grazing views dominate; 1 makes every bin's relative error count by its sample count
    (:func:`homofac.fit.sums.nv_weights`); when the structure is chosen (``max_lookups``,
    ``target_error``) for a lighting target of a BRDF with kd > 0 and ``nv_balance`` is not given, the
    candidates are fitted with the preset's (:data:`homofac.fit.plan.PRESETS`; None: the preset's, else 0). ``polish`` (after
    ``als``): that many Levenberg-Marquardt steps on the grid pairs and texel-sampled pairs at
    ``polish_size`` between the texel centres the grid design sees (:mod:`homofac.fit.polish`); 0 (the
    default) is off. When the structure is chosen and
    ``polish`` is not given, the candidates are ranked on their ALS fits and the kept one is then
    polished with the preset's steps (:mod:`homofac.fit.plan`; ``selection.polish`` records
    the validation error before and after); given, every candidate is polished that much (0: none).
    ``ridge``: that many more pairs in the polish, drawn on the grazing ridge of the brightest light(s)
    with weights that keep the objective that of uniform pairs (:mod:`homofac.fit.ridge`); 0 is off; in
    the ``best`` preset the chooser's polish draws its ridge pairs when it is
    not given (:data:`homofac.fit.plan.PRESETS`). It needs the plain objective
    (``nv_balance`` 0) and a polish.
    ``highlight_start``: ALS sweeps of the highlight terms' own start (fitted first on the data alone, the
    products masked out; :func:`homofac.fit.sums.begin`), at most ``iterations // 2``; None: the preset's,
    else ``iterations // 2``.
    """

    method: Literal["auto", "als", "levenberg_marquardt", "gauss_newton"] = "auto"
    backend: Literal["optimistix", "jaxopt"] = "optimistix"
    iterations: int = Field(30, ge=1, le=100_000)
    inner_iterations: int = Field(100, ge=1, le=100_000)
    laplacian: float = Field(1e-2, ge=0, allow_inf_nan=False)
    start: Literal["auto", "split_sum", "product"] = "auto"
    nv_balance: Optional[float] = Field(None, ge=0, le=1, allow_inf_nan=False)
    polish: Optional[int] = Field(None, ge=0, le=1000)
    polish_size: int = Field(24, ge=4, le=256)
    ridge: Optional[int] = Field(None, ge=0, le=1_000_000)
    tolerance: Optional[float] = Field(None, ge=0, le=1, allow_inf_nan=False)
    highlight_start: Optional[int] = Field(None, ge=1, le=100_000)

    @model_validator(mode="after")
    def _ridge_objective(self):
        if (self.ridge or 0) > 0 and (self.nv_balance or 0) > 0:
            raise ValueError(RIDGE_NEEDS_PLAIN)
        return self

    def resolved(self, **preset) -> "LinearOptions":
        """These options with every value left unset (None) taken from ``preset`` (a preset's values,
        :mod:`homofac.fit.plan`), else 0: the options a fit runs with."""
        update = {k: preset.get(k, 0) for k in ("nv_balance", "polish", "ridge") if getattr(self, k) is None}
        if "nv_balance" in update:
            update["nv_balance"] = float(update["nv_balance"])
        if self.tolerance is None:
            update["tolerance"] = float(preset.get("tolerance", DEFAULT_TOLERANCE))
        if self.highlight_start is None and preset.get("highlight_start"):
            update["highlight_start"] = int(preset["highlight_start"])
        return self.model_copy(update=update) if update else self


#: ``linear.tolerance`` where neither the options nor a preset give one.
DEFAULT_TOLERANCE = 1e-5

#: Why ``linear.ridge`` with ``linear.nv_balance`` is refused.
RIDGE_NEEDS_PLAIN = ("ridge weighs its pairs as a share of uniform pairs, which the n.v-bin weights of "
                     "nv_balance would change: set one of them")


#: The presets (``preset``, pinned names): lookup budgets 4, 8 and 16 with their sample counts and votes
#: (:data:`homofac.fit.plan.PRESETS`).
PresetName = Literal["fast", "balanced", "best"]

#: The preset of a config or call that names none and no fit (:func:`names_a_fit`).
DEFAULT_PRESET = "balanced"

#: Top-level keys that name what to fit (a parametrization, a structure, a budget, an error goal): given
#: any of them (or an ``advanced`` key of :data:`ADVANCED_NAMING_KEYS`) without ``preset``, no preset
#: applies (``parametrization: NR`` alone is the single product).
NAMING_KEYS = ("parametrization", "target_error", "terms", "diffuse", "nv_factor", "max_lookups")
#: The ``advanced`` keys that name a fit in the same way.
ADVANCED_NAMING_KEYS = ("reflection", "prefiltered", "rw_terms", "highlights", "line_size", "linear", "baseline")

#: Largest number of fitted terms accepted (the packed shaders and the ALS blocks grow as K^2).
MAX_TERMS = 32


class HighlightOptions(Options):
    """``advanced.highlights``: the highlight terms of the structure (:class:`homofac.fit.structures.Highlights`):
    ``terms`` J fitted terms d(nh_dom) w(n.v), the highlights of the J brightest lights (at most one per
    highlight projection, ``projections.HIGHLIGHTS``; when the structure is chosen, J restricts the
    candidates to that count and 0 turns the highlight candidates off); each term also reads a ``line``
    texture f(v.h') of its light's Fresnel argument (``fresnel``) or c(n.i) of its light's cosine
    (``cosine``: the shadowing G1(n.i) and the light's horizon), one lookup more each; ``table``: a 2D
    ``parabolic`` table T(n.i, n.v) in place of c(n.i) w(n.v), one lookup fewer (:mod:`homofac.fit.table`);
    ``disc``: its light's coordinate at the point of the light's disc closest to r (``nhs_dom``: the sun at
    grazing views). ``null`` (the default) is the preset's: off for a named structure, the chooser's
    candidates and votes otherwise (:mod:`homofac.fit.plan`)."""

    terms: Optional[int] = Field(None, ge=0, le=len(pj.HIGHLIGHTS))
    fresnel: Optional[bool] = None
    cosine: Optional[bool] = None
    table: Optional[bool] = None
    disc: Optional[bool] = None


class AdvancedOptions(Options):
    """``advanced``: the research keys (a preset sets what they decide; docs/config.md,
    "`advanced`: the research keys").

    The rest of a structure (:class:`homofac.fit.structures.Structure`) beside the top-level ``terms``,
    ``diffuse`` and ``nv_factor``: ``reflection`` (lighting: one more fitted term, an r-only texture),
    ``prefiltered`` (lighting: the split sum's P(r) W(n.v) computed and kept; the products fit
    corrections to it), ``rw_terms`` (lighting: J more fitted terms q(r) w(n.v), without a normal
    texture, beside the K products), ``highlights`` (:class:`HighlightOptions`). ``line_size``: texels of
    a sum's ``line`` textures (w(n.v) and the highlight lines; default 32, or the preset's line vote:
    :func:`homofac.fit.plan.line_sizes`); a single log-space product's scalar factor has ``texture_size``
    texels. ``linear``: the linear-space fit of sums (:class:`LinearOptions`). ``baseline``: options of a
    baseline ``parametrization`` (validated by the baseline's option model). ``analysis``: record
    Mahajan's in-out analysis of the target (:class:`AnalysisOptions`). ``validation_light``: the light
    resolution the validation pairs of a choosing fit read (default: decided from the environment by
    doubling until converged, :mod:`homofac.fit.validation`; the fit's own resolution reads the votes
    against the fit's lighting)."""

    reflection: bool = False
    prefiltered: bool = False
    rw_terms: int = Field(0, ge=0, le=MAX_TERMS)
    highlights: HighlightOptions = Field(default_factory=HighlightOptions)
    line_size: Optional[int] = Field(None, ge=2, le=4096)
    linear: Optional[LinearOptions] = None
    baseline: Optional[dict] = None  # validated by the chosen baseline's option model (homofac.baselines)
    analysis: Optional[AnalysisOptions] = None
    validation_light: Optional[int] = Field(None, ge=1, le=1024)


#: Keys of earlier configs (and keywords of ``factorize``) that live under ``advanced`` now: key -> its
#: place. A config or call giving one at the top level is refused in one line naming the place
#: (:func:`homofac.options.format_error`); a recorded config of an earlier run is read through
#: :func:`upgrade_record`.
MOVED_KEYS = {
    "reflection": "advanced.reflection", "prefiltered": "advanced.prefiltered", "rw_terms": "advanced.rw_terms",
    **{f"highlight_{k}": f"advanced.highlights.{k}" for k in HighlightOptions.model_fields},
    "line_size": "advanced.line_size", "linear": "advanced.linear", "baseline": "advanced.baseline",
    "analysis": "advanced.analysis",
}


def _given(key: str, value) -> bool:
    """Whether an ``advanced`` key is given: not None (``highlights``: one of its keys not None)."""
    if key == "highlights" and isinstance(value, (dict, Options)):
        items = value.model_dump().values() if isinstance(value, Options) else value.values()
        return any(v is not None for v in items)
    return value is not None


def names_a_fit(data: dict) -> bool:
    """Whether the raw keys ``data`` (a config's top level, ``factorize``'s keywords) name what to fit:
    any of :data:`NAMING_KEYS`, or of :data:`ADVANCED_NAMING_KEYS` under ``advanced`` (a model given
    as ``advanced`` names what differs from its defaults)."""
    adv = data.get("advanced")
    if isinstance(adv, Options):
        adv = adv.model_dump(exclude_defaults=True)
    adv = adv if isinstance(adv, dict) else {}
    return (any(data.get(k) is not None for k in NAMING_KEYS)
            or any(_given(k, adv.get(k)) for k in ADVANCED_NAMING_KEYS))


def upgrade_record(config: dict) -> dict:
    """A config recorded by an earlier run (factorization.json's ``config``, index.json's) in today's
    layout: the keys of :data:`MOVED_KEYS` moved from the top level under ``advanced`` (``None`` values
    dropped); a config already in today's layout is returned as it is."""
    moved = [k for k in MOVED_KEYS if k in config]
    if not moved:
        return config
    out = {k: v for k, v in config.items() if k not in MOVED_KEYS}
    adv = dict(out.get("advanced") or {})
    for key in moved:
        value = config[key]
        if value is None:
            continue
        *path, leaf = MOVED_KEYS[key].split(".")[1:]
        node = adv
        for part in path:
            node = node.setdefault(part, {})
        node[leaf] = value
    out["advanced"] = adv
    return out


def recorded_fit_options(config: dict) -> dict:
    """The keywords of :func:`homofac.fit.factorize` a recorded config holds (:func:`upgrade_record`)."""
    return {k: v for k, v in upgrade_record(dict(config)).items() if k in FitOptions.model_fields}


class FitOptions(Options):
    """What :func:`homofac.fit.factorize` takes besides the target (and the config's top level).

    ``preset``: ``fast``, ``balanced`` or ``best`` (4, 8, 16 lookups; docs/presets.md): the plan's sample
    counts, candidates, linear-fit options and votes (:mod:`homofac.fit.plan`), each replaced by the key
    of the same meaning where given. Neither a preset nor a key that names a fit (:func:`names_a_fit`):
    ``balanced``.

    ``parametrization``: a registered parametrization of the target's kind (``IV``, ``GSHD``, ``PQP`` for
    BRDFs; ``N``, ``R``, ``NR``, ``NRV``, ``NRHD``, ``NRW``, ``NRO``, ``RO`` for lighting), or a baseline (``split_sum``,
    ``kautz_mccool``; options in ``advanced.baseline``). ``mapper``: of the direction textures (default
    parabolic for BRDFs, dual_paraboloid for lighting). ``texture_size``: S of the mapper.
    ``target_error``: the validation nrmse to meet (fit/auto.py picks the cheapest candidate).

    Sums of products (schema 2, docs/format.md), fitted in linear space: ``terms`` K products of the
    parametrization, ``diffuse`` ``exact`` (the computed term kd/pi E(n); the products fit the rest) or
    ``fitted`` (an n-only texture started from it), ``nv_factor`` (a 1D ``line`` texture w(n.v) in each
    product; for BRDFs w(cos_i) w(cos_o)), ``max_lookups`` (homofac chooses the structure within that many
    texture lookups per pixel, by validation error; :mod:`homofac.fit.structures`). The rest of a
    structure and the research keys are under ``advanced`` (:class:`AdvancedOptions`); the keys of
    :data:`MOVED_KEYS` at the top level are refused with their place.
    """

    MOVED: ClassVar[dict[str, str]] = MOVED_KEYS

    preset: Optional[PresetName] = None
    parametrization: ParametrizationName = "NR"
    mapper: Optional[MapperName] = None
    texture_size: int = Field(32, ge=MIN_TEXTURE_SIZE, le=MAX_TEXTURE_SIZE)
    target_error: Optional[float] = Field(None, gt=0, lt=10)
    max_lookups: Optional[int] = Field(None, ge=1, le=256)
    terms: int = Field(1, ge=1, le=MAX_TERMS)
    diffuse: Optional[Literal["exact", "fitted"]] = None
    nv_factor: bool = False
    sampling: SamplingOptions = Field(default_factory=SamplingOptions)
    solver: solvers.options_type() = Field(default_factory=lambda: solvers.options())  # type: ignore[valid-type]
    advanced: AdvancedOptions = Field(default_factory=AdvancedOptions)

    @model_validator(mode="before")
    @classmethod
    def _default_preset(cls, data):
        """No preset and no key that names a fit (:func:`names_a_fit`): the preset :data:`DEFAULT_PRESET`.
        So ``parametrization: NR`` alone stays the single product."""
        if isinstance(data, dict) and data.get("preset") is None and not names_a_fit(data):
            return {**data, "preset": DEFAULT_PRESET}
        return data

    @property
    def is_sum(self) -> bool:
        """True when the fit is a linear-space sum of products rather than today's log-space product."""
        a, h = self.advanced, self.advanced.highlights
        return (self.terms > 1 or self.diffuse is not None or self.nv_factor or a.reflection or a.rw_terms > 0
                or bool(h.terms) or bool(h.fresnel) or bool(h.cosine) or bool(h.table) or bool(h.disc)
                or a.prefiltered or self.max_lookups is not None or a.linear is not None or self.preset is not None)

    def structure(self, parametrization: str | None = None) -> Structure:
        """The one structure these options name (``parametrization`` in place of theirs where given): the
        top-level ``terms``, ``diffuse``, ``nv_factor`` and the rest from ``advanced`` (a highlight key
        not given is off)."""
        a = self.advanced
        h = {k: v for k, v in a.highlights.model_dump().items() if v is not None}
        return Structure.of({"parametrization": parametrization or self.parametrization, "terms": self.terms,
                             "diffuse": self.diffuse, "nv_factor": self.nv_factor, "reflection": a.reflection,
                             "prefiltered": a.prefiltered, "rw_terms": a.rw_terms, "highlights": h})


__all__ = ["ADVANCED_NAMING_KEYS", "DEFAULT_PRESET", "MOVED_KEYS", "NAMING_KEYS", "PresetName", "AdvancedOptions",
           "AnalysisOptions", "CameraOptions", "DEFAULT_VALIDATION", "HighlightOptions", "MAX_CAMERAS",
           "MAX_CAMERA_SIDE", "MAX_SCENE_PIXELS", "FitOptions", "LinearOptions", "MAX_TERMS", "MAX_TEXTURE_SIZE",
           "MIN_TEXTURE_SIZE", "MapperName", "SamplingOptions", "names_a_fit", "recorded_fit_options",
           "upgrade_record"]
