"""AMAT, the asynchronous multi-agent transformer.

* ``model`` — :class:`AMAT` (torch ``nn.Module``: training, batched decisions) and :class:`AmatConfig`;
  its transformer blocks and decoding cache in ``layers``;
* ``fast`` — ``FastAmat``: the same function for one world's decision event, in numba; its weights
  snapshot in ``fast_weights``, its small kernels in ``numba_ops``;
* ``conv_kernels`` — the sparse convolutions of the maps, shared by ``fast`` and ``sparse_conv``;
* ``sparse_conv``, ``small_attention`` — hand-written autograd kernels the model uses on CPU.

Imports run one way: ``model`` imports ``layers`` (which imports ``small_attention``) and ``sparse_conv``
(which imports ``conv_kernels``, which imports ``numba_ops``); ``fast`` imports ``model``, ``fast_weights``,
``conv_kernels`` and ``numba_ops``; nothing in the package imports ``fast``.
"""
