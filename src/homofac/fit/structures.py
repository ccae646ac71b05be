"""The structure of a sum of products: which terms, factors and textures (docs/format.md, schema 2).

A :class:`Structure` is one nested model of a sum: the pinned config keys (``terms: K``, ``diffuse: exact |
fitted``, ``nv_factor``) over a parametrization (the product each fitted term repeats), the extra terms
(``reflection``, ``prefiltered``, ``rw_terms``) and the highlight terms as a sub-model
(:class:`Highlights`: ``highlights.terms``, ``.fresnel``, ``.cosine``, ``.table``, ``.disc``); the config
names the extra terms and the highlights under ``advanced:``:

    value(a, b) = [diffuse term] + sum_{t < K} prod_(factors of the parametrization) t_(k, t)(pi_j(a, b))
                                               [* w_t(n.v)]

* lighting: the diffuse term is ``kd/pi E(n)`` on an ``n`` texture ``E`` (``exact``: the irradiance at
  the texel centres, not fitted; ``fitted``: a free n-only texture started from it);
* BRDF: the diffuse term is the constant ``kd/pi`` (no lookup) for ``quantity: brdf`` and
  ``kd/pi cos(theta_i)`` (a ``line`` texture of ``cos_i`` holding x) for ``brdf_cos``;
* ``nv_factor``: each fitted term also reads a ``line`` texture ``w_t`` at ``nv`` (lighting) or at
  ``cos_i`` and ``cos_o`` (BRDF, the same texture twice: reciprocal for PQP);
* ``rw_terms`` (lighting): J more fitted terms ``q_t(r) w_t(n.v)`` without a normal texture (two lookups
  each) after the K products: a sum can mix products that carry p(n) (they help under a sun) with ones
  that do not (they fit lamp highlights better; docs/notes/sums-research.md);
* ``highlights.terms`` (lighting, J <= 3): J more fitted terms ``d_t(x_j) w_t(n.v)`` (two lookups each),
  ``d_t`` a ``line`` texture read at ``x_j = nh_dom`` (``nh_dom1``, ``nh_dom2``), the NDF argument of
  the half vector of the j-th brightest light (context ``dominant``, ``dominant1``, ``dominant2``:
  :func:`homofac.light.brightest_directions`, the sun or the brightest lamps). A
  microfacet highlight of one light is ``D(n.h') F G / (4 n.v)``: a function of ``x`` times one of n.v,
  which keeps its shape at every view where a map of r smears it (the near-mirror under the city sun:
  the sun alone holds 71 % of the squared lighting; docs/notes/sums-research.md);
* ``highlights.table`` (lighting): each highlight term reads a 2D table ``T_t(n.i, n.v)`` of its light's
  cosine and the view's (projection ``ninv_dom``, ``ninv_dom1``, ``ninv_dom2``: :func:`homofac.param.projections.table_point`,
  a ``parabolic`` texture of :data:`TABLE_SIZE`) in place of ``c_t(n.i) w_t(n.v)``: one lookup fewer, and
  the highlight's ``min(1, n.i / n.v)`` near the mirror direction, which no product of the two lines holds
  (docs/notes/sums-research.md, "A 2D table of (n.i, n.v)"). The ALS fits the lines (:func:`lined`), which
  :func:`homofac.fit.table.tabulate` turns into the table for the polish to refine;
* ``highlights.disc`` (lighting): each highlight term reads its light's coordinate at the point of the
  light's disc closest to ``r`` (projection ``nhs_dom``, ``nhs_dom1``, ``nhs_dom2``; context ``radius``,
  :func:`homofac.light.light_radii`): at grazing views a point light's half vector is ill-conditioned
  and a sun's highlight there comes from the part of its disc on the mirror direction (docs/notes/sums-research.md,
  "The sun's disc at grazing views");
* ``reflection`` (lighting): one more fitted term, an r-only texture ``R`` (one lookup). Within a lookup
  budget it is worth more than an n.v-only or n-only term (gold under lamps: 0.83 -> 0.78 of
  split-sum at 8 lookups);
* ``prefiltered`` (lighting): the split sum's specular term P(r) W(n.v) (Karis 2013, the model's own
  NDF and DFG; :mod:`homofac.baselines.split_sum`) is computed and kept, and the fitted terms are
  corrections to the split sum: the structure whose frontal error stays at split-sum's.

:func:`skeleton` turns a structure into the textures (names, mappers, sizes) and terms of a
:class:`~homofac.factorization.Factorization`; :func:`candidates` lists the structures within a
lookup budget for ``max_lookups``.
"""

