"""The MARL baselines' asynchronous advantage (TorchRL's GAE along each robot's own decisions) against a
hand computation, and the saved policy's round trip."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule

from catmip_env import make_config
from catmip_env.play import WorldNotSupported
from catmip_rl.adapters import keys as K
from catmip_rl.adapters.torchrl_marl import (
    ADVANTAGE,
    VALUE_TARGET,
    decision_samples,
    load_policy,
    make_actor,
    save_policy,
)  # fmt: skip

GAMMA, LAMBDA = 0.9, 0.8
ACTIVE = [[1, 1], [0, 1], [1, 0], [0, 1], [1, 1]]  # (T, N): who decides at each event row
TICKS = [2, 3, 1, 2, 4]  # ticks each event row ran
REWARD = [[1, 0], [0, 1], [2, 0], [0, 1], [5, 5]]  # (T, N) each robot's reward of each row


class RowValue(torch.nn.Module):
    """V = the tag written into the global map: 0.1 t + 0.01 n for row t, robot n."""

    def forward(self, state, global_map, local_map, agent_class):
        return global_map[..., 0, 0, 0:1]


def _batch(ends: list[str]) -> TensorDict:
    """B worlds of the same pattern; world b's episode ends at the last row by ``ends[b]``
    ("rescue", "horizon") or goes on past the batch ("none")."""
    b, t, n = len(ends), len(ACTIVE), 2
    gmap = torch.zeros(b, t, n, 7, 5, 5)
    for r in range(t):
        for i in range(n):
            gmap[:, r, i, 0, 0, 0] = 0.1 * r + 0.01 * i
    robots = TensorDict(
        {"active": torch.tensor(ACTIVE, dtype=torch.bool).expand(b, t, n), "global_map": gmap,
         "local_map": torch.zeros(b, t, n, 6, 7, 7), "agent_class": torch.zeros(b, t, n, 2),
         "action_mask": torch.ones(b, t, n, 49, dtype=torch.bool),
         "action": torch.zeros(b, t, n, dtype=torch.long),
         "action_log_prob": torch.zeros(b, t, n)},
        batch_size=(b, t, n),
    )  # fmt: skip
    done = torch.zeros(b, t, 1, dtype=torch.bool)
    term = torch.zeros(b, t, 1, dtype=torch.bool)
    for w, end in enumerate(ends):
        done[w, -1] = end != "none"
        term[w, -1] = end == "rescue"
    reward = torch.tensor(REWARD, dtype=torch.float32).expand(b, t, n)[..., None]
    nxt = TensorDict(
        {K.ROBOTS: TensorDict({"reward": reward},
                              batch_size=(b, t, n)),
         "event_ticks": torch.tensor(TICKS).expand(b, t)[..., None], "done": done, "terminated": term},
        batch_size=(b, t),
    )  # fmt: skip
    return TensorDict({K.ROBOTS: robots, "state": torch.zeros(b, t, 4, 5, 5), "next": nxt}, batch_size=(b, t))


def _expected(n: int, end: str) -> dict[int, float]:
    """Row -> advantage of robot n's trainable decisions, by the formulas of the module docstring."""
    rows = [t for t in range(len(ACTIVE)) if ACTIVE[t][n]]
    v = {t: 0.1 * t + 0.01 * n for t in rows}
    steps = []  # (row, R, dt, next row or None, terminal)
    for k, t in enumerate(rows):
        nxt = rows[k + 1] if k + 1 < len(rows) else None
        last = (nxt - 1) if nxt is not None else len(ACTIVE) - 1
        if nxt is None and end != "rescue":
            continue  # cut by the horizon or the batch's end: not trained
        ret = sum(REWARD[r][n] * GAMMA ** sum(TICKS[t:r]) for r in range(t, last + 1))
        steps.append((t, ret, sum(TICKS[t : last + 1]), nxt, nxt is None))
    adv, following = {}, None
    for t, ret, dt, nxt, terminal in reversed(steps):
        boot = 0.0 if terminal else GAMMA**dt * v[nxt]
        a = ret + boot - v[t]
        if following is not None and following[0] == nxt:
            a += GAMMA**dt * LAMBDA * following[1]
        adv[t] = a
        following = (t, a)
    return adv


