"""The sandbox's worker counts the project's entry points a ``py:`` policy calls while it plays (worlds
built or reset, map sets read, maps generated, planners made and run): ``policy.calls()``. A plain
policy calls none; the committed MAPPO / IPPO entries build no world while loading or playing."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest

from catmip_env.engines.events import EventEngine
from catmip_rl.evaluation.evaluate import EvalSetting
from catmip_rl.evaluation.sandbox import isolated_policy
from catmip_rl.evaluation.user_policy import PolicyError

POLICIES = textwrap.dedent(
    """
    import numpy as np
    from catmip_env.planners import make_planner

    class Plain:
        def act(self, engine):
            return engine.masks.argmax(-1)

    class BuildsWorld(Plain):
        def __init__(self, env_config):
            from catmip_env.engines.world import BatchedWorld
            BatchedWorld(env_config, num_worlds=1, seed=0).reset()

    class RunsRRT:
        goal_mode = "cell"
        def act(self, engine):
            return make_planner("rrt").act(engine)

    class UnpatchesThenBuilds(Plain):
        def __init__(self, env_config):
            from catmip_env.engines.world import BatchedWorld
            wrapper = BatchedWorld.__init__
            original = next(c.cell_contents for c in wrapper.__closure__ if callable(c.cell_contents))
            BatchedWorld.__init__ = original  # put back: the worker wraps it again before the next request
            self.cfg = env_config
        def act(self, engine):
            from catmip_env.engines.world import BatchedWorld
            BatchedWorld(self.cfg, num_worlds=1, seed=0)
            return super().act(engine)

    class Reads:
        def act(self, observations, infos):
            from catmip_env.maps.map_sets import manifest
            manifest("task1")
            active = [r for r in observations if infos[r]["active"]]
            return {r: int(np.argmax(observations[r]["action_mask"])) for r in active}

    def plain(env_config, seed): return Plain()
    def builds_world(env_config, seed): return BuildsWorld(env_config)
    def runs_rrt(env_config, seed): return RunsRRT()
    def unpatches(env_config, seed): return UnpatchesThenBuilds(env_config)
    def reads_map_sets(env_config, seed): return Reads()
    """
)

SETTING = EvalSetting("task1")
ZERO = {"worlds": 0, "map_sets": 0, "mapgen": 0, "planners_made": 0, "planner_decisions": 0, "restored": 0}


@pytest.fixture(scope="module")
def policy_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("counts") / "counted.py"
    path.write_text(POLICIES)
    return path


def _calls_after_play(spec: str, setting: EvalSetting = SETTING, events: int = 3) -> dict[str, int]:
    """Build the isolated policy, let it decide at ``events`` events of a one-world engine, and read its
    counts."""
    cfg = setting.env_config()
    policy = isolated_policy(spec, "counted", cfg, 0)
    try:
        engine = EventEngine(cfg, num_worlds=1, seed=0, goal_mode=policy.goal_mode)
        engine.reset()
        if getattr(policy, "one_world_at_a_time", False):
            policy.reset()
        for _ in range(events):
            engine.step(policy.act(engine))
        return policy.calls()
    finally:
        policy.close()


def test_a_plain_policy_calls_nothing(policy_file):
    assert _calls_after_play(f"py:{policy_file}:plain") == ZERO


def test_a_world_built_in_the_factory_is_counted(policy_file):
    calls = _calls_after_play(f"py:{policy_file}:builds_world")
    assert calls["worlds"] >= 1 and calls["mapgen"] >= 1 and calls["planner_decisions"] == 0


def test_a_planner_run_at_each_decision_is_counted(policy_file):
    calls = _calls_after_play(f"py:{policy_file}:runs_rrt")
    assert calls["planner_decisions"] == calls["planners_made"] == 3 and calls["worlds"] == 0


def test_a_map_set_read_at_the_pettingzoo_level_is_counted(policy_file):
    calls = _calls_after_play(f"py:{policy_file}:reads_map_sets")
    assert calls["map_sets"] == 3 and calls["worlds"] == 0


def test_a_wrapper_put_back_is_wrapped_again_and_said(policy_file):
    calls = _calls_after_play(f"py:{policy_file}:unpatches")
    assert calls["restored"] >= 1 and calls["worlds"] == 3


@pytest.mark.parametrize("factory", ["mappo_s0", "ippo_s1"])
def test_the_committed_marl_entries_build_no_world(factory):
    spec = f"py:run-records/marl-pool4/policies.py:{factory}"
    calls = _calls_after_play(spec, EvalSetting("task2", "2"), events=5)
    assert calls["worlds"] == 0 and calls["mapgen"] == 0 and calls["map_sets"] == 0, calls


def test_an_in_process_policy_has_no_counts():
    from catmip_rl.evaluation.checked_policy import wrap_user_policy

    class P:
        def act(self, engine):
            return np.zeros((engine.num_worlds, engine.num_robots), np.int64)

    assert wrap_user_policy(P(), "p").calls() is None


def test_a_closed_worker_is_one_line(policy_file):
    policy = isolated_policy(f"py:{policy_file}:plain", "counted", SETTING.env_config(), 0)
    policy.close()
    with pytest.raises(PolicyError, match="its process was closed before calls"):
        policy.calls()
