#!/bin/bash
# coord_seeds.sh: general-coord's recipe with training seeds 14 and 15 (seed 13 is coord0), exported as the recipe does,
# then each on the T2 and T3 sigma-2 + noise gates (seed 9100): is "level with the proposer, above RRT" the recipe's or one seed's?
cd /work/main
for s in 14 15; do
  R=/root/runs/coord-s$s
  [ -f $R/coord.pt ] || { nice -n 5 .venv/bin/catmip train --preset general-coord --init-from run-records/general-memory/amat_general.pt \
      --run-dir $R/run --threads 1 --seed $s --iterations 1 --set eval_every=0 --set checkpoint_every=1 --no-progress > $R.log 2>&1 || exit 1
    .venv/bin/catmip export $R/run/checkpoints/iter_000000.pt --out $R/coord.pt --half >> $R.log 2>&1 || exit 1; }
done
for s in 14 15; do
  /root/runs/gate3/one.sh coord-s$s "coord-s$s=amat:/root/runs/coord-s$s/coord.pt" 2 0.05 &
done; wait
for s in 14 15; do
  /root/runs/gate3/t3one.sh coord-s${s}k "coord-s$s=amat:/root/runs/coord-s$s/coord.pt" 2 0.05 1000 &
done; wait
echo done $(date)
