#!/bin/bash
# usage: peak_tree.sh CMD... ; prints the command's wall time and the peak summed RSS (MB) of its process tree, sampled every 0.5 s
"$@" > "${PEAK_TREE_OUT:-peak_tree.out}" 2>&1 &
pid=$!
peak=0
start=$(date +%s.%N)
while kill -0 $pid 2>/dev/null; do
  pids=$(pstree -p $pid 2>/dev/null | grep -o '([0-9]\+)' | tr -d '()' | tr '\n' ',')
  rss=$(ps -o rss= -p ${pids%,} 2>/dev/null | awk '{s+=$1} END {print int(s/1024)}')
  [ -n "$rss" ] && [ "$rss" -gt "$peak" ] && peak=$rss
  sleep 0.5
done
end=$(date +%s.%N)
echo "wall $(echo "$end - $start" | bc) s, peak tree RSS $peak MB"
grep avg_unc "${PEAK_TREE_OUT:-peak_tree.out}"
