"""The plan of a fit: what will run, decided once before any compute (``preset``, ``--plan``).

:func:`build_plan` turns the target, a preset (``fast``, ``balanced``, ``best``: lookup budgets 4, 8, 16)
and the options the caller gave into a frozen :class:`Plan`: the sample counts, the candidate structures,
the linear-fit options of each stage and the votes with the figure each reads.
:func:`homofac.fit.pipeline.factorize` builds it and then executes it; the execution reads the plan and
holds no rules of its own. A preset sets values; an option given explicitly replaces the preset's
(``None`` in the options means "the preset's").

Which preset applies (:func:`preset_of`): ``preset`` when given; else, for ``max_lookups`` N, the
smallest preset whose budget holds N (``best`` above 8), so that a config of ``max_lookups: 16`` keeps
the settings it always had; else (``target_error`` with sum keys: the ladder within 16 lookups)
``best``; else none (a named structure, a single product, a baseline).
"""

from __future__ import annotations

import dataclasses
import json
from typing import Any, NamedTuple

from .. import baselines
from ..errors import HomofacError
from ..options import validate
from ..param import parametrizations as pz
from ..target import Target
from . import structures, sums, validation
from .draw import default_mapper, grid_projection
from .options import DEFAULT_TOLERANCE, DEFAULT_VALIDATION, FitOptions, LinearOptions
from .polish import RIDGE_NEEDS_ENVIRONMENT
from .sampling import GRID_COUNT
from .structures import HIGHLIGHT_LINES, Structure
from .validation import ValidationLight


class Preset(NamedTuple):
    """The values a preset sets (each replaced by the option of the same meaning where given).

    ``lookups``: the budget ``max_lookups``; ``grid_count``: training pairs of the grid design
    (``sampling.count``); ``validation``: validation pairs (``sampling.validation``); ``line_ratio``: 0
    for 32-texel lines only, k for a vote between 32 and k x ``texture_size`` texels (``advanced.line_size``);
    ``table``: highlight candidates read a 2D table T(n.i, n.v) (``advanced.highlights.table``); ``disc_vote``:
    the kept structure is fitted again reading its lights' discs (``advanced.highlights.disc``); ``nv_balance``:
    of the candidates on lighting of a BRDF with kd > 0 (``advanced.linear.nv_balance``); ``polish``:
    Levenberg-Marquardt steps of the kept structure (``advanced.linear.polish``); ``ridge``: ridge pairs of its
    polish and of the validation estimate (``advanced.linear.ridge``); ``analysis``: record Mahajan's in-out
    analysis (``advanced.analysis``); ``directions``: the grid directions
    (:func:`~homofac.fit.draw.grid_projection`) whose candidates a lighting fit tries (empty: all);
    ``polish_stride``: the polish fits every k-th grid pair and every k-th view of its off-grid pairs (only
    those evaluated); ``race``: the ALS sweep counts
    (increasing) after which the candidates still in the race are ranked on the validation figure (every
    candidate runs its first sweeps on the training pairs with the programs of its full fit; after each
    round only the lowest and those within ``race_margin`` (relative) of it, at most ``race_keep`` of the
    round, continue from where they stopped; empty: every candidate fitted in full); ``race_stride``: the
    first round fits every k-th training pair (k > 1: short fits of their own, those kept start over on
    every pair, or with ``race_continue`` continue on every pair from their short fit's textures:
    :func:`homofac.fit.sums.continued`; so does a line or disc vote's alternative fitted in full, from its
    ``vote_screen`` short fit); ``tolerance``: the ALS
    stops where a sweep lowers its objective by less than this fraction (``advanced.linear.tolerance``);
    ``vote_screen``: ALS sweeps of the short fits (on every ``race_stride``-th pair, as the race's first round)
    that the line and disc votes read first: the kept structure's other line size, or its disc, is fitted in
    full only where its short fit's figure is below the kept structure's (0: always fitted in full);
    ``highlight_start``: ALS sweeps of the highlight terms' own start (``advanced.linear.highlight_start``;
    None: half the fit's sweeps); ``polish_direct``: with ``ridge`` pairs, the polish is only the stage with them
    straight from the ALS fit (:func:`homofac.fit.polish.polish` with ``direct``), voted against the ALS fit,
    instead of the three stages of :func:`~homofac.fit.polish.polish_stages`; ``dropped``: the labels of candidates
    the preset does not try (a candidate the race never keeps: :data:`BALANCED_DROPPED`; a constraint in the options
    that leaves only dropped ones tries those); ``race_strided``: every round of
    the race fits the first round's every ``race_stride``-th pair, a later round continuing the strided fits
    where they stopped (a round may then keep every candidate its margin admits: ``race_keep`` only caps it);
    ``race_margins``: the margin of each round (replacing ``race_margin`` where given); ``table_twins``: a highlight
    candidate on lines whose table twin (``with_highlights(table=True)``) is a candidate is not tried;
    ``polish_gate``: the polish runs only where the kept fit's mean squared residual on the polish's off-grid pairs is
    above this multiple of the one on its grid pairs (:func:`homofac.fit.polish.off_grid_figures`; 0: always)."""

    lookups: int
    grid_count: int
    validation: int
    line_ratio: int
    table: bool
    disc_vote: bool
    nv_balance: float
    polish: int
    ridge: int
    analysis: bool
    directions: tuple[str, ...] = ()
    polish_stride: int = 1
    race: tuple[int, ...] = ()
    race_keep: tuple[int, ...] = ()
    race_margin: float = 0.0
    race_stride: int = 1
    tolerance: float = DEFAULT_TOLERANCE
    vote_screen: int = 0
    race_continue: bool = False
    highlight_start: int | None = None
    polish_direct: bool = False
    dropped: tuple[str, ...] = ()
    race_strided: bool = False
    race_margins: tuple[float, ...] = ()
    table_twins: bool = False
    polish_gate: float = 0.0


