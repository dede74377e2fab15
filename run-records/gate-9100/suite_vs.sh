#!/bin/bash
# suite_vs.sh: the hint entry against every planner, the teacher and amat-general, setting by setting
rm -rf /tmp/lb /tmp/lbout; mkdir -p /tmp/lb
cp /work/main/leaderboard/entries/*.json /tmp/lb/
cp /root/runs/suite-hint/entries/*.json /tmp/lb/
for m in rrt nearest apf utility rrt-relay-heading amat-general amat_paper; do
  /work/main/.venv/bin/catmip leaderboard --entries /tmp/lb --out /tmp/lbout/$m --vs $m --force > /tmp/lbout-$m.log 2>&1 || tail -2 /tmp/lbout-$m.log
done
python3 /root/runs/gate3/suite_vs.py
