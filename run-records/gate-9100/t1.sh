#!/bin/bash
# Task 1 on the held-out maps (seed 1000, 1000 a setting): hint0, the shipped model, RRT, Nearest
O=/root/runs/gate3/t1
for m in "hint0=amat:/root/runs/gate3/hint0.pt" "shipped=amat:general" rrt nearest; do
  name=${m%%=*}; spec=${m#*=}
  for comm in full 4 2; do for n in 0 0.05; do
    out=$O/$name/t1-$comm-$n
    [ -f $out/summary.json ] || (cd /work/hint && PYTHONPATH=/work/hint /work/main/.venv/bin/catmip eval --task task1 --comm $comm --noise $n --method "$spec" --episodes 1000 --seed 1000 --threads 1 --no-progress --argmax-only --out $out > $out.log 2>&1)
  done; done
done
echo done $(date)