#: The grid directions of the presets' candidates: the off-specular reflection ``r_off`` only. On the
#: 16-case accuracy benchmark (benchmarks/accuracy.json) the candidates on ``r`` (NRW, SS+NRW: 6 of 15 at
#: 8 lookups, 1 of 4 at 4) were never kept at 4, 8 or 16 lookups, and each direction costs its own grid
#: of training pairs (the lighting integral at every pair, the largest stage of a fit: docs/notes/speed.md).
PRESET_DIRECTIONS = ("r_off",)


#: ``fast``'s race and ALS stop (:class:`Preset`; docs/notes/speed.md, "The race"): every candidate runs 3
#: ALS sweeps, the lowest and those within 8 % of it (at most 2) continue; a fit stops where a sweep lowers
#: its objective by less than 1e-3 of it. On the accuracy benchmark's four speed cases
#: (benchmarks/race_study_fast.json) the candidates' figures after 3 sweeps put the full fits' lowest first
#: on each; the nearest other one was 4.9 % above it there (interior) and every candidate's figure moved by
#: less than 13 % from 3 sweeps to 30; stopping at 1e-3 moved the kept structures' figures by at most 0.3 %.
#: The highlight terms' own start runs 5 sweeps (``highlight_start``; 15 before, half the 30 of a fit): on the four
#: speed cases the highlight candidate's race figure moved by -1.3 to +0.1 % and the kept fits by 0 to -0.15 %
#: (mirror / studio keeps it: 0.3517 -> 0.3512 on the converged truth), 10 sweeps on 300 000 pairs less
#: (benchmarks/presets_fast17_cand.json; docs/notes/speed.md, "The candidate loop, seventeenth session").
FAST_RACE = {"race": (3,), "race_keep": (2,), "race_margin": 0.08, "tolerance": 1e-3, "highlight_start": 5}

#: The race of ``best``: a first round of 10 ALS sweeps on every 4th training pair (fits of their own), the
#: lowest and those within 3 % of it (at most 2) fitted in full (the screen of the second speed work: gold /
#: forest 192 s CPU against 348-374 s for the 9 full fits, the kept structure 0.4 % above the full fits' lowest
#: on the validation pairs). A first round on every pair, from which the kept would continue, costs more there:
#: each of the candidates' start (its highlight terms' own 15 sweeps) runs on every pair, and their figures
#: cross between 6 and 8 sweeps (docs/notes/speed.md, "The race").
RACE = {"race": (10,), "race_keep": (2,), "race_margin": 0.03, "race_stride": 4}

#: ``balanced``'s race and ALS stop: ``best``'s first round (10 sweeps on every 4th pair), then only the lowest
#: is fitted in full (on the accuracy benchmark's four speed cases a runner-up within 3 % was fitted in full on gold /
#: forest only, and the first round's lowest was the full fits' lowest there, 0.1291 against 0.1298; each full fit
#: is about a quarter of the preset's CPU time: docs/notes/speed.md, "balanced, sixteenth session"), continuing on
#: every pair from its short fit until a sweep lowers the objective by less than 3e-3 of it. On the four speed
#: cases the kept fit then ran 5-10 sweeps instead of the 7-25 of a stop at 1e-3 (0.6-0.9 s CPU each on 300 000
#: pairs) and the preset's nrmse on the converged truth moved by +0.11 % (gold / forest), -3.2 % (plastic / city:
#: the further sweeps fitted the grid, not the lighting between it), +0.08 % (mirror / studio) and -0.34 % (metal /
#: interior) (benchmarks/presets_balanced20_tol3.json against presets_balanced20_base.json; docs/notes/speed.md,
#: "balanced, twentieth session"). The race's short fits run their 10 sweeps either way. The race cuts once before
#: that (``race_strided``, rounds (4, 10)): after 4 of the strided fits' 10 sweeps only those within 10 % of the lowest
#: continue. On the 11 accuracy cases of benchmarks/race_study_balanced19.json (the four speed cases among them) the
#: 10-sweep lowest was within 3.2 % of the lowest after 4 sweeps on every case (0 % on 9), and 26 of their 88
#: candidates were within 10 % (1-5 a case), so about 62 of 88 stop 6 sweeps early; the candidates that reach 10
#: sweeps run the same fits as a race of one round (docs/notes/speed.md, "balanced, twenty-second session").
BALANCED_RACE = {**RACE, "race": (4, 10), "race_keep": (8, 1), "race_margin": 0.0, "race_margins": (0.10, 0.0),
                 "race_strided": True, "tolerance": 3e-3, "race_continue": True}

