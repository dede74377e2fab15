"""AMAT as the robots run it: decentralised execution and the batch-1 numba forward pass.

* ``execution`` — :class:`AmatExecutor` / :class:`CellGoalExecutor`: one decision per communication
  neighbourhood, the messages' sizes;
* ``fast_amat`` — ``FastAmat``, the same function as ``amat.model.AMAT`` for one world's decision event in
  numba, on a weight snapshot (``snapshot``).
"""