from __future__ import annotations

import functools
import re
from typing import Literal, NamedTuple, Optional, TypeVar

from pydantic import Field, ValidationError, field_validator, model_validator

from ..errors import HomofacError
from ..options import Options, format_error
from ..param import parametrizations as pz
from ..param import projections as pj

#: The line texture read by ``nv_factor`` (and by a BRDF ``brdf_cos`` diffuse term).
LINE_SIZE = 32

#: The ``parabolic`` size of a highlight term's 2D table (``highlights.table``): its square holds
#: ``TABLE_SPAN x 96 = 58`` texels per axis of (sqrt(n.i), sqrt(n.v)).
TABLE_SIZE = 96

M = TypeVar("M", bound=Options)


class HighlightLine(NamedTuple):
    """An extra line a highlight term may read beside ``d(nh_dom)``: the :class:`Highlights` field that
    turns it on, its projection per light (brightest first), its texture's name prefix, role and label
    letter, and the scalar it reads (for the refusal)."""

    key: str
    projections: tuple[str, ...]
    prefix: str
    role: str
    letter: str
    reads: str


#: The extra lines of highlight terms, in factor order: ``f(v.h')`` (``highlights.fresnel``, the Fresnel
#: argument) and ``c(n.i)`` (``highlights.cosine``, the light's cosine: shadowing and horizon).
HIGHLIGHT_LINES = (
    HighlightLine("fresnel", tuple(p for p, _ in pj.HIGHLIGHT_FRESNEL), "f", "fresnel", "F", "v.h'"),
    HighlightLine("cosine", tuple(p for p, _ in pj.HIGHLIGHT_COSINE), "c", "cosine", "C", "n.i"),
)


class TextureSpec(NamedTuple):
    """A texture of the skeleton: name, mapper, size, and the role its unknowns play."""

    name: str
    mapper: str
    size: int
    role: str  # "diffuse" (exact, computed), "diffuse_fitted", "factor", "nv", "cos" (identity line)


class TermSpec(NamedTuple):
    """A term of the skeleton: its factors as (projection, texture name) and its kind."""

    factors: tuple[tuple[str, str], ...]
    kind: str  # "irradiance" | "diffuse" | "fitted"
    fitted: bool  # its textures are unknowns of the linear-space fit


def _validated(model: type[M], data: dict, what: str) -> M:
    try:
        return model.model_validate(data)
    except ValidationError as e:
        raise HomofacError(format_error(e, what, model)) from None


class Highlights(Options):
    """The highlight terms of a structure (lighting): ``terms`` J fitted terms ``d_j(nh_dom_j) w_j(n.v)``
    of the J brightest lights, each also reading ``f(v.h')`` (``fresnel``) and ``c(n.i)`` (``cosine``),
    a table ``T(n.i, n.v)`` in place of ``c(n.i) w(n.v)`` (``table``), and its light's disc (``disc``)
    (see the module docstring). The flags are refused without highlight terms, and ``table`` with
    ``cosine`` (the table holds the cosine)."""

    terms: int = Field(0, ge=0, le=len(pj.HIGHLIGHTS))
    fresnel: bool = False
    cosine: bool = False
    table: bool = False
    disc: bool = False

    @model_validator(mode="after")
    def _consistent(self):
        if not self.terms:
            for key, what in (("fresnel", "the v.h' line"), ("cosine", "the n.i line"),
                              ("table", "the (n.i, n.v) table"), ("disc", "the disc's coordinate")):
                if getattr(self, key):
                    raise ValueError(f"{key}: {what} is read by highlight terms; set highlights.terms (got 0 terms)")
        if self.table and self.cosine:
            raise ValueError("table holds the light's cosine n.i with n.v in one table: set table or cosine, not "
                             "both (got both)")
        return self

    def replace(self, **changes) -> "Highlights":
        """These highlights with ``changes`` (validated: one-line :class:`HomofacError`)."""
        return _validated(Highlights, {**self.model_dump(), **changes}, "highlights")