#: ``best``'s race: ``balanced``'s, with the strided fits on every 4th pair run to the full fit's 30 sweeps.
#: At 16 lookups 10 sweeps of a fit of 10 misrank the candidates: on gold / forest (75 000 grid pairs, validation nrmse) the
#: fits of ``E'+NROW x4+HFT x1``, ``E'+NROW x4+R+HW x1`` and ``E'+ROW x4+R+HFW x2`` read 0.133 / 0.117 / 0.130
#: after 10 sweeps, 0.119 / 0.115 / 0.128 after 20 and 0.112 / 0.113 / 0.128 after 30, the order of their full
#: fits on 300 000 pairs (0.101 / 0.104 / 0.122; on the converged truth 0.095 / 0.102 / 0.117); the race of 10
#: sweeps kept the third (docs/notes/speed.md, "best, seventeenth session"). Every round fits the strided pairs
#: (``race_strided``): after 10 of the 30 sweeps (the highlight terms' start already that of a fit of 30) those more than
#: 5 % behind the lowest are dropped, the others continue to 30, where the lowest is kept. The 30-sweep figures are
#: the one-round race's (to 4 digits on gold / forest); after 10 sweeps the 30-sweep winner was 1.2 % behind the
#: lowest on gold / forest and the lowest on plastic / city, where 4 and 9 of the 11 candidates were more than 5 %
#: behind (benchmarks/presets_best19_race.json; docs/notes/speed.md, "best, nineteenth session"). The kept candidate
#: continues from its race fit (``race_continue``, as ``balanced``'s): on plastic / city the fit on every pair then
#: converges in 5 sweeps (27 s CPU) where one started over runs its highlight start and 14, to a figure as low
#: (validation with the ridge stratum 0.140 against 0.143; docs/notes/speed.md, "best, eighteenth session").
BEST_RACE = {**BALANCED_RACE, "race": (10, 30), "race_keep": (10, 1), "race_strided": True, "race_margins": (0.05, 0.0),
             "tolerance": 1e-3}

#: ``fast`` has no polish: on the accuracy benchmark's four speed cases the polish then (a 2-step trial, then 8
#: steps on every pair) lowered the figure on one (mirror / studio, 0.3514 unpolished against 0.3454 polished on the converged truth, +1.7 %), and the
#: polish's off-grid pairs and Levenberg-Marquardt program were a third of the preset's time
#: (docs/notes/speed.md, "The third speed work"). ``balanced``'s polish is 2 steps on every 4th grid pair and
#: off-grid view, kept where it lowers the validation figure: on the four speed cases it came within 0.5 % of 8
#: steps on every pair where those were kept (mirror / studio 0.2303 -> 0.2264 against 0.2260, metal / interior
#: 0.2895 -> 0.2888 against 0.2873) and below them where they were not (plastic / city 0.0545 -> 0.0519 against
#: 0.0591), for a quarter of the pairs' lighting and a quarter of the steps; the preset's nrmse on the converged
#: truth moved by +0.1, -5.5, +0.4 and +1.6 % (docs/notes/speed.md, "balanced, sixteenth session").
POLISH_STRIDE = 4

#: The candidates ``balanced`` does not try: on the accuracy benchmark's cases (materials x environments; 11 of the
#: 16 measured) its race's first round (10 ALS sweeps on every 4th grid pair) put ``E'+ROW x3+R`` 13.6 % or more
#: above the lowest on every case (median 61 %), and it was the lowest after 2-10 sweeps on none
#: (benchmarks/race_study_balanced19.json; docs/notes/speed.md, "balanced, nineteenth session"). It was the only
#: candidate of its ALS slot shape (3 lined terms): dropping it saves that sweep program's compilation and its
#: sweeps (about 4-5 s CPU in a fresh process) and changes no kept structure (the race keeps the lowest).
#: ``E'+NROW x1+R+HW x1`` and ``E'+NROW x1+R+HFW x1`` were the race's pick (the lowest after 10 strided sweeps) on none
#: of the 16 cases either (the 11 of race_study_balanced19.json and the other 5 in benchmarks/balanced_votes_bal23.jsonl:
#: nearest 0.4 % and 2.3 % behind the pick on rough / studio and rough / city, 3.7 % on plastic / forest); they fill
#: the slot shape of two other candidates, so dropping them saves their race fits (about 1.3 s CPU each on gold /
#: forest) and changes no pick on those cases (docs/notes/speed.md, "balanced, twenty-third session").
BALANCED_DROPPED = ("E'+ROW x3+R", "E'+NROW x1+R+HW x1", "E'+NROW x1+R+HFW x1")

#: ``best`` does not try a highlight candidate on the lines ``w(n.v)`` (``HFW``) whose table twin (``HFT``: the same
#: terms, their highlight read from a table ``T(n.i, n.v)`` fitted as the lines ``c(n.i) w(n.v)``, at the same lookups)
#: is a candidate (``Preset.table_twins``; at 16 lookups three: ``E'+NROW x4+HFW x1``, ``E'+ROW x4+R+HFW x2``,
#: ``E'+ROW x6+HFW x1``). The twin holds every function the lined candidate holds (``c`` constant) and its ALS fits a
#: superset of the lined one's unknowns. In the race on the four speed cases (gold / forest, plastic / city, mirror /
#: studio, metal / interior) the twin read lower in all 12 pairs after 30 strided sweeps (by 0.6-9.9 %) and in 11 of 12
#: after 10 (gold / forest's ``x2`` pair: the lined 0.7 % lower, 0.6 % higher after 30), and no lined candidate was
#: the race's lowest after 30 sweeps (benchmarks/presets_best19_race.json, presets_best20_race.json;
#: docs/notes/speed.md, "best, twentieth session"). Dropping them saves their race starts (11-24 s CPU each on gold /
#: forest at load 14) and, where they pass the first round's margin, their later sweeps; without tables
#: (``advanced.highlights.table: false``) there is no twin and they are tried.

