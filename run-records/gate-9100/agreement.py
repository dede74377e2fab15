"""Scratch: how often a hint model's chosen cell is its hint, per robot class. python agree.py eval ..."""
import sys, atexit
import numpy as np
from catmip_rl.evaluation import execution as E
stats = {"rescuer": [0, 0], "explorer": [0, 0]}
orig = E.CellGoalExecutor.act
def act(self, engine):
    h = {}
    real = self.hinter.act
    def rec(eng):
        out = real(eng); h["v"] = np.asarray(out).copy(); return out
    self.hinter.act = rec
    try:
        a = orig(self, engine)
    finally:
        self.hinter.act = real
    if "v" in h:
        act_ = engine.active & ~engine.state.done[:, None]
        for b, i in zip(*np.nonzero(act_)):
            k = "rescuer" if engine.state.can_rescue[b, i] else "explorer"
            stats[k][0] += int(a[b, i] == h["v"][b, i]); stats[k][1] += 1
    return a
E.CellGoalExecutor.act = act
atexit.register(lambda: print("AGREE", {k: (v[0] / max(v[1], 1), v[1]) for k, v in stats.items()}))
from catmip_rl.cli.main import main
sys.argv = ["catmip", *sys.argv[1:]]
main()
