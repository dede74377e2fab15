"""Playing one method under the protocol: the methods by name, your own policy, statistics and plots.

* ``methods`` — the methods by name (planners, window planners, AMAT models, your own ``py:`` policy);
* ``user_policy`` — your policy's factory found and loaded, and the read-only view it is given;
* ``checked_policy`` — your policy as the evaluator plays it: every call guarded, every answer checked;
* ``sandbox`` — a ``py:`` policy played in a worker process that holds no engine (how every ``py:``
  policy plays); its worker: ``workers``; the pipe between them: ``pipe``; its bounds (time, memory,
  processes, folder): ``bounds``; the project's entry points it calls, counted: ``call_counts``;
* ``evaluate`` — settings and the evaluation itself (frozen map sets checked);
* ``stats`` — success intervals, curve bands and paired tests; ``plots`` — every plot the commands draw;
* ``warmup`` — what a command or a worker does before it plays (kernels compiled, threads, its parent).
"""