#: The candidates ``best`` does not try: the two with a reflection term and highlights on lines without the Fresnel
#: factor beside 5 or 6 products (``E'+ROW x5+R+HW x2``, ``E'+ROW x6+R+HW x1``). In ``best``'s race (strided fits)
#: they were the lowest on none of 6 cases; after 30 sweeps they read above the lowest by 7.8 / 12.3 % on gold /
#: forest (ridge stratum), 8.1 / 46.6 % on mirror / studio, 15.3 / 32.4 % on metal / interior, 86 / 204 % on rough /
#: forest and 75 / 74 % on rough / studio (plain validation nrmse), and by 30.0 / 30.6 % on plastic / city after 10
#: (where the race stopped them); the kept structure of the accuracy benchmark's 4 sixteen-lookup rows was a table
#: candidate (``HFT``) on each (benchmarks/presets_best19_race.json, presets_best20_race.json,
#: race_study_best23.json, accuracy.json; docs/notes/speed.md, "best, twenty-third session"). Their race starts were
#: 32 s CPU of the first round's 109 on gold / forest. ``E'+NROW x4+R+HW x1`` stays (2.6 % above the lowest on gold /
#: forest, 4 % on rough / forest).
BEST_DROPPED = ("E'+ROW x5+R+HW x2", "E'+ROW x6+R+HW x1")

#: ``fast``'s training pairs: 22 per unknown of its largest candidate (``E'+NROW x1`` and ``E'+ROW x1+R``: 5456 texels
#: per channel at texture size 32). The grid's lighting integrals are the largest fixed stage of ``fast`` (10 s CPU of
#: 27 on gold / forest at 175 000 pairs; its 1624 normals stay, the views per normal shrink: 14 -> 11 blocks of
#: (256, 64) rows, 1 s CPU less). On the four speed cases 120 000 pairs moved the nrmse on the converged truth by
#: +0.8 % (gold / forest), -1.0 % (plastic / city), -0.8 % (mirror / studio), -0.3 % (metal / interior) against 175 000,
#: every vote picking the same structure; 90 000 flipped plastic / city's vote (+8.3 %), as 150 000 had (+5.6 %):
#: that vote is close at every count (docs/notes/speed.md, "fast, twenty-third session").
FAST_GRID_COUNT = 120_000

#: The presets (names pinned). ``fast`` and ``balanced`` are the 4- and 8-lookup settings measured on
#: the accuracy benchmark (docs/notes/sums-research.md). ``best`` is ``balanced``'s machinery at 16 lookups
#: (300 000 grid pairs, 20 000 validation pairs, one candidate fitted in full, the ALS stop at 1e-3, a polish
#: on every 4th pair) with what the 16-lookup structures measurably need: a first round of 30 sweeps
#: (:data:`BEST_RACE`), the tables (kept on 3 of the accuracy benchmark's 4 sixteen-lookup rows), the line
#: vote 32 / 4 x texture_size and the disc vote (each read on a short fit first), the plain objective, and 20 000
#: ridge pairs in every figure and in its polish: one stage of 8 Levenberg-Marquardt steps with the ridge pairs
#: straight from the ALS fit (``polish_direct``; the stage kept on every case where three were tried:
#: docs/notes/sums-research.md, "A third polish stage"). On gold / forest the choice among its candidates is
#: most of its accuracy: the full fits of the three leading structures on 300 000 pairs read 0.095 / 0.102 /
#: 0.117 on the converged truth (docs/notes/speed.md, "best, seventeenth session"). On plastic / city the benchmark's
#: 20000 pairs put it above ``balanced`` (0.0626 against 0.0598) and the 270 000 dense pairs, which see the city sun's
#: grazing ridge, below (0.118 against 0.138; docs/notes/speed.md, "best, eighteenth session").
PRESETS: dict[str, Preset] = {
    "fast": Preset(lookups=4, grid_count=FAST_GRID_COUNT, validation=DEFAULT_VALIDATION, line_ratio=0, table=False,
                   disc_vote=False, nv_balance=1.0, polish=0, ridge=0, analysis=False, directions=PRESET_DIRECTIONS,
                   **FAST_RACE),
    "balanced": Preset(lookups=8, grid_count=GRID_COUNT, validation=DEFAULT_VALIDATION, line_ratio=0, table=False,
                       disc_vote=False, nv_balance=1.0, polish=2, ridge=0, analysis=False,
                       directions=PRESET_DIRECTIONS, polish_stride=POLISH_STRIDE, dropped=BALANCED_DROPPED,
                       **BALANCED_RACE),
    "best": Preset(lookups=16, grid_count=GRID_COUNT, validation=DEFAULT_VALIDATION, line_ratio=4, table=True,
                   disc_vote=True, nv_balance=0.0, polish=8, ridge=20_000, analysis=False, directions=PRESET_DIRECTIONS,
                   polish_stride=POLISH_STRIDE, polish_direct=True, vote_screen=BEST_RACE["race"][-1],
                   table_twins=True, dropped=BEST_DROPPED, **BEST_RACE),
}

#: The lookup budget of ``target_error`` with sum keys but no ``max_lookups``.
DEFAULT_MAX_LOOKUPS = 16

#: Why ``linear.ridge`` is refused where no polish runs (the ridge pairs are the polish's).
RIDGE_NEEDS_POLISH = ("advanced.linear.ridge adds pairs to the polish: set advanced.linear.polish (or use a preset, "
                      "which polishes)")


@dataclasses.dataclass(frozen=True)
class Vote:
    """A choice the execution makes by measurement: its name, what it chooses between, what it reads."""

    name: str
    choices: tuple[str, ...]
    reads: str


