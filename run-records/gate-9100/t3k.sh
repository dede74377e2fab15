#!/bin/bash
# t3k.sh: Task 3 σ=2 + noise, 1,000 maps of seed 9100: the teacher, RRT, Nearest, then the hint models
G=/root/runs/gate3/t3one.sh
$G teacherk rrt-relay-heading 2 0.05 1000
$G rrtk rrt 2 0.05 1000
$G nearestk nearest 2 0.05 1000
echo planners done $(date)
