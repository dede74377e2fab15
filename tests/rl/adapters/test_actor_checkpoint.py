"""The TorchRL actor/critic wrappers, checkpoints and distributed execution."""

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import set_interaction_type

from catmip_env import make_config
from catmip_env.engines.events import EventEngine, random_valid_actions
from catmip_rl.adapters import keys as K
from catmip_rl.adapters.torchrl_actor import AmatActor, AmatCritic
from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.model import AMAT
from catmip_rl.amat.onboard.neighbourhoods import decide_by_neighbourhood, message_bytes
from catmip_rl.store.checkpoint import load_model, save_model
from tests.rl.helpers import shaken_model


def _td_from_engine(eng: EventEngine) -> TensorDict:
    st = eng.state
    c = eng.cfg.num_classes
    b, n = eng.num_worlds, eng.num_robots
    robots = {
        "global_map": torch.from_numpy(eng.obs_global.copy()),
        "local_map": torch.from_numpy(eng.obs_local.copy()),
        "agent_class": torch.nn.functional.one_hot(torch.from_numpy(st.cls.copy()), c).float(),
        "action_mask": torch.from_numpy(eng.masks.copy()).bool(),
        "active": torch.from_numpy(eng.active.copy()),
    }
    return TensorDict({K.ROBOTS: TensorDict(robots, batch_size=[b, n])}, batch_size=[b])


@pytest.fixture
def engine():
    eng = EventEngine(make_config("train"), 4, seed=0)
    eng.reset()
    rng = np.random.default_rng(0)
    eng.step(random_valid_actions(eng.masks, rng))  # a mid-episode event
    return eng


def test_actor_samples_valid_goals_and_get_dist_rescores_them(engine):
    actor = AmatActor(shaken_model())
    td = actor(_td_from_engine(engine))
    a, lp, mask, active = td[K.ACTION], td[K.LOG_PROB], td[K.ACTION_MASK], td[K.ACTIVE]
    assert mask.gather(-1, a[..., None]).all()
    assert td[K.VALUE].shape == (4, 3, 1) and td[K.ORDER].shape == (4, 3)
    dist = actor.get_dist(td)
    lp2 = dist.log_prob(a)
    assert torch.allclose(lp2[active], lp[active], atol=1e-5)
    assert (lp[~active] == 0).all()
    ent = dist.entropy()
    assert ent.shape == (4, 3) and (ent[active] >= 0).all()
    # gradients flow through get_dist only
    lp2[active].sum().backward()
    assert actor.model.obs_fc1.weight.grad is not None


def test_actor_engine_roundtrip_plays_episodes(engine):
    """The actor's actions, fed back to the engine event after event, are the active robots' allowed
    goals with finite log-probabilities, and the worlds play on (their ticks advance)."""
    actor = AmatActor(AMAT())
    decisions = 0
    for _ in range(30):
        td = actor(_td_from_engine(engine))
        action, active = td[K.ACTION].numpy(), engine.active & ~engine.state.done[:, None]
        b, i = np.nonzero(active)
        assert (engine.masks[b, i, action[b, i]] == 1).all()
        assert torch.isfinite(td[K.LOG_PROB][torch.from_numpy(active)]).all()
        decisions += len(b)
        before = engine.state.ticks.copy()
        engine.step(action)
        assert (engine.state.ticks >= before).all() and (engine.state.ticks > before).any()
        if engine.state.done.any():
            engine.reset(worlds=engine.state.done)
    assert decisions >= 30


def test_deterministic_interaction_type(engine):
    actor = AmatActor(shaken_model())
    base = _td_from_engine(engine)
    with set_interaction_type("deterministic"):
        a1 = actor(base.clone())[K.ACTION]
        a2 = actor(base.clone())[K.ACTION]
    assert torch.equal(a1, a2)
    critic = AmatCritic(actor.model)
    v = critic(base.clone())[K.VALUE]
    assert torch.allclose(v, actor(base.clone())[K.VALUE])


def test_checkpoint_roundtrip_and_errors(tmp_path):
    m = shaken_model(AmatConfig(window=5))
    path = save_model(m, tmp_path / "amat.pt", extra={"iteration": 3})
    assert (tmp_path / "amat.json").exists() and not list(tmp_path.glob(".*tmp"))
    back = load_model(path)
    assert back.config == m.config
    for (k1, v1), (k2, v2) in zip(m.state_dict().items(), back.state_dict().items()):
        assert k1 == k2 and torch.equal(v1, v2)
    blob = torch.load(path, weights_only=True)
    blob["config"]["embed_dim"] = 64
    torch.save(blob, tmp_path / "bad.pt")
    with pytest.raises(ValueError, match="does not fit"):
        load_model(tmp_path / "bad.pt")
    torch.save({"weights": 1}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not an AMAT checkpoint"):
        load_model(tmp_path / "other.pt")


def test_distributed_execution_with_full_communication_matches_centralised(engine):
    actor = AmatActor(shaken_model(), deterministic=True)
    td = actor(_td_from_engine(engine))
    for b in range(engine.num_worlds):
        obs = {k: td["robots", k][b] for k in ("global_map", "local_map", "agent_class")}
        goals = decide_by_neighbourhood(
            actor.model, obs, td[K.ACTION_MASK][b], td[K.ACTIVE][b], torch.zeros(3, dtype=torch.long)
        )
        assert torch.equal(goals, td[K.ACTION][b])


def test_message_bytes():
    sizes = message_bytes(AmatConfig(), (20, 20))
    assert sizes["embedding"] == 192 * 4
    assert sizes["raw_uint8"] == 7 * 400 + 6 * 49 + 2
    assert sizes["raw_float32"] == 4 * sizes["raw_uint8"]
