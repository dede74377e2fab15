"""Evaluating policies on the paper's protocol.

* ``methods`` — the methods by name (planners, window planners, AMAT models, your own ``py:`` policy);
* ``user_policy`` — your policy at the PettingZoo or engine level, checked at every call;
* ``execution`` — decentralised AMAT execution (per-neighbourhood decisions, message sizes);
* ``evaluate`` — settings and the evaluation itself (frozen map sets checked);
* ``compare`` — paired per-map differences and across-seed statistics with CIs;
* ``results_check`` — what ``compare`` checks in the result folders it reads (counts, ranges, copies);
* ``plots`` — every plot the evaluation commands draw (the paper figures, ``catmip compare``'s);
* ``paper`` — the paper's figures: every method on every panel, tables and plots.
"""
