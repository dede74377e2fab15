"""The batch-1 runtime: ``FastAmat`` (``fast_amat``), the same function as ``amat.model.AMAT`` for one
world's decision event in numba, on a weight snapshot (``snapshot``)."""
