#!/bin/sh
# 2x the agents: the family-trained teams of zero_shot.yml (trained/transfer/family-er/seed<k>)
# with 8 agents on paper-50, on the comparison sweep's episodes of each seed.
for k in 0 1 2; do
  sb3-pm evaluate --policy results/zero_shot/trained/transfer/family-er/seed$k/team --graph paper-50 \
    --agents 8 --episodes 10 --seed $((1000000 + 1000 * k)) --json agents8_family_s$k.json
done
