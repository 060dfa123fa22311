#!/bin/sh
# The neglect bound B = 99 over unserved targets, deployed on the five default teams of 3g.
for k in 0 1 2 3 4; do
  sb3-pm evaluate --policy runs/3g/run_s$k/team --graph paper-50 --episodes 10 --seed $((1000000 + 1000 * k)) --neglect-bound 99 --neglect-scope unserved --json runs/b99/eval_s$k.json --no-progress > runs/b99/out_s$k.txt 2>&1
done
