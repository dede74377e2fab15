"""The benchmark product: the suite, its entries and leaderboard, the paper's figures, and comparisons.

* ``suite`` — ``catmip bench suite``: every method on every setting of a split, written as an entry;
  ``estimate`` — how long it will take, each method timed on a few maps first;
* ``entry`` — what a suite entry is (its runs, class, maps); ``entry_check`` — what the leaderboard accepts;
* ``leaderboard`` — the ranked page of the committed entries; ``replay`` — an entry's maps played again;
* ``paper`` — the paper's figures: every method on every panel, tables and plots;
* ``jobs`` — the (method, setting) jobs the suite and the figures run in parallel processes;
  ``resume_check`` — what a resumed grid checks in a finished run's folder before reading it back;
* ``compare`` — paired per-map differences and across-seed statistics of result folders;
* ``results_check`` — what ``compare`` checks in the result folders it reads (counts, ranges, copies).
"""
