"""Play amat:general on one turned/reflected view of each decision (not pooled): is the model orientation-bound?"""
import sys, torch
from catmip_rl.amat import symmetry
from catmip_rl.amat.symmetry import Views
from catmip_rl.checkpoint import load_model
from catmip_rl.evaluation.execution import CellGoalExecutor

T = 0

class OneView(Views):
    def pool(self, logp):  # every view acts on view T's policy
        t, hw = self.count, logp.shape[-1]
        per_view = logp.view(t, -1, hw)
        in_map = torch.gather(per_view, 2, self.inv[:, None, :].expand_as(per_view))[T]
        return in_map[:, self.src].transpose(0, 1).reshape(-1, hw)

class Ex(CellGoalExecutor):
    def _views_of(self, side):
        if self._views is None: self._views = OneView(8, side)
        return self._views

def factory(cfg, seed):
    return Ex(load_model("general"), loop_guard=True, views=8)
