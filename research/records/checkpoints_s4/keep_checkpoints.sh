#!/bin/sh
# Start next to: sb3-pm train --config ippo --env paper-50 --seed 4 --out runs/ckpt_s4
# copy every checkpoint of the run as it appears (the trainer keeps only its last two)
run=runs/ckpt_s4; keep=runs/ckpt_s4_keep; mkdir -p $keep
while true; do
  for d in $run/checkpoints/rollout_*; do
    [ -d "$d" ] || continue
    n=$(basename $d)
    [ -d $keep/$n ] || { sleep 3; cp -r $d $keep/$n; }
  done
  [ -f $run/DONE ] && break
  [ -d $run/team ] && [ -f $run/team/*.zip ] 2>/dev/null && sleep 30 && break
  sleep 10
done
