"""What runs around the env on a machine: numba's compiled kernels (``numba_cache``, ``warmup``), the
machine's description every result records (``machine``) and files written atomically (``files``)."""
