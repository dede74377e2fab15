"""The CPU kernels AMAT runs on (numba; speed only, the model's function is ``amat.model``'s):

* ``sparse_conv`` — the global map convolution + max-pool on the uint8 maps, with its autograd (training);
* ``small_attention`` — attention over an event's few tokens in numba loops, with its autograd;
* ``conv`` — the sparse convolution kernels shared by ``sparse_conv`` and the batch-1 runtime;
* ``numba_ops`` — the small numba operations they are built from.
"""