class Structure(Options):
    """A sum of products (see the module docstring): ``terms`` products of ``parametrization`` plus an
    optional diffuse term, ``nv_factor``, the extra terms ``reflection``, ``prefiltered`` and
    ``rw_terms``, and the :class:`Highlights`. One frozen, hashable, validated value; :meth:`label`
    names it (``E'+NROW x4+R+HSFT x2``) and :meth:`parse` reads a label back.

    ``Structure("NR", 2, "fitted", True, reflection=True)``: the first four fields may be given in order.
    ``nv_factor`` is true for a parametrization that reads n.v itself (NRW), as its records say."""

    parametrization: str
    terms: int = Field(1, ge=1)
    diffuse: Optional[Literal["exact", "fitted"]] = None
    nv_factor: bool = False
    reflection: bool = False  # lighting: one more term, a fitted r-only texture q(r) (one lookup)
    prefiltered: bool = False  # lighting: the split sum's P(r) W(n.v) computed, not fitted (two lookups)
    rw_terms: int = Field(0, ge=0)  # lighting: this many more fitted terms q(r) w(n.v) (two lookups each)
    highlights: Highlights = Highlights()

    def __init__(self, parametrization: str | None = None, terms: int | None = None, diffuse: str | None = None,
                 nv_factor: bool | None = None, /, **data):
        given = zip(("parametrization", "terms", "diffuse", "nv_factor"), (parametrization, terms, diffuse, nv_factor))
        data = {**{k: v for k, v in given if v is not None}, **data}
        try:
            super().__init__(**data)
        except ValidationError as e:
            raise HomofacError(format_error(e, "structure", Structure)) from None

    @field_validator("parametrization")
    @classmethod
    def _registered(cls, name: str) -> str:
        if name not in pz.PARAMETRIZATIONS:
            raise ValueError(f"{name!r} is not a parametrization ({', '.join(pz.PARAMETRIZATIONS)})")
        return name

    @model_validator(mode="before")
    @classmethod
    def _own_nv(cls, data):
        name = data.get("parametrization") if isinstance(data, dict) else None
        if isinstance(name, str) and name in pz.PARAMETRIZATIONS and _has_nv(name) and not data.get("nv_factor"):
            return {**data, "nv_factor": True}
        return data

    def replace(self, **changes) -> "Structure":
        """This structure with ``changes`` (validated: one-line :class:`HomofacError`)."""
        return _validated(Structure, {**self.model_dump(), **changes}, "structure")

    def with_highlights(self, **changes) -> "Structure":
        """This structure with ``changes`` to its :class:`Highlights` (``with_highlights(disc=True)``)."""
        return self.replace(highlights=self.highlights.replace(**changes))

    @classmethod
    def of(cls, rec: dict) -> "Structure":
        """The structure of a record (:meth:`record`, the result's ``solver.structure``). Records written
        before the nested model (flat ``highlight_terms``, ``highlight_fresnel``, ... keys; a ``None``
        flag is off) are read the same."""
        if not isinstance(rec, dict):
            raise HomofacError(f"a structure record is a mapping, not {type(rec).__name__}")
        data = {k: rec[k] for k in ("parametrization", "terms", "diffuse", "nv_factor", "reflection", "prefiltered",
                                    "rw_terms", "highlights") if k in rec and rec[k] is not None}
        if "highlights" not in data:  # the flat layout of earlier records
            data["highlights"] = {k: rec[f"highlight_{k}"] for k in Highlights.model_fields
                                  if rec.get(f"highlight_{k}") is not None}
        return _validated(cls, data, "structure")

    def label(self) -> str:
        h = self.highlights
        d = {None: "", "exact": "E+", "fitted": "E'+"}[self.diffuse] + ("SS+" if self.prefiltered else "")
        w = "W" if self.nv_factor and not _has_nv(self.parametrization) else ""
        rw = f"+RW x{self.rw_terms}" if self.rw_terms else ""
        lines = "".join(line.letter for line in HIGHLIGHT_LINES if getattr(h, line.key))
        hw = f"+H{'S' if h.disc else ''}{lines}{'T' if h.table else 'W'} x{h.terms}" if h.terms else ""
        return f"{d}{self.parametrization}{w} x{self.terms}{rw}{'+R' if self.reflection else ''}{hw}"

    def describe(self) -> str:
        """The nested model in words (``NR products x2, diffuse fitted, nv_factor, reflection``)."""
        h = self.highlights
        parts = [f"{self.parametrization} products x{self.terms}"]
        parts += [f"diffuse {self.diffuse}"] if self.diffuse else []
        parts += [k for k in ("nv_factor", "reflection", "prefiltered") if getattr(self, k)]
        parts += [f"rw_terms {self.rw_terms}"] if self.rw_terms else []
        if h.terms:
            flags = [k for k in ("fresnel", "cosine", "table", "disc") if getattr(h, k)]
            parts.append(f"highlights {{terms {h.terms}" + "".join(f", {k}" for k in flags) + "}")
        return ", ".join(parts)

    @classmethod
    def parse(cls, label: str) -> "Structure":
        """The structure a :meth:`label` names (``E'+NROW x4+R+HSFT x2``): the inverse of :meth:`label`,
        with one identity: ``NRW x1`` reads as NR products with the n.v factor (the NRW parametrization
        fits the same sum). A string that is no label is refused in one line."""
        m = _LABEL.match(label.strip()) if isinstance(label, str) else None
        if m is None:
            raise HomofacError(f"{label!r} is not a structure label (such as E'+NRW x2+R or E'+ROW x3+R+HFCW x1)")
        g = m.groupdict()
        name, w = g["p"], bool(g["w"])
        if name not in pz.PARAMETRIZATIONS and w and name + "W" in pz.PARAMETRIZATIONS:
            name, w = name + "W", False
        if name not in pz.PARAMETRIZATIONS:
            raise HomofacError(f"{label!r}: {name} is not a parametrization ({', '.join(pz.PARAMETRIZATIONS)})")
        diffuse = {None: None, "E+": "exact", "E'+": "fitted"}[g["d"]]
        highlights = {"terms": int(g["j"] or 0), "fresnel": bool(g["f"]), "cosine": bool(g["c"]),
                      "table": g["tw"] == "T", "disc": bool(g["s"])}
        return _validated(cls, {"parametrization": name, "terms": int(g["k"]), "diffuse": diffuse, "nv_factor": w,
                                "reflection": bool(g["r"]), "prefiltered": bool(g["ss"]),
                                "rw_terms": int(g["rw"] or 0), "highlights": highlights}, repr(label))

    def record(self) -> dict:
        """The structure as plain data (``solver.structure`` of factorization.json; :meth:`of` reads it)."""
        return self.model_dump(mode="json")

    def keywords(self) -> dict:
        """The keywords of :func:`homofac.fit.factorize` that fit exactly this structure: the pinned
        ``parametrization``, ``terms``, ``diffuse``, ``nv_factor`` and the rest under ``advanced``."""
        h = {k: v for k, v in self.highlights.model_dump().items() if v}
        adv = {k: getattr(self, k) for k in ("reflection", "prefiltered", "rw_terms") if getattr(self, k)}
        return {"parametrization": self.parametrization, "terms": self.terms, "diffuse": self.diffuse,
                "nv_factor": self.nv_factor, "advanced": {**adv, **({"highlights": h} if h else {})}}


