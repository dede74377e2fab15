#!/bin/bash
# t1c.sh COMM...: Task 1 on the held-out maps (seed 1000, 1,000 a setting): coord0
O=/root/runs/gate3/t1; mkdir -p $O/coord0
for comm in "$@"; do for n in 0 0.05; do
  out=$O/coord0/t1-$comm-$n
  [ -f $out/summary.json ] || (cd /work/main && .venv/bin/catmip eval --task task1 --comm $comm --noise $n --method "coord0=amat:/root/runs/gate3/coord0.pt" --episodes 1000 --seed 1000 --threads 1 --no-progress --argmax-only --out $out > $out.log 2>&1)
done; done
echo done $(date)
