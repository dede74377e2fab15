#!/bin/bash
# suite_vs9.sh: the coordinated planner's and model's entries against the planners, the old teacher and amat-general
rm -rf /tmp/lb /tmp/lbout; mkdir -p /tmp/lb
cp /work/main/leaderboard/entries/*.json /tmp/lb/
cp /root/runs/suite-coord/out/entries/*.json /tmp/lb/ 2>/dev/null; cp /root/runs/suite-coordp/entries/*.json /tmp/lb/
for m in rrt nearest apf utility amat_paper rrt-relay-heading rrt-relay-coord amat-general; do
  /work/main/.venv/bin/catmip leaderboard --entries /tmp/lb --out /tmp/lbout/$m --vs $m --force > /tmp/lbout-$m.log 2>&1 || tail -2 /tmp/lbout-$m.log
done
python3 /root/runs/gate3/suite_vs9.py "$@"
