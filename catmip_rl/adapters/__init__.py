"""Adapters to other frameworks: the only modules that import TorchRL or Ray.

* ``torchrl_env`` — :class:`CatmipEnv`, a TorchRL ``EnvBase`` over the event engine;
* ``torchrl_actor`` — AMAT as a TorchRL actor and critic; ``keys`` — their TensorDict keys;
* ``ray_collect`` — rollouts collected by Ray workers (``--collector ray``);
* ``ray_tasks`` — the benchmark's chunks as Ray tasks (``--backend ray``).
"""