#: The grammar of :meth:`Structure.label`.
_LABEL = re.compile(r"^(?P<d>E'\+|E\+)?(?P<ss>SS\+)?(?P<p>[A-Z]+?)(?P<w>W)? x(?P<k>[1-9][0-9]*)"
                    r"(?:\+RW x(?P<rw>[1-9][0-9]*))?(?P<r>\+R)?"
                    r"(?:\+H(?P<s>S)?(?P<f>F)?(?P<c>C)?(?P<tw>[TW]) x(?P<j>[1-9][0-9]*))?$")


def lined(structure: Structure) -> Structure:
    """The structure whose highlight terms read the lines ``c(n.i) w(n.v)`` where ``structure``'s read a
    table ``T(n.i, n.v)`` (what the ALS fits; :func:`homofac.fit.table.separate` goes there)."""
    return structure.with_highlights(table=False, cosine=True) if structure.highlights.table else structure


def tabled(structure: Structure) -> Structure:
    """The structure whose highlight terms read a table ``T(n.i, n.v)`` where ``structure``'s read the lines
    ``c(n.i) w(n.v)`` (:func:`homofac.fit.table.tabulate` goes there)."""
    if not (structure.highlights.terms and structure.highlights.cosine):
        raise HomofacError(f"{structure.label()}: only highlight terms with the cosine line c(n.i) become tables")
    return structure.with_highlights(cosine=False, table=True)


