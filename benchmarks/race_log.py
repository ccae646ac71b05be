"""The race's rounds from a fit's stage log (``benchmarks/presets.py --log`` on stderr): per round, each candidate's
figure (the validation nrmse the race ranks by) and CPU seconds, and each figure's gap to the round's lowest.

    PYTHONPATH=src python benchmarks/presets.py --presets best --cases metal/forest --truth-limit 256 --no-split-sum \\
        --log --preset-values '{"race": [10, 20, 30], "race_keep": [99, 99, 1], "race_strided": true,
        "race_margins": [1e9, 1e9, 0.0]}' --json /tmp/r.json 2> /tmp/forest.log
    python benchmarks/race_log.py metal/forest /tmp/forest.log [more case/log pairs] > benchmarks/presets_best19_race.json

With a first-round margin of 1e9 every candidate runs every round (the race's evidence: where the last round's
lowest stood after each earlier round). A candidate's CPU seconds in a round run from the previous candidate's
"measuring errors" line to its own (its sweeps, and the previous one's measurement); in the first round they include
its start and its programs' compilation; the round's ``tail`` is the last measurement and the figures' scoring.
A log needs only its race lines: the fit may be stopped once the last round is logged.
"""

from __future__ import annotations

import json
import re
import sys

LINE = re.compile(r"\s*([\d.]+)\s+([\d.]+) (.*)")
RACE = re.compile(r"race \((\d+) ALS sweeps\): (.*?) ((?:E'|NROW|ROW|SS)\S*.*); continue: (.*)")


def rounds(text: str) -> list[dict]:
    """The race's rounds in a stage log: sweeps, labels, figures, gaps to the lowest, CPU per candidate."""
    rows = [(float(m[1]), float(m[2]), m[3]) for m in map(LINE.match, text.splitlines()) if m]
    out, last = [], None
    start = next(i for i, r in enumerate(rows) if r[2].startswith("fitting"))
    cpu0, marks = rows[start - 1][1], []
    for i, (_, cpu, msg) in enumerate(rows[start:], start):
        if msg == "measuring errors":
            marks.append(cpu)
        m = RACE.match(msg)
        if not m:
            continue
        pairs = [p.rsplit(" ", 1) for p in m[3].split(", ")]
        labels, figs = [p[0] for p in pairs], [float(p[1]) for p in pairs]
        low = min(figs)
        cpus = [b - a for a, b in zip([cpu0] + marks[:-1], marks)]
        out.append({"sweeps": int(m[1]), "figure": m[2], "labels": labels, "figures": figs,
                    "gap": [f / low - 1.0 for f in figs], "cpu_s": cpus, "tail_s": cpu - (marks[-1] if marks else cpu0),
                    "round_cpu_s": cpu - cpu0, "continue": m[4].split(", ")})
        cpu0, marks, last = cpu, [], i
    return out


def main(argv: list[str]) -> int:
    cases = {}
    for case, path in zip(argv[::2], argv[1::2]):
        rs = rounds(open(path).read())
        final = rs[-1]
        winner = final["labels"][final["figures"].index(min(final["figures"]))]
        cases[case] = {"winner": winner, "winner_gap": {r["sweeps"]: r["gap"][r["labels"].index(winner)]
                                                        for r in rs if winner in r["labels"]}, "rounds": rs}
    print(json.dumps(cases, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
