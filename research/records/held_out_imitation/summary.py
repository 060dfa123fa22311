"""The imitation transfer teams beside the prior-4 teams and the rule, per graph (summary.txt).

Run from this folder: python summary.py. Reads imit_G_sS.json and ph_G_sS.txt (the pass-held
probe's line) here, and ../held_out_prior4/p4_plain_G_sS.json and territory_patrol_G_sS.json (the
same episodes).
"""
import json, os
import numpy as np
R = ".."
GRAPHS = ["rgg-60", "rooms-4", "cliques-6x8", "karate", "small-world-60", "tree-50"]
def load(path):
    return json.load(open(path)) if os.path.exists(path) else None
print("graph | imitation (x rule) | per seed | with pass-held (x rule) | per seed | prior 4 (x rule) | rule | worst max_neglect: imitation / with pass-held / prior 4 / rule")
for g in GRAPHS:
    runs = [load(f"imit_{g}_s{s}.json") for s in range(3)]
    p4 = [load(f"{R}/held_out_prior4/p4_plain_{g}_s{s}.json") for s in range(3)]
    rule = [load(f"{R}/held_out_prior4/territory_patrol_{g}_s{s}.json") for s in range(3)]
    done = [s for s in range(3) if runs[s] is not None]
    if not done:
        continue
    mean = lambda ds: np.mean([d["mean"]["avg_uncertainty"] for d in ds])
    worst = lambda ds: max(e["max_neglect"] for d in ds for e in d["episodes"])
    im, pr, ru = [runs[s] for s in done], [p4[s] for s in done], [rule[s] for s in done]
    lines = [open(f"ph_{g}_s{s}.txt").read().strip().splitlines()[-1] for s in done]
    held = [float(line.split()[3]) for line in lines]
    held_worst = max(max(int(x) for x in line.split("max_neglect")[1].strip(" []").split(",")) for line in lines)
    print(f"{g} | {mean(im):.1f} ({mean(im)/mean(ru):.2f}) | {' / '.join('%.1f' % d['mean']['avg_uncertainty'] for d in im)} | "
          f"{np.mean(held):.1f} ({np.mean(held)/mean(ru):.2f}) | {' / '.join('%.1f' % h for h in held)} | "
          f"{mean(pr):.1f} ({mean(pr)/mean(ru):.2f}) | {mean(ru):.1f} | {worst(im):g} / {held_worst} / {worst(pr):g} / {worst(ru):g}")
