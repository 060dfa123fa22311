"""The imitating transfer teams under the filter's rule 10 (pass_held), zoo/ippo_transfer.yml's three
seeds, beside the same teams without it and the rule, per graph (summary.txt).

Run from this folder: python summary.py. Reads heldout_G_sS.json here, and
../held_out_imitation/imit_G_sS.json and ../held_out_prior4/territory_patrol_G_sS.json and
p4_plain_G_sS.json (the same episodes). From ../transfer_keep_moving/ (rules 10 and 11 against
rule 10 alone): python ../transfer_pass_held/summary.py ../transfer_pass_held/heldout "rules 10 and 11" "rule 10 alone"
"""

import json
import sys

import numpy as np

#: The runs compared, and the two columns' names: this folder's runs' and theirs.
AGAINST, OURS, THEIRS = (sys.argv[1:4] if len(sys.argv) > 3 else ("../held_out_imitation/imit", "rule 10", "without rule 10"))

GRAPHS = ["rgg-60", "rooms-4", "cliques-6x8", "karate", "small-world-60", "tree-50"]


def load(path):
    with open(path) as file:
        return json.load(file)


def mean(runs, key="avg_uncertainty"):
    return float(np.mean([run["mean"][key] for run in runs]))


def worst(runs):
    return max(episode["max_neglect"] for run in runs for episode in run["episodes"])


print(
    f"graph | {OURS} (x rule) | per seed | x lower bound | {THEIRS} (x rule) | prior 4 (x rule) | rule"
    f" | worst max_neglect: {OURS} / {THEIRS} / rule"
)
for graph in GRAPHS:
    shipped = [load(f"heldout_{graph}_s{s}.json") for s in range(3)]
    without = [load(f"{AGAINST}_{graph}_s{s}.json") for s in range(3)]
    prior4 = [load(f"../held_out_prior4/p4_plain_{graph}_s{s}.json") for s in range(3)]
    rule = [load(f"../held_out_prior4/territory_patrol_{graph}_s{s}.json") for s in range(3)]
    r = mean(rule)
    seeds = " / ".join(f"{run['mean']['avg_uncertainty']:.1f}" for run in shipped)
    print(
        f"{graph} | {mean(shipped):.1f} ({mean(shipped) / r:.2f}) | {seeds} | {mean(shipped, 'x_lower_bound'):.2f} | "
        f"{mean(without):.1f} ({mean(without) / r:.2f}) | {mean(prior4):.1f} ({mean(prior4) / r:.2f}) | {r:.1f} | "
        f"{worst(shipped):g} / {worst(without):g} / {worst(rule):g}"
    )
