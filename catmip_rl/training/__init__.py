"""Training AMAT: one PPO iteration is collect → GAE → PPO update, run by ``train.train``.

* ``config`` — :class:`TrainConfig`, validated when built; ``presets`` — the recipes (``--preset NAME``);
* ``collect`` — the asynchronous rollout of B worlds (the event engine + AMAT's decisions);
* ``gae`` — asynchronous GAE over decision events, value normalisation and the PPO batch built from a
  rollout;
* ``ppo`` — the clipped loss and the update: epochs over minibatches, step control, the LR schedule;
* ``parallel_update`` — the update's gradients computed by several CPU processes;
* ``imitation`` — the DAgger warm start from a planner;
* ``allocator`` — malloc tuning for the update's activations;
* ``run_dir`` — one writer per run folder, the checks before a run starts;
* ``train`` — builds the parts, then runs the loop (logs, evaluation, checkpoints).
"""
