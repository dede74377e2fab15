"""Evaluating policies on the paper's protocol.

* ``execution`` — decentralised AMAT execution (per-neighbourhood decisions, message sizes);
* ``evaluate`` — methods (AMAT, planners, window planners), settings and the evaluation itself;
* ``paper`` — the paper's figures: every method on every panel, tables and plots.
"""
