. /work/main/.venv/bin/activate
for S in 0 1 2 3 4; do
  sb3-pm evaluate --policy /work/runs/3g/run_s$S --graph paper-50 --episodes 10 --seed $((1000000 + 1000 * S)) --stochastic --no-progress --json stoch_s$S.json > stoch_s$S.log 2>&1
done
echo done > done.txt