@dataclasses.dataclass(frozen=True)
class Plan:
    """What a fit will run (see the module docstring). ``mode``: ``product`` (one log-space product),
    ``auto`` (``target_error`` over products), ``baseline`` (computed, not fitted), ``sum`` (one named
    structure) or ``choose`` (the best of ``candidates`` by validation error). ``options``: the resolved
    options the execution reads (the preset's values filled in)."""

    mode: str
    preset: str | None
    parametrization: str
    mapper: str
    texture_size: int
    sampling: str
    grid_count: int
    validation: int
    light_resolution: int | None
    validation_light: ValidationLight | None  # the lighting the validation pairs read (None: the fit's)
    max_lookups: int | None
    candidates: tuple[Structure, ...]
    linear: LinearOptions | None
    polish: int  # steps of the kept structure's polish (0: none, or every candidate polished by linear.polish)
    polish_stride: int  # the polish fits every k-th grid pair and every k-th view of its off-grid pairs
    polish_direct: bool  # the polish is only the ridge stage straight from the ALS fit (with ridge pairs)
    polish_gate: float  # ... run only where the off-grid residual is above this multiple of the grid's (0: always)
    race: tuple[int, ...]  # ALS sweeps after which the candidates still in are ranked (empty: no race)
    race_keep: tuple[int, ...]  # at most this many continue after each round
    race_margin: float  # ... the lowest and those within this relative margin of its figure
    race_stride: int  # the first round fits every k-th training pair (k > 1: fits of their own)
    race_continue: bool  # ... from which those kept (and the votes' screened alternatives) continue on every pair
    race_strided: bool  # every round on the first round's strided pairs (later rounds continue the strided fits)
    race_margins: tuple[float, ...]  # the margin of each round (``race_margin`` per round, or the preset's own)
    vote_screen: int  # ALS sweeps of the short fits the line and disc votes read first (0: full refits only)
    vote_stride: int  # ... fitted on every k-th training pair
    ridge: int
    line_sizes: tuple[int, ...]
    disc_vote: bool
    analysis: bool
    votes: tuple[Vote, ...]
    options: FitOptions

    def to_dict(self) -> dict[str, Any]:
        """The plan as plain data (what ``--plan`` prints as JSON, and what tests compare)."""
        return {"mode": self.mode, "preset": self.preset, "parametrization": self.parametrization,
                "mapper": self.mapper, "texture_size": self.texture_size,
                "sampling": {"kind": self.sampling, "grid_count": self.grid_count, "validation": self.validation},
                "light_resolution": self.light_resolution,
                "validation_light": None if self.validation_light is None else self.validation_light.record(),
                "max_lookups": self.max_lookups,
                "candidates": [{"label": c.label(), "structure": c.record()} for c in self.candidates],
                "linear": None if self.linear is None else self.linear.model_dump(),
                "polish": self.polish, "polish_stride": self.polish_stride, "polish_direct": self.polish_direct,
                "polish_gate": self.polish_gate,
                "ridge": self.ridge,
                "race": {"sweeps": list(self.race), "keep": list(self.race_keep), "margin": self.race_margin,
                         "stride": self.race_stride, "continue": self.race_continue,
                         "strided": self.race_strided, "margins": list(self.race_margins)},
                "line_sizes": list(self.line_sizes),
                "vote_screen": {"sweeps": self.vote_screen, "stride": self.vote_stride},
                "disc_vote": self.disc_vote, "analysis": self.analysis,
                "votes": [dataclasses.asdict(v) for v in self.votes]}

    def __str__(self) -> str:
        d = self.to_dict()
        s = d["sampling"]
        lines = [f"plan: {self.mode}" + (f" (preset {self.preset})" if self.preset else ""),
                 f"  textures: {self.parametrization} family, {self.mapper} {self.texture_size}",
                 f"  samples: {s['kind']}" + (f", {s['grid_count']} grid pairs" if s["kind"] == "grid" else "")
                 + f", {s['validation']} validation pairs"
                 + (f", lights at resolution {self.light_resolution}" if self.light_resolution else "")]
        if self.validation_light is not None:
            lines.append(f"  validation lighting: {self.validation_light.describe()}")
        if self.max_lookups is not None:
            lines.append(f"  budget: {self.max_lookups} lookups per pixel")
        if self.mode == "sum":
            c = self.candidates[0]
            lines.append(f"  structure: {c.label()} ({c.describe()})")
        elif self.candidates:
            lines.append(f"  candidates ({len(self.candidates)}):")
            lines += [f"    {c.label()} ({c.describe()})" for c in self.candidates]
        if self.race:
            lines.append("  race: " + describe_race(self.race, self.race_keep, self.race_margins,
                                                    self.race_stride, self.race_continue, self.race_strided))
        if self.linear is not None:
            lin = self.linear
            lines.append(f"  linear fit: {lin.method}, {lin.iterations} iterations (stops where one lowers the "
                         f"objective by < {lin.tolerance:g} of it), laplacian {lin.laplacian:g}, nv_balance {lin.nv_balance:g}"
                         + ("" if lin.highlight_start is None else
                            f", highlight terms started by at most {lin.highlight_start} sweeps of their own"))
            if self.polish:
                lines.append(f"  polish: {self.polish} Levenberg-Marquardt steps"
                             + (f", {self.ridge} ridge pairs" if self.ridge else "")
                             + (" from the ALS fit (one stage)" if self.polish_direct else "")
                             + (f" on every {self.polish_stride}th grid pair and off-grid view"
                                if self.polish_stride > 1 else "")
                             + (f", where the kept fit's off-grid residual is above {self.polish_gate:g}x its grid "
                                "residual" if self.polish_gate > 0 else ""))
        if len(self.line_sizes) > 1 or self.mode in ("sum", "choose"):
            lines.append("  line textures: " + " or ".join(str(n) for n in self.line_sizes) + " texels")
        if self.analysis:
            lines.append("  records Mahajan's in-out analysis")
        for v in self.votes:
            choices = ("the candidates" + (" the race keeps" if v.name == "structure" and self.race else "")
                       if v.name in ("structure", "race") else " | ".join(v.choices))
            lines.append(f"  vote {v.name}: {choices}; reads {v.reads}")
        return "\n".join(lines)