def _reads_n(parametrization: str) -> bool:
    return any(f.projection == "n" for f in pz.get(parametrization).factors)


def _has_nv(parametrization: str) -> bool:
    return any(pj.get(f.projection).scalar for f in pz.get(parametrization).factors)


@functools.lru_cache(maxsize=4096)
def skeleton(structure: Structure, kind: str, quantity: str, mapper: str, size: int,
             line_size: int = LINE_SIZE) -> tuple[tuple[TextureSpec, ...], tuple[TermSpec, ...]]:
    """Textures and terms of ``structure`` (see the module docstring); texture names carry the term
    index when there is more than one term (``n0, r0, w0, n1, ...``)."""
    p = pz.get(structure.parametrization, kind)
    textures: list[TextureSpec] = []
    terms: list[TermSpec] = []
    if structure.diffuse is not None:
        fitted = structure.diffuse == "fitted"
        if kind == "lighting":
            textures.append(TextureSpec("E", mapper, size, "diffuse_fitted" if fitted else "diffuse"))
            terms.append(TermSpec((("n", "E"),), "fitted" if fitted else "irradiance", fitted))
        elif quantity == "brdf_cos":
            textures.append(TextureSpec("C", "line", line_size, "cos"))
            terms.append(TermSpec((("cos_i", "C"),), "diffuse", False))
        else:
            terms.append(TermSpec((), "diffuse", False))
    if structure.prefiltered:
        if kind != "lighting":
            raise HomofacError("prefiltered: the split sum's specular term is for lighting targets")
        textures += [TextureSpec("P", mapper, size, "prefiltered"), TextureSpec("W", "line", line_size, "dfg")]
        terms.append(TermSpec((("r", "P"), ("nv", "W")), "prefiltered", False))
    many = structure.terms + structure.rw_terms + structure.highlights.terms > 1
    for t in range(structure.terms):
        suffix = str(t) if many else ""
        names = [f"{name}{suffix}" for name in p.textures]
        for k, name in enumerate(names):
            textures.append(TextureSpec(name, "line" if p.scalar(k) else mapper,
                                        line_size if p.scalar(k) else size, "factor"))
        factors = [(f.projection, names[f.texture]) for f in p.factors]
        if structure.nv_factor and not _has_nv(p.name):
            w = f"w{suffix}"
            textures.append(TextureSpec(w, "line", line_size, "nv"))
            factors += [("nv", w)] if kind == "lighting" else [("cos_i", w), ("cos_o", w)]
        terms.append(TermSpec(tuple(factors), "fitted", True))
    if structure.rw_terms:
        if kind != "lighting":
            raise HomofacError("rw_terms: the q(r) w(n.v) terms are for lighting targets")
        if p.textures == ("r",) or "r" not in {f.projection for f in p.factors}:
            raise HomofacError(f"rw_terms: {p.name} products are already q(r) w(n.v) or lack an r factor; "
                               f"use terms (rw_terms adds them beside NR products)")
    for t in range(structure.terms, structure.terms + structure.rw_terms):
        r, w = f"r{t}", f"w{t}"
        textures += [TextureSpec(r, mapper, size, "factor"), TextureSpec(w, "line", line_size, "nv")]
        terms.append(TermSpec((("r", r), ("nv", w)), "fitted", True))
    if structure.reflection:
        if kind != "lighting":
            raise HomofacError("reflection: the r-only term is for lighting targets")
        textures.append(TextureSpec("R", mapper, size, "reflection"))
        terms.append(TermSpec(((pz.reflection_projection(p), "R"),), "fitted", True))  # r_off for NRO
    h = structure.highlights
    if h.terms and kind != "lighting":
        raise HomofacError("highlights: the d(nh_dom) w(n.v) terms are for lighting targets")
    lines = [line for line in HIGHLIGHT_LINES if getattr(h, line.key)]
    first = structure.terms + structure.rw_terms
    for j in range(h.terms):
        t = first + j
        d, w = f"d{t}", f"w{t}"
        textures.append(TextureSpec(d, "line", line_size, "highlight"))
        factors = [((pj.HIGHLIGHT_DISCS if h.disc else pj.HIGHLIGHTS)[j][0], d)]
        for line in lines:
            textures.append(TextureSpec(f"{line.prefix}{t}", "line", line_size, line.role))
            factors.append((line.projections[j], f"{line.prefix}{t}"))
        if h.table:  # T(n.i, n.v) in place of c(n.i) w(n.v)
            textures.append(TextureSpec(f"T{t}", "parabolic", TABLE_SIZE, "table"))
            factors.append((pj.HIGHLIGHT_TABLE[j][0], f"T{t}"))
        else:
            textures.append(TextureSpec(w, "line", line_size, "nv"))
            factors.append(("nv", w))
        terms.append(TermSpec(tuple(factors), "fitted", True))
    return tuple(textures), tuple(terms)


