"""The engine room: the numba kernels every world runs on, and the arrays they share.

* ``state`` — :class:`WorldState`, the worlds' arrays (one row per world), and their kernel views;
* ``rng`` — each world's random stream (a counter-based generator the kernels draw from), and the block
  of uniforms a map is drawn from;
* ``seeding`` — numpy's seed sequences, PCG64 and ``Generator`` draws, bit for bit, inside a kernel;
* ``mapgen`` — the maps: ``generate``, rooms with their walls and doorways;
* ``episodes`` — a reset's new episodes loaded into their worlds in one call a thread;
* ``placement`` — what a map holds besides its rooms: obstacles, target, clues, the robots' start;
* ``sensing`` — what a robot sees, and the maps it shares with the robots it is linked to;
* ``dynamics`` — one primitive tick: moves, collisions, perception, communication, rewards;
* ``bfs`` — shortest paths on a robot's map (the controller's and the planners');
* ``macro`` — macro-actions: the controller that walks a robot to its goal, the run to the next event,
  the action masks;
* ``activation`` — the robots' macro state: macro-action ends, activation, goal assignment;
* ``observe`` — the observations (global and local maps) built from a robot's belief;
* ``primitive`` — a small batch's primitive step (tick and observations) in one call, at the kernel's
  compiled entry.

Nothing here is a public API: ``catmip_env``'s world, engine and env are built on it.
"""