def race_of(p: Preset | None, lin: LinearOptions | None, candidates: int) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The rounds of the race (sweep counts, at most how many continue after each) of preset ``p`` for
    ``candidates`` candidates fitted with ``lin``: the preset's rounds below ``linear.iterations`` (a first
    round on every ``race_stride``-th pair, k > 1, up to it: short fits of their own) whose keep is below
    the candidates still in (a round that would keep every one is no round); none without a preset (or
    where the caller passes None: a target_error, a polish of every candidate, no ALS fit)."""
    if p is None or lin is None:
        return (), ()
    rounds, keep, left = [], [], candidates
    strided = p.race_strided and p.race_stride > 1
    for j, (sweeps, k) in enumerate(zip(p.race, p.race_keep)):
        below = sweeps <= lin.iterations if (not rounds or strided) and p.race_stride > 1 else sweeps < lin.iterations
        cut = k < left or (strided and j + 1 < len(p.race) and left > 1)  # a strided round drops by its margin
        if 0 < sweeps and below and cut and (not rounds or sweeps > rounds[-1]):
            rounds.append(int(sweeps))
            keep.append(int(min(k, left)))
            left = min(k, left)
    return tuple(rounds), tuple(keep)


def race_margins_of(p: Preset | None, race: tuple[int, ...]) -> tuple[float, ...]:
    """The margin of each of the planned rounds ``race`` (:func:`race_of`) of preset ``p``: its
    ``race_margins`` by the round's position among the preset's rounds, else ``race_margin``."""
    if p is None or not race:
        return ()
    by_sweeps = {n: (p.race_margins[j] if j < len(p.race_margins) else p.race_margin) for j, n in enumerate(p.race)}
    return tuple(float(by_sweeps[n]) for n in race)


def describe_race(race: tuple[int, ...], keep: tuple[int, ...], margin: float | tuple[float, ...], stride: int = 1,
                  carry: bool = False, strided: bool = False) -> str:
    """The race in words (``--plan``): after each round's sweeps, who continues (``carry``: the kept continue
    on every pair from their strided first-round fit; ``strided``: every round on the strided pairs, the
    last round's kept continue on every pair). ``margin``: one for every round, or each round's."""
    margins = tuple(margin) if isinstance(margin, (tuple, list)) else (float(margin),) * len(race)
    last = len(race) - 1

    def who(j: int, k: int) -> str:
        if stride > 1 and strided and j < last:
            return " continue on the same pairs from where they stopped" if k > 1 else \
                " continues on the same pairs from where it stopped"
        if stride > 1 and (not j or strided):
            return ((" continue on every pair from their short fits" if carry else " start over on every pair")
                    if k > 1 else (" continues on every pair from its short fit" if carry
                                   else " starts over on every pair"))
        return " continue from where they stopped" if k > 1 else " continues from where it stopped"

    return "; ".join(f"after {n} ALS sweeps" + (f" on every {stride}th training pair" if stride > 1 and not j else "")
                     + " the lowest validation figure"
                     + (f" and those within {100 * m:g} % of it (at most {k})" if k > 1 else "")
                     + who(j, k)
                     for j, (n, k, m) in enumerate(zip(race, keep, margins)))


def preset_of(opts: FitOptions) -> str | None:
    """The preset that applies to ``opts`` (see the module docstring)."""
    if opts.preset is not None:
        return opts.preset
    budget = opts.max_lookups if opts.max_lookups is not None else (
        DEFAULT_MAX_LOOKUPS if opts.target_error is not None and opts.is_sum else None)
    if budget is None:
        return None
    return next((name for name, p in PRESETS.items() if budget <= p.lookups), "best")


def budget_of(opts: FitOptions) -> int | None:
    """The lookup budget of the chooser: ``max_lookups``, else the preset's; None for one named fit."""
    if opts.max_lookups is not None:
        return int(opts.max_lookups)
    name = preset_of(opts)
    return None if name is None else PRESETS[name].lookups


def grid_count(opts: FitOptions) -> int:
    """Training pairs of the ``grid`` design: ``sampling.count`` when set, else the preset's, else
    :data:`homofac.fit.sampling.GRID_COUNT`."""
    name = preset_of(opts)
    return opts.sampling.count or (PRESETS[name].grid_count if name else GRID_COUNT)


def validation_count(opts: FitOptions) -> int:
    """Validation pairs: ``sampling.validation`` when given, else the preset's, else
    :data:`~homofac.fit.options.DEFAULT_VALIDATION`."""
    if opts.sampling.validation is not None:
        return int(opts.sampling.validation)
    name = preset_of(opts)
    return PRESETS[name].validation if name else DEFAULT_VALIDATION


def line_sizes(opts: FitOptions) -> tuple[int, ...]:
    """The line sizes the fit tries, the candidates' first: ``(line_size,)`` when given; else with a
    preset whose ``line_ratio`` k is set, ``(32, k x texture_size)`` (the line vote; measured in
    docs/notes: plastic / city 0.055 -> 0.038 with 128 texels, gold / city the other way, so a vote);
    else ``(32,)``."""
    if opts.advanced.line_size is not None:
        return (int(opts.advanced.line_size),)
    name = preset_of(opts)
    fine = PRESETS[name].line_ratio * int(opts.texture_size) if name else 0
    return (structures.LINE_SIZE, fine) if fine and fine != structures.LINE_SIZE else (structures.LINE_SIZE,)


def _lit(target: Target) -> bool:
    return target.kind == "lighting" and getattr(target.fn, "env", None) is not None


