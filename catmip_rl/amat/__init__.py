"""AMAT, the asynchronous multi-agent transformer.

* ``model`` — :class:`AMAT` (torch ``nn.Module``: training, batched decisions) and :class:`AmatConfig`;
  ``layers`` — its transformer blocks and decoding cache; ``inputs`` — the macro-observation dict;
* ``kernels/`` — the CPU kernels the model runs on (sparse global convolution, small attention; numba);
* ``batch1/`` — the batch-1 runtime: ``FastAmat``, the same function for one world's decision event in
  numba, on a weight snapshot.

Imports run one way: ``model`` imports ``layers`` and ``kernels``; ``batch1`` imports ``model`` and
``kernels``; nothing in the package imports ``batch1``.
"""
