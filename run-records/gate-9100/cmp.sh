#!/bin/bash
# cmp.sh A B TAG: paired difference A - B on gate3's TAG set (catmip compare orders the pair itself)
O=/root/runs/gate3; a=$O/$1/$3; b=$O/$2/$3
[ -f $a/summary.json ] && [ -f $b/summary.json ] || { echo "$3 $1 vs $2: missing"; exit; }
/work/main/.venv/bin/catmip compare $a $b --out /tmp/c3-$1-$2-$3 --force >/dev/null 2>&1
python3 -c "
import csv
r=next(csv.DictReader(open('/tmp/c3-$1-$2-$3/paired.csv')))
d, lo, hi = float(r['diff']), float(r['ci_low']), float(r['ci_high'])
if r['method_a'] != '$1' and r['method_b'] != '$2':  # reported as B - A: flip
    d, lo, hi = -d, -hi, -lo
print('$3', r['maps'], '$1 - $2', 'diff %+.4f [%+.3f, %+.3f]'%(d, lo, hi), '(', r['method_a'], r['success_a'], r['method_b'], r['success_b'], ')')"
