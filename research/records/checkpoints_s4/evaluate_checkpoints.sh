#!/bin/sh
# Each kept checkpoint of the seed-4 run: 5 validation episodes (seeds never used by a sweep) and the
# sweep's 10 test episodes of seed 4.
keep=runs/ckpt_s4_keep; out=runs/ckpt_s4_eval; mkdir -p $out
for d in $keep/rollout_*; do
  n=$(basename $d)
  [ -f $out/val_$n.json ] || sb3-pm evaluate --policy $d --graph paper-50 --episodes 5 --seed 2004000 --json $out/val_$n.json --no-progress > /dev/null 2>&1
  [ -f $out/test_$n.json ] || sb3-pm evaluate --policy $d --graph paper-50 --episodes 10 --seed 1004000 --json $out/test_$n.json --no-progress > /dev/null 2>&1
done
# The finished team (50,000 steps per learner)
sb3-pm evaluate --policy runs/ckpt_s4/team --graph paper-50 --episodes 5 --seed 2004000 --json $out/val_final.json --no-progress > /dev/null 2>&1
sb3-pm evaluate --policy runs/ckpt_s4/team --graph paper-50 --episodes 10 --seed 1004000 --json $out/test_final.json --no-progress > /dev/null 2>&1
