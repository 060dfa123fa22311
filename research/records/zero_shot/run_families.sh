#!/bin/sh
# Zero-shot evaluations of the size-independent teams (transfer.yml's no_encoding cells).
for k in 0 1 2; do
  team=runs/tr/cells/no_encoding/paper-50/seed$k/team
  while [ ! -f runs/tr/cells/no_encoding/paper-50/seed$k/DONE ]; do sleep 20; done
  for g in rgg-60 rooms-4 cliques-6x8 karate; do
    out=runs/zs/${g}_s$k.json
    [ -f $out ] || sb3-pm evaluate --policy $team --graph $g --episodes 10 --seed $((1000000 + 1000 * k)) --json $out --no-progress > /dev/null 2>&1
  done
done