def lookups(structure: Structure, kind: str, quantity: str = "lighting") -> int:
    """Texture lookups per pixel: one per factor of every term (the count of docs/format.md)."""
    _, terms = skeleton(structure, kind, quantity, "dual_paraboloid" if kind == "lighting" else "parabolic", 8)
    return sum(len(t.factors) for t in terms)


def candidates(kind: str, max_lookups: int, *, parametrization: str | None = None, has_diffuse: bool = True,
               max_terms: int = 16, highlight: bool = True, table: bool = False) -> list[Structure]:
    """The structures worth fitting within ``max_lookups`` texture lookups, cheapest first.

    For each variant (the split sum computed or not; lighting) the one with the most terms that fits,
    with the n.v factor and, when the material has a diffuse part, a fitted diffuse texture: more terms,
    a free diffuse texture and w(n.v) never fit worse, so the smaller variants are not tried; a lookup
    left over goes to the r-only term. ``parametrization`` defaults to NR (lighting) and PQP
    (BRDF); with NR the same products read at the off-specular reflection ``r_off`` (NRO) and the
    products without p(n) at ``r_off``, ``q_t(r') w_t(n.v)`` (RO with the n.v factor), are candidates
    too (:data:`RELATIVES`; RO holds a glossy metal under lamps far better: gold / interior 0.41
    against 0.54 nrmse at 4 lookups, where NR holds a plastic better: 0.37 against 0.51).
    :func:`homofac.fit.sums.choose` fits them and keeps the best on the validation pairs; the errors
    are heavy-tailed (the worst 0.1 % of pairs hold up to half the squared error): 5000 validation pairs
    ranked E'+NRW and E'+RW+R unlike the ground truth on two of three cases, 20000 (the default) at the
    same light resolution alike on all three (docs/notes/sums-research.md).
    Sums that mix both kinds of product (``rw_terms``) are not candidates: they fitted worse than
    either kind alone (docs/notes/sums-research.md). With ``highlight`` (lighting targets with an environment) each
    family is tried again with one highlight term of the brightest light (``highlights.terms: 1``): the
    near-mirror under the city sun falls from 0.47 to 0.17 nrmse at 4 lookups. With ``table`` the
    highlight terms that would read the cosine line c(n.i) and w(n.v) read a 2D table T(n.i, n.v) instead
    (``highlights.table``: one lookup fewer each, which goes to more terms;
    the ``best`` preset, :mod:`homofac.fit.plan`).
    """
    return _sorted(_variants(kind, max_lookups, parametrization, has_diffuse, max_terms, largest=True,
                             highlight=highlight, table=table))


def ladder(kind: str, max_lookups: int, *, parametrization: str | None = None, has_diffuse: bool = True,
           max_terms: int = 16, highlight: bool = True, table: bool = False) -> list[Structure]:
    """Every structure within ``max_lookups``, cheapest first (``target_error``: the first that meets it)."""
    return _sorted(_variants(kind, max_lookups, parametrization, has_diffuse, max_terms, largest=False,
                             highlight=highlight, table=table))