@pytest.mark.parametrize("end", ["rescue", "horizon", "none"])
def test_the_asynchronous_advantage_matches_a_hand_computation(end):
    critic = TensorDictModule(RowValue(), in_keys=[(K.ROBOTS, "state"), *K.OBS_KEYS[:2], K.AGENT_CLASS],
                              out_keys=[K.VALUE])  # fmt: skip
    out = decision_samples(_batch([end]), critic, GAMMA, LAMBDA)
    got = {}
    for i in range(len(out)):
        tag = float(out[i].get(K.GLOBAL_MAP)[0, 0, 0])
        t, n = round(tag * 10 - 0.05), round((tag * 10 - round(tag * 10 - 0.05)) * 10)
        got[(n, t)] = float(out[i].get(ADVANTAGE))
        target = float(out[i].get(VALUE_TARGET))
        assert target == pytest.approx(got[(n, t)] + tag, abs=1e-5)  # lambda-return = A + V
    want = {(n, t): a for n in (0, 1) for t, a in _expected(n, end).items()}
    assert got.keys() == want.keys()
    for key, a in want.items():
        assert got[key] == pytest.approx(a, abs=1e-5), key


def test_a_saved_policy_loads_as_the_same_actor(tmp_path):
    cfg = make_config("task1")
    actor = make_actor(cfg)
    save_policy(actor, cfg, tmp_path, {"algo": "mappo"})
    policy = load_policy(tmp_path / "policy.pt", cfg)
    for a, b in zip(actor.parameters(), policy.module.parameters()):
        assert torch.equal(a, b)
    assert "make_policy" in (tmp_path / "policy.py").read_text()
    assert policy.files == policy.sampled(0).files == (str(tmp_path / "policy.pt"),)  # hashed on results
    with pytest.raises(WorldNotSupported, match="was trained for"):  # bench paper leaves that panel out
        load_policy(tmp_path / "policy.pt", make_config("task2"))
    (tmp_path / "policy.pt").write_bytes(b"junk")
    with pytest.raises(ValueError, match="not a readable saved policy"):
        load_policy(tmp_path / "policy.pt", cfg)


def test_a_pooled_policy_plays_every_map_size(tmp_path):
    from catmip_rl.evaluation.evaluate import EvalSetting, evaluate

    cfg = make_config("task1")
    save_policy(make_actor(cfg, pool=4), cfg, tmp_path, {"algo": "ippo"}, pool=4)
    for task in ("task1", "task2", "task3"):  # 15x15 / 20x20 / 32x32, 2 / 3 / 6 robots
        policy = load_policy(tmp_path / "policy.pt", make_config(task))
        result = evaluate("pooled", EvalSetting(task), episodes=1, seed=0, policy=policy, sampled_too=False)
        assert result.summary["episodes"] == 1 and result.summary["actions"] == "argmax"


@pytest.mark.parametrize("deterministic", [True, False])
def test_a_loaded_policy_feeds_only_the_deciding_robots_to_its_network(tmp_path, deterministic):
    from catmip_env.engines.events import EventEngine
    from catmip_rl.adapters.torchrl_policy import TorchRLPolicy

    cfg = make_config("task3")  # six robots: some of them busy at an event
    torch.manual_seed(0)  # the same untrained network whatever ran before
    save_policy(make_actor(cfg, pool=4), cfg, tmp_path, {"algo": "ippo"}, pool=4)
    fast = load_policy(tmp_path / "policy.pt", cfg, deterministic=deterministic)
    assert fast.per_robot and fast.sampled(0).per_robot
    full = TorchRLPolicy(fast.module, float_maps=True, deterministic=deterministic)
    engine = EventEngine(cfg, num_worlds=4, seed=2)
    engine.reset()
    fed = []
    fast.module.register_forward_hook(lambda m, args, out: fed.append(out.batch_size.numel()))
    deciding = 0
    for _ in range(30):
        a = fast.act(engine)
        active = engine.active
        assert (a[~active] == 0).all() and fed[-1] == active.sum()
        deciding += active.sum()
        if deterministic:  # the argmax of each robot's row is the full batch's: the same game
            assert (a[active] == full.act(engine)[active]).all()
        assert engine.masks[active, a[active]].all()  # sampled: allowed goals all the same
        engine.step(a)
    assert deciding < 30 * engine.active.size  # the point of it: fewer rows than the whole batch
