#!/bin/bash
# baselines on the seed-9100 Task-2 gate: the shipped model, the teacher, RRT (2000 maps a setting)
G=/root/runs/gate3/one.sh
for set in "2 0" "2 0.05" "full 0" "full 0.05"; do
  $G teacher rrt-relay-heading $set
  $G rrt rrt $set
  $G shipped amat:general $set
done
echo done $(date)
