r"""Summarize ``sb3-pm evaluate --settling --json`` records on paper-50, per training seed.

For each record: the team's mean avg_uncertainty; how many episodes settle in exactly the graph's
one pairing of targets ({9, 40}, {20, 32}, {19, 36}, {3, 46}, one agent each) and their mean;
the other episodes' mean; the learners that keep one set of places in at least 8 of the episodes;
the episodes in which some target averages 90 or more over the window. Then the pooled figures.

python docs/results/default_machine2/settling_summary.py \
    docs/results/default_machine2/settle_s{0,1,2,3,4}.json
"""

import json
import sys
from collections import Counter
from statistics import mean

PAIRING = {frozenset(pair) for pair in ([9, 40], [20, 32], [19, 36], [3, 46])}
FIXED_IN = 8

in_pairing_all: list[float] = []
others_all: list[float] = []
capped_all = fixed_all = 0
for path in sys.argv[1:]:
    record = json.load(open(path))
    episodes = [
        (row["avg_uncertainty"], s) for row, s in zip(record["episodes"], record["settling"], strict=True)
    ]
    in_pairing = [u for u, s in episodes if {frozenset(p) for p in s["places"]} == PAIRING]
    others = [u for u, s in episodes if {frozenset(p) for p in s["places"]} != PAIRING]
    capped = sum(max(s["target_u"].values()) >= 90 for _, s in episodes)
    agents = len(episodes[0][1]["places"])
    fixed = sum(
        Counter(tuple(s["places"][a]) for _, s in episodes).most_common(1)[0][1] >= FIXED_IN
        for a in range(agents)
    )
    in_pairing_all += in_pairing
    others_all += others
    capped_all += capped
    fixed_all += fixed
    line = f"{path}: {mean(u for u, _ in episodes):.1f}; in the pairing {len(in_pairing)}"
    if in_pairing:
        line += f" ({mean(in_pairing):.1f})"
    if others:
        line += f"; others {mean(others):.1f}"
    print(f"{line}; learners with fixed places {fixed}; episodes with a target averaging >= 90: {capped}")
print(
    f"pooled: in the pairing {len(in_pairing_all)} ({mean(in_pairing_all):.1f}), others {len(others_all)}"
    f" ({mean(others_all):.1f}); learners with fixed places {fixed_all}; target averaging >= 90: {capped_all}"
)
