"""Write research/records/held_out/results.json's territory_patrol rows one file per graph and
seed (territory_patrol_<graph>_s<seed>.json), the records `sb3-pm effect` pairs with."""

import json
from pathlib import Path

here = Path(__file__).resolve().parent
results = json.loads((here.parent / "held_out" / "results.json").read_text())
for record in results["results"]["Territory patrol"]:
    graph, seed = record["config"]["graph"], (record["config"]["seed"] - 1_000_000) // 1000
    (here / f"territory_patrol_{graph}_s{seed}.json").write_text(json.dumps(record))