def _base(target: Target, opts: FitOptions) -> str:
    """The parametrization whose family the candidates come from: the options'; on a BRDF target the
    options' default (NR, a lighting family) stands for PQP."""
    if target.kind == "brdf" and opts.parametrization == FitOptions.model_fields["parametrization"].default:
        return "PQP"
    return opts.parametrization


def constrained(cands: list[Structure], opts: FitOptions) -> list[Structure]:
    """The candidates that a ``diffuse``, ``advanced.highlights.terms``, extra highlight line or
    ``advanced.highlights.disc`` given in ``opts`` allows (each constrains the search; all candidates
    where none is given)."""
    h = opts.advanced.highlights
    if opts.diffuse is not None:
        cands = [c for c in cands if c.diffuse == opts.diffuse] or cands
    if h.terms is not None:
        cands = [c for c in cands if c.highlights.terms == h.terms] or cands
    for key in (line.key for line in HIGHLIGHT_LINES if getattr(h, line.key) is not None):
        cands = [c for c in cands if getattr(c.highlights, key) == getattr(h, key) or not c.highlights.terms] or cands
    if h.disc:
        cands = [c.with_highlights(disc=True) if c.highlights.terms else c for c in cands]
    return cands


def _vote_figure(ridge: int) -> str:
    return (f"the validation nrmse with a ridge stratum of {ridge} pairs" if ridge
            else "the validation nrmse")


