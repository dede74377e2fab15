#!/bin/bash
# ppo100.sh: the pre-set gate of PPO from coord0 at iteration 100 (T2 and T3, sigma 2 + noise, seed 9100), and coord0 on T3
O=/root/runs/gate3; P=/root/runs/coord-ppo/run/checkpoints/iter_000100.pt
$O/one.sh cppo100 "cppo100=amat:$P" 2 0.05 &
$O/t3one.sh coord0k "coord0=amat:$O/coord0.pt" 2 0.05 1000
wait
$O/t3one.sh cppo100k "cppo100=amat:$P" 2 0.05 1000
echo done $(date)
