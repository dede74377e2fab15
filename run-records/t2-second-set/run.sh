#!/bin/bash
# run.sh COMMS...: Task 2 on a second held-out set (seed 4000, 2000 maps), shipped model + planners, argmax
cd /work/main
O=/root/runs/t2-second
for spec in "amat-general=amat:general" rrt utility nearest apf rrt-relay-heading; do
  name=${spec%%=*}
  for comm in "$@"; do for n in 0 0.05; do
    tag=$comm-$n
    [ -f $O/$name/$tag/summary.json ] || .venv/bin/catmip eval --task task2 --comm $comm --noise $n --method "$spec" --episodes 2000 --seed 4000 --threads 1 --no-progress --argmax-only --out $O/$name/$tag > $O/$name-$tag.log 2>&1
  done; done
done
echo done $(date)
