"""The ``catmip`` command and the README demo.

* ``main`` — ``catmip train | eval | render | compare | bench paper | bench perf | export``: what each
  command runs, and every user error turned into one line (``catmip = catmip_rl.cli.main:main``);
* ``parser`` — the argument parser and its help; ``args`` — the argument types that check each value;
* ``demo`` — ``make demo``: train AMAT on Task 1 for minutes, evaluate it against the planners.
"""
