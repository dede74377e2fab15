#!/bin/bash
# one.sh NAME METHOD COMM NOISE [EPISODES] [SEED]: Task 2 gate (fresh seed 9100), argmax
cd /work/main; O=/root/runs/gate3; n=${5:-2000}; s=${6:-9100}
tag=t2-$3-$4
[ -f $O/$1/$tag/summary.json ] || .venv/bin/catmip eval --task task2 --comm $3 --noise $4 --method "$2" --episodes $n --seed $s --threads 1 --no-progress --argmax-only --out $O/$1/$tag > $O/$1-$tag.log 2>&1
