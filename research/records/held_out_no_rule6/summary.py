"""Summary of the no-rule-6 transfer teams against the prior-4 teams and the rule, per graph.

Run from this folder: python summary.py. Reads no_rule6_G_sS.json here, and
../held_out_prior4/p4_plain_G_sS.json and territory_patrol_G_sS.json (the same episodes).
"""

import json
from pathlib import Path

GRAPHS = ["rgg-60", "rooms-4", "cliques-6x8", "karate", "small-world-60", "tree-50"]
HERE = Path(__file__).resolve().parent
PRIOR4 = HERE.parent / "held_out_prior4"


def metric(path: Path, key: str) -> tuple[float, float]:
    """The record's mean of ``key`` over its episodes, and its worst episode."""
    record = json.loads(path.read_text())
    values = [episode[key] for episode in record["episodes"]]
    return sum(values) / len(values), max(values)


print("graph | no rule 6 (x rule) | per seed | prior 4 (x rule) | rule | worst max_neglect: no rule 6 / prior 4 / rule | collisions: no rule 6 / prior 4")
for graph in GRAPHS:
    rows = {}
    for name, folder, prefix in (("no_rule6", HERE, "no_rule6"), ("prior4", PRIOR4, "p4_plain"), ("rule", PRIOR4, "territory_patrol")):
        files = [folder / f"{prefix}_{graph}_s{seed}.json" for seed in range(3)]
        rows[name] = {
            "means": [metric(f, "avg_uncertainty")[0] for f in files],
            "worst": max(metric(f, "max_neglect")[1] for f in files),
            "collisions": sum(metric(f, "collisions")[0] for f in files) / 3 if name != "rule" else None,
        }
    mean = {name: sum(row["means"]) / 3 for name, row in rows.items()}
    print(
        f"{graph} | {mean['no_rule6']:.1f} ({mean['no_rule6'] / mean['rule']:.2f}) | "
        + " / ".join(f"{m:.1f}" for m in rows["no_rule6"]["means"])
        + f" | {mean['prior4']:.1f} ({mean['prior4'] / mean['rule']:.2f}) | {mean['rule']:.1f} | "
        + f"{rows['no_rule6']['worst']:.0f} / {rows['prior4']['worst']:.0f} / {rows['rule']['worst']:.0f} | "
        + f"{rows['no_rule6']['collisions']:.1f} / {rows['prior4']['collisions']:.1f}"
    )
