"""AMAT, the asynchronous multi-agent transformer.

* ``model`` — :class:`AMAT` (torch ``nn.Module``: training, batched decisions) and :class:`AmatConfig`;
  ``layers`` — its transformer blocks and decoding cache; ``inputs`` — the macro-observation dict;
* ``kernels/`` — the CPU kernels the model runs on (sparse global convolution, small attention; numba);
* ``onboard/`` — AMAT as the robots run it: decentralised execution (``AmatExecutor``) on ``FastAmat``,
  the same function for one world's decision event in numba, on a weight snapshot.

Imports run one way: ``model`` imports ``layers`` and ``kernels``; ``onboard`` imports ``model`` and
``kernels``; nothing in the package imports ``onboard``.
"""