#: Lighting parametrizations whose ``max_lookups`` candidates include relatives of another family.
RELATIVES = {"NR": ("NRO", "RO"), "NRO": ("RO",)}


def _variants(kind, max_lookups, parametrization, has_diffuse, max_terms, largest, highlight=True, table=False):
    if max_lookups < 1:
        raise HomofacError(f"max_lookups must be at least 1, got {max_lookups}")
    base = parametrization or ("NR" if kind == "lighting" else "PQP")
    pz.get(base, kind)
    # the relatives tried beside the NR products (docs/notes/sums-research.md): the same read at the off-specular
    # reflection r_off (NRO), and the products without p(n) at r_off, q(r') w(n.v) (RO; they replace
    # R's q(r) w(n.v), which they beat on every case measured)
    relatives = RELATIVES.get(base, ()) if kind == "lighting" else ()
    prefs = (False, True) if relatives else (False,)
    # A fitted diffuse texture can do all the exact one does (it starts there), and the n.v factor is
    # worth more than a whole term (issue 13): the other variants are not tried.
    if not has_diffuse:
        diffuses: tuple = (None,)
    else:
        diffuses = ("fitted",) if kind == "lighting" else ("exact",)
    families = [Structure(base, 1, d, not _has_nv(base), prefiltered=pre) for d in diffuses for pre in prefs]
    families += [Structure(rel, 1, d, True) for rel in relatives for d in diffuses]
    if relatives and highlight:
        # each family again with the highlight term of the brightest light, d(nh_dom) w(n.v)
        # (docs/notes/sums-research.md);
        # where a product with w(n.v) leaves no room for it, the product without w
        lit = [f.with_highlights(terms=1) for f in families]
        lit += [f.replace(nv_factor=False) for f in lit
                if not _has_nv(f.parametrization) and lookups(f, kind) > max_lookups]
        # and the products without p(n) with the highlights of the two brightest lights (lamps)
        lit += [f.with_highlights(terms=2) for f in lit if _w(f) and not _reads_n(f.parametrization)]
        # and each with the Fresnel line f(v.h') in its highlight terms where the budget has room for it
        # (a dielectric's highlight rises 25-fold toward grazing v.h', which d(x) w(n.v) cannot follow)
        lit += [f.with_highlights(fresnel=True) for f in lit if _w(f)]
        # and those with both the Fresnel line and the light's cosine c(n.i) (the shadowing G1(n.i) and the
        # horizon: plastic / city at 16 lookups 0.084 -> 0.076 on 90000 pairs)
        lit += [f.with_highlights(cosine=True) for f in lit if f.highlights.fresnel]
        if table:  # c(n.i) w(n.v) as one table T(n.i, n.v): one lookup fewer, for more terms
            lit = [tabled(f) if f.highlights.cosine else f for f in lit]
        families += lit
    out = []
    for family in families:
        fits = [family.replace(terms=k) for k in range(1, max_terms + 1)
                if lookups(family.replace(terms=k), kind) <= max_lookups]
        if kind == "lighting" and fits and lookups(fits[-1].replace(reflection=True), kind) <= max_lookups:
            fits.append(fits[-1].replace(reflection=True))  # a lookup left over: the r-only term
        out += fits[-1:] if largest else fits
    if not out:
        smallest = lookups(Structure(base, 1, diffuses[0]), kind)
        raise HomofacError(f"max_lookups {max_lookups}: no structure of {base} fits (the smallest needs {smallest})")
    return out


def _w(structure: Structure) -> bool:
    """Whether the structure's products carry the extra n.v factor (not a parametrization's own)."""
    return structure.nv_factor and not _has_nv(structure.parametrization)


def _sorted(structures):
    return sorted(structures, key=lambda s: (lookups(s, "lighting" if pz.get(s.parametrization).kind == "lighting"
                                                       else "brdf"), s.terms, not _w(s), str(s.diffuse),
                                             s.highlights.terms, s.highlights.fresnel, s.highlights.cosine,
                                             s.highlights.table, s.highlights.disc))


__all__ = ["HIGHLIGHT_LINES", "LINE_SIZE", "TABLE_SIZE", "HighlightLine", "Highlights", "Structure", "TermSpec", "TextureSpec", "candidates",
           "ladder", "lined", "lookups", "skeleton", "tabled"]