def build_plan(target: Target, preset: str | None = None, overrides: dict | FitOptions | None = None,
               *, samples_given: str | None = None) -> Plan:
    """The plan of fitting ``target`` with ``preset`` and the options ``overrides`` (the keywords of
    :func:`homofac.fit.factorize`, or validated :class:`~homofac.fit.options.FitOptions`), refused in one
    line (:class:`~homofac.errors.HomofacError`) where they cannot run. ``samples_given``: the grid
    direction of samples the caller provides (only the candidates on it are tried)."""
    if isinstance(overrides, FitOptions):
        opts = overrides if preset is None else overrides.model_copy(update={"preset": preset})
    else:
        data = {k: v for k, v in (overrides or {}).items() if v is not None}
        if preset is not None:
            data["preset"] = preset
        opts = validate(FitOptions, data, "")
    if not isinstance(target, Target):
        raise HomofacError(f"factorize needs a homofac Target (brdf_target or lighting_target), got {type(target).__name__}")
    name = preset_of(opts)
    p = PRESETS.get(name) if name else None
    base = _base(target, opts) if (name or opts.is_sum) else opts.parametrization
    mapper = opts.mapper or default_mapper(target.kind)
    is_baseline = opts.parametrization in baselines.BASELINES
    if opts.is_sum and is_baseline:
        raise HomofacError(f"preset, terms, diffuse, nv_factor, max_lookups and linear shape fitted sums; "
                           f"{opts.parametrization} is a baseline (computed, not fitted)")
    if not is_baseline and not (opts.target_error is not None and not opts.is_sum):
        pz.get(base, target.kind)
    budget = budget_of(opts) if opts.is_sum else None
    choosing = budget is not None
    mode = ("choose" if choosing else "sum") if opts.is_sum else (
        "auto" if opts.target_error is not None else "baseline" if is_baseline else "product")
    lit = _lit(target)
    s = opts.sampling
    kind = s.kind if s.kind != "auto" else ("grid" if opts.is_sum and target.kind == "lighting" else "texels")
    given = opts.advanced.linear or LinearOptions()
    if given.ridge and not lit:
        raise HomofacError(RIDGE_NEEDS_ENVIRONMENT)
    if choosing:
        # the candidates: the preset's nv_balance; a polish given explicitly runs on every candidate (as on
        # a named structure), else the preset's polishes the kept one (the polish vote)
        kd = target.kind == "lighting" and sums.has_diffuse(target)
        lin = given.resolved(nv_balance=p.nv_balance if kd else 0.0, tolerance=p.tolerance,
                             highlight_start=p.highlight_start)
        als_fit = lin.method in ("auto", "als") and (kind == "grid" or samples_given is not None)
        steps = 0 if given.polish is not None or target.kind != "lighting" or not als_fit else p.polish
        ridge = given.ridge if given.ridge is not None else (p.ridge if lit and steps else 0)
        if given.polish is not None and ridge and not lin.polish:
            raise HomofacError(RIDGE_NEEDS_POLISH)
    else:
        lin = given.resolved() if opts.is_sum else None
        steps, ridge = 0, 0
        if lin is not None and lin.ridge and not lin.polish:
            raise HomofacError(RIDGE_NEEDS_POLISH)
    direct = bool(steps and ridge and p is not None and p.polish_direct)
    if lin is not None and lin.nv_balance and target.kind != "lighting":
        raise HomofacError(sums.NV_BALANCE_NEEDS_LIGHTING)
    hl = opts.advanced.highlights
    table = (hl.table if hl.table is not None else p.table) if choosing else False
    cands: tuple[Structure, ...] = ()
    votes: list[Vote] = []
    if mode == "sum":
        cands = (opts.structure(base),)
    elif choosing:
        has_d = sums.diffuse_albedo(target) is not None if target.kind == "lighting" else sums.has_diffuse(target)
        pick = structures.ladder if opts.target_error is not None else structures.candidates
        found = constrained(pick(target.kind, budget, parametrization=base, has_diffuse=has_d, highlight=lit,
                                  table=table), opts)
        # the split sum's term only where the target's model has one (a gltf or measured BRDF has none)
        found = [c for c in found if not c.prefiltered or sums.split_sum_possible(target, c)]
        grid = opts.sampling.model_copy(update={"kind": "grid"})
        if samples_given is not None:
            found = [c for c in found if grid_projection(target.kind, c.parametrization, grid) == samples_given] or found
        elif p is not None and p.directions and target.kind == "lighting":
            found = [c for c in found if grid_projection(target.kind, c.parametrization, grid) in p.directions] or found
        if p is not None and p.dropped:
            found = [c for c in found if c.label() not in p.dropped] or found
        if p is not None and p.table_twins:  # the lined candidates whose table twin runs (a superset of them)
            twins = set(found)
            found = [c for c in found if not (c.highlights.terms and not (c.highlights.table or c.highlights.cosine)
                                              and c.with_highlights(table=True) in twins)]
        cands = tuple(found)
    # the race: every candidate's first ALS sweeps rank them; only the lowest continue to the full fit
    race, race_keep = race_of(p if choosing and opts.target_error is None and als_fit and not lin.polish else None,
                              lin, len(cands))
    sizes = line_sizes(opts) if opts.is_sum else ()
    disc = bool(choosing and p is not None and p.disc_vote and hl.disc is None
                and any(c.highlights.terms for c in cands))
    # the line and disc votes read a short fit of the alternative first (the race's first round's sweeps and stride)
    vote_screen = (p.vote_screen if choosing and p is not None and (len(sizes) > 1 or disc) and als_fit
                   and not lin.polish and 0 < p.vote_screen <= lin.iterations - (p.race_stride <= 1) else 0)
    vote_stride = int(p.race_stride) if vote_screen else 1
    carry = bool(race and p.race_stride > 1 and p.race_continue)  # full fits continue from their short fits
    quick = (f"; the alternative fitted in full only where a {vote_screen}-sweep ALS fit"
             + (f" on every {vote_stride}th training pair" if vote_stride > 1 else "")
             + " reads lower than the kept structure's" + (", continuing from that fit" if carry else "")
             if vote_screen else "")
    if choosing:
        figure = _vote_figure(ridge)
        rule = (f"the first whose figure meets target_error {opts.target_error:g}" if opts.target_error is not None
                else "the lowest")
        if race:
            votes.append(Vote("race", tuple(c.label() for c in cands),
                              f"{figure} after each round of ALS sweeps (the race above)"))
        votes.append(Vote("structure", tuple(c.label() for c in cands), f"{figure} ({rule})"))
        if len(sizes) > 1:
            votes.append(Vote("lines", tuple(f"{n} texels" for n in sizes), figure + " of the kept structure" + quick))
        if disc:
            votes.append(Vote("disc", ("point light", "the light's disc"), figure + " of the kept structure" + quick))
        if steps:
            stages = (("ALS fit", "polish + ridge pairs from the ALS fit") if direct else
                      ("ALS fit", "polish") + (("polish + ridge pairs", "polish + ridge pairs from the ALS fit")
                                               if ridge else ()))
            votes.append(Vote("polish", stages, figure + "; the polish is kept only where it falls"))
    env = getattr(target.fn, "env", None)
    res = (getattr(env, "info", None) or {}).get("resolution") if env is not None else None
    vlight = validation_light(target, opts, mode, validation_count(opts))
    advanced = opts.advanced.model_copy(update={"linear": lin if opts.is_sum else opts.advanced.linear})
    resolved = opts.model_copy(update={"parametrization": base, "max_lookups": budget if choosing else opts.max_lookups,
                                       "advanced": advanced})
    return Plan(mode=mode, preset=name, parametrization=base, mapper=mapper, texture_size=int(opts.texture_size),
                sampling=kind, grid_count=grid_count(opts), validation=validation_count(opts),
                light_resolution=int(res) if res else None, validation_light=vlight, max_lookups=budget if choosing else None,
                candidates=cands, linear=lin, polish=int(steps or 0),
                polish_stride=int(p.polish_stride) if steps else 1, polish_direct=direct, ridge=int(ridge or 0),
                polish_gate=float(p.polish_gate) if steps else 0.0,
                race=race, race_keep=race_keep, race_margin=float(p.race_margin) if race else 0.0,
                race_stride=int(p.race_stride) if race else 1,
                race_continue=carry, race_strided=bool(race and p.race_strided and p.race_stride > 1),
                race_margins=race_margins_of(p, race),
                vote_screen=int(vote_screen), vote_stride=vote_stride,
                line_sizes=sizes,
                disc_vote=disc, analysis=bool(choosing and target.kind == "lighting"
                                              and (p.analysis if p else True) or opts.advanced.analysis is not None),
                votes=tuple(votes), options=resolved)


def validation_light(target: Target, opts: FitOptions, mode: str, count: int) -> ValidationLight | None:
    """The lighting the validation pairs read where a vote reads them (``choose``, ``auto``) on a lighting
    target with light texels: ``advanced.validation_light`` where given, else decided by doubling
    (:func:`homofac.fit.validation.decide`); None elsewhere (the fit's own lighting)."""
    if mode not in ("choose", "auto") or count <= 0 or validation.environment(target) is None:
        return None
    if opts.advanced.validation_light is not None:
        return validation.given(target, int(opts.advanced.validation_light))
    return validation.decide(target, count, int(opts.sampling.seed) + 1)


def dumps(plan: Plan) -> str:
    """The plan as indented JSON."""
    return json.dumps(plan.to_dict(), indent=2)


__all__ = ["constrained", "DEFAULT_MAX_LOOKUPS", "PRESET_DIRECTIONS", "PRESETS", "Plan", "Preset", "RIDGE_NEEDS_POLISH", "Vote", "budget_of", "describe_race", "race_margins_of", "race_of",
           "build_plan", "dumps", "grid_count", "line_sizes", "preset_of", "validation_count", "validation_light"]
