"""Communication drawn per episode (EnvConfig.comm_sigma_choices): the maps do not change, the draw is
reproducible, and an episode that drew a range plays exactly as with that range fixed."""

import numpy as np
import pytest

from catmip_env import BatchedWorld, make_config

CHOICES = (None, 4.0, 2.0)


def _engine(cfg, episodes, num_worlds=None):
    eng = BatchedWorld(cfg, num_worlds=num_worlds or len(episodes), seed=3)
    eng.reset(episode_indices=np.asarray(episodes))
    return eng


def test_the_maps_are_those_of_a_fixed_range_and_every_choice_is_drawn():
    episodes = np.arange(60)
    fixed = _engine(make_config("train"), episodes)
    mixed = _engine(make_config("train", comm_sigma_choices=CHOICES), episodes)
    for name in ("grid", "target", "pos", "heading", "cls"):
        assert np.array_equal(getattr(fixed.state, name), getattr(mixed.state, name)), name
    assert set(np.unique(fixed.state.comm_sigma)) == {0.0}  # full communication
    drawn = mixed.state.comm_sigma
    assert set(np.unique(drawn)) == {0.0, 2.0, 4.0}  # 0 = full communication
    assert all(10 <= (drawn == v).sum() <= 30 for v in (0.0, 2.0, 4.0))  # uniform: 20 each expected
    # episode k draws the same range whatever the batch and the other worlds
    again = _engine(make_config("train", comm_sigma_choices=CHOICES), episodes[::-1][:7])
    assert np.array_equal(again.state.comm_sigma, drawn[::-1][:7])
    assert make_config("train", comm_sigma=2.0).comm_ranges == (2.0,)


@pytest.mark.parametrize("level", ["tick", "event"])
def test_an_episode_plays_exactly_as_with_its_drawn_range_fixed(level):
    from catmip_env.engines.events import EventEngine
    from catmip_env.planners.baselines import make_planner

    cfg = make_config("task2", comm_sigma_choices=CHOICES, horizon_ticks=120)
    episodes = np.arange(9)
    sigmas = _engine(cfg, episodes).state.comm_sigma
    for k, sigma in zip(episodes, sigmas):
        runs = []
        for c in (cfg, cfg.replace(comm_sigma_choices=(), comm_sigma=None if sigma == 0 else float(sigma))):
            if level == "tick":
                eng = _engine(c, [k])
                acts = np.random.default_rng(int(k)).integers(0, 4, size=(120, 1, c.num_robots))
                comps = [eng.step(a) and eng.state.comp.copy() for a in acts]
            else:
                eng = EventEngine(c, num_worlds=1, seed=3, goal_mode="cell")
                eng.reset(episode_indices=np.array([k]))
                planner, comps = make_planner("nearest", seed=0), []
                while not eng.state.done.all():
                    eng.step(planner.act(eng))
                    comps.append(eng.state.comp.copy())
            runs.append((np.array(comps), eng.state.belief.copy(), eng.state.rescue_tick.copy()))
        assert all(np.array_equal(x, y) for x, y in zip(*runs)), (k, sigma)
    assert len(set(sigmas.tolist())) > 1


@pytest.mark.parametrize(
    "bad", [[0], [-2.0], ["4"], [float("nan")], [float("inf")], [None, 1e-300], [True], "4", 4]
)
def test_bad_choices_are_refused_naming_the_field(bad):
    with pytest.raises(ValueError, match="comm_sigma_choices"):
        make_config("train", comm_sigma_choices=bad)


def test_a_fixed_range_and_choices_together_are_refused():
    with pytest.raises(ValueError, match="comm_sigma .* or comm_sigma_choices .* not both"):
        make_config("train", comm_sigma=4.0, comm_sigma_choices=[None, 2.0])


def test_choices_come_from_json_lists():
    cfg = make_config("train").replace(**{"comm_sigma_choices": [None, 4, 2.5]})
    assert cfg.comm_sigma_choices == (None, 4, 2.5) and cfg.comm_ranges == (None, 4, 2.5)
    assert make_config("train", comm_sigma_choices=[]).comm_ranges == (None,)
    from catmip_env import EnvConfig

    direct = EnvConfig(comm_sigma_choices=[None, 2.0], team=["rescuer", "explorer"])  # lists become tuples
    assert direct.comm_sigma_choices == (None, 2.0) and direct.team == ("rescuer", "explorer")
    assert hash(direct) == hash(direct.replace())
