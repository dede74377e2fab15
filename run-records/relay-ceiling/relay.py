"""Scratch experiment (issue 37): how much would carrying the news of a found target to a rescuer buy
over RRT under lossy communication? Explorers that know the target go to a rescuer that does not."""

import numpy as np

from catmip_env.constants import TARGET_BIT
from catmip_env.planners import RRT


def _toward(ctx, cell):
    """The valid reachable goal nearest (Euclid) to ``cell``, ties by path distance."""
    ok = ctx.valid & (ctx.dist >= 0)
    ok[ctx.own] = False
    cells = np.argwhere(ok)
    if len(cells) == 0:
        return None
    d = ((cells - np.asarray(cell)) ** 2).sum(axis=1) * 1000 + ctx.dist[cells[:, 0], cells[:, 1]]
    r, c = cells[np.argmin(d)]
    return int(r), int(c)


class RelayOracle(RRT):
    """Privileged: knows which rescuers do not know the target and where they are."""

    name = "rrt-relay-oracle"
    goal_mode = "cell"
    deterministic = True

    def act(self, engine):
        self._engine = engine
        return super().act(engine)

    def choose(self, ctx):
        st = self._engine.state
        b = ctx.b
        if not ctx.can_rescue and ctx.knows_target:
            tr, tc = ctx.target
            ign = [
                j
                for j in range(st.pos.shape[1])
                if st.can_rescue[b, j] and not (st.belief[b, j, tr, tc] & TARGET_BIT)
            ]
            if ign:
                d = [np.hypot(*(st.pos[b, j] - np.asarray(ctx.own))) for j in ign]
                g = _toward(ctx, st.pos[b, ign[int(np.argmin(d))]])
                if g is not None:
                    return g
        return super().choose(ctx)


class RelayMemory(RRT):
    """Fair: an explorer remembers where it last had each rescuer in its neighbourhood and whether it
    has shared a neighbourhood with it since it knew the target; it carries the news to the nearest
    rescuer it has not told (giving up on a last-seen cell once it stands next to it)."""

    name = "rrt-relay-memory"
    goal_mode = "cell"
    deterministic = True

    def act(self, engine):
        st = engine.state
        b_, n = st.pos.shape[:2]
        if not hasattr(self, "_episode") or self._episode.shape != st.episode.shape:
            self._episode = np.full(b_, -1, np.int64)
            self._seen = np.zeros((b_, n, n, 2), np.int64)
            self._known = np.zeros((b_, n, n), bool)
            self._told = np.zeros((b_, n, n), bool)
        new = st.episode != self._episode
        self._episode[:] = st.episode
        self._known[new] = False
        self._told[new] = False
        for b in range(b_):
            tr, tc = st.target[b]
            knows = (st.belief[b, :, tr, tc] & TARGET_BIT) != 0
            same = st.comp[b][:, None] == st.comp[b][None, :]
            self._seen[b][same] = np.broadcast_to(st.pos[b][None, :, :], (n, n, 2))[same]
            self._known[b] |= same
            self._told[b] |= same & knows[:, None]
        self._engine = engine
        return super().act(engine)

    def choose(self, ctx):
        st = self._engine.state
        b, i = ctx.b, ctx.i
        if not ctx.can_rescue and ctx.knows_target:
            cand = [
                j
                for j in range(st.pos.shape[1])
                if st.can_rescue[b, j] and not self._told[b, i, j] and self._known[b, i, j]
            ]
            if cand:
                own = np.asarray(ctx.own)
                d = [np.hypot(*(self._seen[b, i, j] - own)) for j in cand]
                k = int(np.argmin(d))
                if d[k] <= 1.5:  # at the last-seen cell and the rescuer is not here: forget it
                    self._known[b, i, cand[k]] = False
                else:
                    g = _toward(ctx, self._seen[b, i, cand[k]])
                    if g is not None:
                        return g
        return super().choose(ctx)


def oracle(env_config, seed):
    return RelayOracle(seed=seed)


def memory(env_config, seed):
    return RelayMemory(seed=seed)
