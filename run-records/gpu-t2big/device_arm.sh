#!/bin/bash
# GPU arm (issue 37): general-heading-a05's iteration 140 fine-tuned on Task 2 alone (communication drawn per
# episode, with and without 5 % SLAM noise), 512 episodes per world per iteration (8x the CPU arms)
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
W='[{"preset":"task2","activation":[2,5],"comm_sigma_choices":[null,4,2],"num_worlds":512},{"preset":"task2","activation":[2,5],"comm_sigma_choices":[null,4,2],"slam_noise":0.05,"num_worlds":512}]'
timeout 500 python3 -m catmip_rl.cli.main train --preset general-heading --init-from .whl/start.pt \
  --run-dir /tmp/t2 --device cuda --threads 16 --minutes 6.5 --seed 7 --minibatches 8 --micro-batch 0 --lr 1e-4 --no-progress \
  --set iterations=100000 --set anchor_coef=0.05 --set value_warmup_iterations=2 --set eval_every=0 --set checkpoint_every=3 \
  --set "worlds=$W" 2>&1 | tail -8
cp /tmp/t2/metrics.csv /tmp/t2/config.json $OUT/
ls /tmp/t2/checkpoints
python3 -m catmip_rl.cli.main export /tmp/t2 --out $OUT/t2big.pt 2>&1 | tail -3
for f in $(ls /tmp/t2/checkpoints/iter_*.pt | tail -4 | head -3); do python3 -m catmip_rl.cli.main export $f --out $OUT/$(basename $f) 2>&1 | tail -1; done
ls -la $OUT
