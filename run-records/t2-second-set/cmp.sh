#!/bin/bash
# cmp.sh TAG: amat-general against each planner on the second set (paired)
cd /work/main; O=/root/runs/t2-second
for p in rrt utility nearest apf rrt-relay-heading; do
  a=$O/amat-general/$1; b=$O/$p/$1
  [ -f $a/summary.json ] && [ -f $b/summary.json ] || { echo "$1 $p: missing"; continue; }
  .venv/bin/catmip compare $a $b --out /tmp/c2-$1-$p --force >/dev/null 2>&1
  python3 -c "
import csv
r=next(csv.DictReader(open('/tmp/c2-$1-$p/paired.csv')))
print('$1', r['maps'], r['method_a'], r['success_a'], r['method_b'], r['success_b'], 'diff a-b %+.4f [%+.3f, %+.3f]'%(float(r['diff']),float(r['ci_low']),float(r['ci_high'])))"
done
