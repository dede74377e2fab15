"""The classical planners: baselines by name, their shared core, goals in the D x D window, the RRT kernel.

* ``baselines`` — :func:`make_planner` and :data:`PLANNERS` (``nearest``, ``rrt``, ...);
* ``core`` — :class:`Planner` and what every planner shares (its random stream per world and episode);
* ``window`` — a planner's goal projected into the D x D goal window (the window planners);
* ``rrt`` — the numba RRT kernel the ``rrt`` planners grow;
* ``proposals`` — a planner's proposal as an observation part (:class:`Proposals`, seeded 0): what a
  model with ``AmatConfig.hint`` reads in play, collection and the TorchRL env;
* ``rollout`` — the rollout teacher: ``rrt-relay-coord`` improved by simulated continuations
  (``py:catmip_env/planners/rollout.py:rollout_coord``; registered once its ceiling gate is met).
"""

from __future__ import annotations

from catmip_env.planners.baselines import PLANNERS, make_planner  # noqa: F401  (the path users import)
