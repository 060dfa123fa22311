#!/bin/sh
# Scaling: the size-independent teams on 2x and 4x their training graph, and with 2x their agents.
while pgrep -f runs/zs/run.sh > /dev/null; do sleep 10; done
for k in 0 1 2; do
  team=runs/tr/cells/no_encoding/paper-50/seed$k/team
  s=$((1000000 + 1000 * k))
  for g in paper-100 paper-200; do
    [ -f runs/zs/${g}_s$k.json ] || sb3-pm evaluate --policy $team --graph $g --episodes 10 --seed $s --json runs/zs/${g}_s$k.json --no-progress > /dev/null 2>&1
  done
  [ -f runs/zs/agents8_s$k.json ] || sb3-pm evaluate --policy $team --graph paper-50 --agents 8 --episodes 10 --seed $s --json runs/zs/agents8_s$k.json --no-progress > /dev/null 2>&1
  [ -f runs/zs/default_agents8_s$k.json ] || sb3-pm evaluate --policy runs/3g/run_s$k/team --graph paper-50 --agents 8 --episodes 10 --seed $s --json runs/zs/default_agents8_s$k.json --no-progress > /dev/null 2>&1
  for b in grazing local_greedy sit_on_nodes random; do
    [ -f runs/zs/${b}_agents8_s$k.json ] || sb3-pm evaluate --policy $b --graph paper-50 --agents 8 --episodes 10 --seed $s --json runs/zs/${b}_agents8_s$k.json --no-progress > /dev/null 2>&1
  done
done
