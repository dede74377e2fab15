"""Scratch planner variants (not in the repo): rrt-relay-heading with a team-cohesion term in RRT's
cluster score. Usage: LAM=0.5 WHO=rescuer python variants.py eval --method tether ...

The file as it ran for the ninth sitting's gates (it repeats RRT.choose's loop to add its terms). The
variant that was kept, LAM=0 MU=0.5 RAD=7, is catmip_env.planners.RRTRelayCoord through RRT's crowding
hook; on 30 Task-3 maps the two played the same episodes."""
import os, sys
import numpy as np
from catmip_env import planners as PL
from catmip_env.kernels.comms import estimated_cells
from catmip_env.planner_core import SQUARE
from catmip_env.kernels.rrt import grow_rrt

LAM = float(os.environ.get("LAM", "0.5"))
MU = float(os.environ.get("MU", "0"))
RAD = float(os.environ.get("RAD", "7"))
WHO = os.environ.get("WHO", "rescuer")  # whose score gets the term: rescuer, explorer, both


class Tether(PL.RRTRelayHeading):
    name = "tether"

    def mates(self, ctx):
        st, b, i = ctx.engine.state, ctx.b, ctx.i
        row = slice(i, i + 1)
        cells = estimated_cells(st.heard_tick[b, row], st.heard_pos[b, row], st.heard_goal[b, row],
                                st.ticks[b], st.speed[b])[0]
        want = ~st.can_rescue[b] if ctx.can_rescue else st.can_rescue[b]
        js = [j for j in np.flatnonzero(want) if j != i and st.heard_tick[b, i, j] >= 0]
        return cells[js] if js else None

    def goals(self, ctx):
        """The cells the robot's teammates were heading for, from its own memory (no news: none)."""
        st, b, i = ctx.engine.state, ctx.b, ctx.i
        js = [j for j in range(st.pos.shape[1]) if j != i and st.heard_tick[b, i, j] >= 0
              and st.heard_goal[b, i, j, 0] >= 0]
        return st.heard_goal[b, i, js] if js else None

    def choose(self, ctx):
        if self._rescuer_to_tell(ctx) is not None:
            return PL.Relay.choose(self, ctx)
        applies = WHO == "both" or (WHO == "rescuer") == ctx.can_rescue
        mates = self.mates(ctx) if applies and not ctx.knows_target and LAM else None
        goals = self.goals(ctx) if MU and not ctx.knows_target else None
        h, w = ctx.explored.shape
        targets = np.empty((PL.RRT_TARGETS, 2), np.int64)
        u = self.rng.random((PL.RRT_ITERATIONS, 2))
        n = grow_rrt(ctx.explored, ctx.occupied, float(ctx.own[0]), float(ctx.own[1]), u, PL.RRT_STEP,
                     PL.RRT_TARGETS, targets)
        if n == 0:
            return None
        cells = np.zeros((h, w), bool)
        cells[targets[:n, 0], targets[:n, 1]] = True
        labels, k_n = PL._label8(cells)
        counts = ctx.unexplored_counts() / float(SQUARE * SQUARE)
        reach = ctx.dist[ctx.dist >= 0]
        far = max(int(reach.max()), 1)
        best, best_score = None, -np.inf
        for k in range(1, k_n + 1):
            members = np.argwhere(labels == k)
            ok = (ctx.dist[members[:, 0], members[:, 1]] >= 0) & ctx.valid[members[:, 0], members[:, 1]]
            members = members[ok]
            if len(members) == 0:
                continue
            centre = members.mean(axis=0)
            m = members[np.argmin(((members - centre) ** 2).sum(axis=1))]
            score = counts[m[0], m[1]] - ctx.dist[m[0], m[1]] / far
            if mates is not None:
                score -= LAM * np.hypot(*(mates - m).T).min() / max(h, w)
            if goals is not None and len(goals):
                d = np.hypot(*(goals - m).T)
                score -= MU * np.clip(1 - d / RAD, 0, None).sum()
            if score > best_score:
                best, best_score = (int(m[0]), int(m[1])), score
        return best


PL.PLANNERS["tether"] = Tether
from catmip_rl.cli.main import main
sys.argv = ["catmip", *sys.argv[1:]]
main()
