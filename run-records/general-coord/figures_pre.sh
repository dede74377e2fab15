#!/bin/bash
# Figures 6-10 without AMAT (general): the runs the next sitting's --resume reads back (then adds the shipped coord model)
cd /work/main
P=run-records/marl-pool4/policies.py; S=run-records/task1-seeds
L=nearest,utility,rrt,apf,random-frontier,random-rescue,random-uniform,window:nearest
AMAT=(--method "AMAT (paper)=amat:paper" --method "AMAT (task1)=amat:task1")
MARL=(--method "MAPPO=py:$P:mappo_s0,py:$P:mappo_s1,py:$P:mappo_s2"
      --method "IPPO=py:$P:ippo_s0,py:$P:ippo_s1,py:$P:ippo_s2")
O=/root/runs/paper-out
.venv/bin/catmip bench paper --figure 6 --methods $L "${AMAT[@]}" "${MARL[@]}" --out $O --no-progress \
    --method "AMAT task1-warm recipe=amat:$S/amat_task1_s0.pt,amat:$S/amat_task1_s1.pt,amat:$S/amat_task1_s2.pt" || exit 1
for f in 7 8 9 10; do
  .venv/bin/catmip bench paper --figure $f --methods $L "${AMAT[@]}" "${MARL[@]}" --out $O --no-progress || exit 1
done
echo done $(date)
