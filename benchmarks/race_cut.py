"""Where a race of strided ALS fits could cut early: read a race study's figures (benchmarks/race_study.py's json).

    python benchmarks/race_cut.py benchmarks/race_study_balanced19.json --final 10 --cuts 2,3,4,5 \
        --margins 0.06,0.08,0.1,0.12 --drop "E'+ROW x3+R"        # docs/notes/speed.md, "balanced, twenty-second session"

For every case (material / environment) the race's pick is the candidate of lowest validation figure after
``--final`` sweeps. For a cut after k sweeps it prints the pick's gap to the lowest figure after k sweeps (how far
behind the pick was there), and per margin how many candidates a cut keeps (those within the margin of the lowest)
and on how many cases the pick is among them. ``--drop``: labels the preset no longer tries (left out).
"""
from __future__ import annotations

import argparse
import collections
import json


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("study")
    ap.add_argument("--final", default="10")
    ap.add_argument("--cuts", default="2,3,4,5")
    ap.add_argument("--margins", default="0.06,0.08,0.1,0.12")
    ap.add_argument("--drop", default="")
    args = ap.parse_args()
    drop = {d for d in args.drop.split(";") if d}
    cases: dict = collections.defaultdict(dict)
    for row in json.load(open(args.study)):
        if row["label"] not in drop:
            cases[row["material"], row["environment"]][row["label"]] = row["nrmse"]
    print(f"{len(cases)} cases, {sum(len(v) for v in cases.values())} candidates; the pick: lowest after {args.final}")
    for k in args.cuts.split(","):
        gaps = {}
        for case, figs in sorted(cases.items()):
            pick = min(figs, key=lambda label: figs[label][args.final])
            low = min(f[k] for f in figs.values())
            gaps[case] = figs[pick][k] / low - 1
        worst = max(gaps, key=gaps.get)
        line = [f"cut after {k}: the pick's largest gap {100 * gaps[worst]:.1f} % ({'/'.join(worst)}), "
                f"the lowest on {sum(g == 0 for g in gaps.values())} cases"]
        for m in (float(x) for x in args.margins.split(",")):
            kept = ok = 0
            for case, figs in cases.items():
                pick = min(figs, key=lambda label: figs[label][args.final])
                low = min(f[k] for f in figs.values())
                inside = [label for label in figs if figs[label][k] <= low * (1 + m)]
                kept += len(inside)
                ok += pick in inside
            line.append(f"margin {100 * m:g} %: {kept} kept, the pick on {ok} of {len(cases)}")
        print("; ".join(line))


if __name__ == "__main__":
    main()
