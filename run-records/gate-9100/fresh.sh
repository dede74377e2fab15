#!/bin/bash
# fresh.sh: the coordinated planner on a second fresh Task-2 set (seed 9200, 2,000 maps) and Task 3 (500)
O=/root/runs/gate3
for set in "2 0.05" "2 0" "full 0.05" "full 0"; do
  for m in rrt-relay-coord rrt-relay-heading rrt; do
    ./one.sh s92-$m $m $set 2000 9200
  done
done
echo done $(date)
