#!/bin/bash
# t3one.sh NAME METHOD COMM NOISE [EPISODES]: Task 3 gate (seed 9100), argmax
O=/root/runs/gate3; n=${5:-500}; tag=t3-$3-$4
[ -f $O/$1/$tag/summary.json ] || (cd /work/main && .venv/bin/catmip eval --task task3 --comm $3 --noise $4 --method "$2" --episodes $n --seed 9100 --threads 1 --no-progress --argmax-only --out $O/$1/$tag > $O/$1-$tag.log 2>&1)
