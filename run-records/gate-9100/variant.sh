#!/bin/bash
# c.sh NAME MU RAD TASK COMM NOISE N: a coordination variant (LAM 0) on the gate (seed 9100)
cd /work/main; O=/root/runs/gate3; tag=$([ $4 = task2 ] && echo t2 || echo t3)-$5-$6
[ -f $O/$1/$tag/summary.json ] || LAM=0 MU=$2 RAD=$3 .venv/bin/python /root/runs/multi/variants.py eval --task $4 --comm $5 --noise $6 --method tether --episodes $7 --seed 9100 --threads 1 --no-progress --argmax-only --out $O/$1/$tag > $O/$1-$tag.log 2>&1
