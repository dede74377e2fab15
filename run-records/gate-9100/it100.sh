#!/bin/bash
# wait for the general-hint run's iteration 100, export it, gate it on T2 and T3 with sigma 2 and noise
while [ ! -f /root/runs/general-hint/checkpoints/iter_000100.pt ]; do sleep 20; done
sleep 5
cd /work/main && .venv/bin/catmip export /root/runs/general-hint/checkpoints/iter_000100.pt --out /root/runs/gate3/hint100.pt --force
/root/runs/gate3/one.sh hint100 amat:/root/runs/gate3/hint100.pt 2 0.05 &
/root/runs/gate3/t3one.sh hint100 amat:/root/runs/gate3/hint100.pt 2 0.05
wait
echo done $(date)
