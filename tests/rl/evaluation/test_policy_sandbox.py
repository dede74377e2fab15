"""A policy cannot write the world it is scored in: an engine-level policy is given a read-only view without
the ground truth (a write fails in one line, exit code 2, nothing written); played isolated, in a worker
process that holds no engine, a policy that walks the garbage collector finds no engine, an honest one
plays exactly the same episodes, and a policy that ends its process is reported."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest

from catmip_env.engines.world import world_key
from catmip_rl.cli.main import main
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate
from catmip_rl.evaluation.user_policy import PolicyError

POLICIES = textwrap.dedent(
    '''
    import gc
    import os
    import numpy as np

    class Teleport:
        """Engine level: puts each world's rescuer next to the target, then stays."""
        def act(self, engine):
            st = engine.state
            for b in range(engine.num_worlds):
                st.pos[b, 0] = st.target[b] + (0, 1)
            return engine.masks.argmax(-1)

    class ReadsGrid:
        def act(self, engine):
            engine.state.grid.sum()
            return engine.masks.argmax(-1)

    class Honest:
        def act(self, engine):
            return engine.masks.argmax(-1)

    def _engines():
        from catmip_env.engines.events import EventEngine
        return [o for o in gc.get_objects() if isinstance(o, EventEngine)]

    class Walker:
        """PettingZoo level: looks for the engine through the garbage collector and, if it finds one,
        teleports the rescuer next to the target."""
        found = 0
        def act(self, observations, infos):
            for eng in _engines():
                Walker.found += 1
                st = eng.state
                st.pos[:, 0] = st.target + (0, 1)
            return {r: int(np.argmax(o["action_mask"])) for r, o in observations.items()
                    if infos[r]["active"]}

    class FirstAllowed:
        def act(self, observations, infos):
            return {r: int(np.argmax(o["action_mask"])) for r, o in observations.items()
                    if infos[r]["active"]}

    class Exits:
        def act(self, engine):
            os._exit(0)

    class GenExit:
        def act(self, observations, infos):
            raise GeneratorExit

    class Columns(Honest):
        deterministic = True
        def start_episodes(self, b, n):
            self.b = b
        def episode_columns(self):
            return {"messages": np.arange(self.b)}

    def make_teleport(env_config, seed): return Teleport()
    def make_grid(env_config, seed): return ReadsGrid()
    def make_honest(env_config, seed): return Honest()
    def make_walker(env_config, seed): return Walker()
    def make_first(env_config, seed): return FirstAllowed()
    def make_exits(env_config, seed): return Exits()
    def make_genexit(env_config, seed): return GenExit()
    def make_columns(env_config, seed): return Columns()
    def make_exit_factory(env_config, seed): os._exit(0)
    '''
)

SETTING = EvalSetting("task1")


@pytest.fixture
def policy_file(tmp_path):
    path = tmp_path / "hostile.py"
    path.write_text(POLICIES)
    return path


def _ticks(res):
    return [(e["map_hash"], e["rescue_tick"], e["decisions"], e["stalls"]) for e in res.episodes]


def _cli(spec: str, out, capsys) -> tuple[int, str]:
    code = main(
        ["eval", "--method", spec, "--episodes", "2", "--out", str(out), "--no-progress", "--threads", "1"]
    )
    return code, capsys.readouterr().err


@pytest.mark.parametrize("factory", ["make_teleport", "make_grid"])
def test_an_engine_level_policy_cannot_write_the_world_or_read_its_truth(
    policy_file, tmp_path, capsys, factory
):
    out = tmp_path / "out"
    code, err = _cli(f"py:{policy_file}:{factory}", out, capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "act(engine) tried to change or read what a policy may not" in err, err
    assert ("read-only" if factory == "make_teleport" else "engine.state.grid is withheld") in err, err
    assert not out.exists()


def test_the_view_holds_what_a_policy_reads_and_the_target_only_where_known():
    seen = []

    class Looks:
        def act(self, engine):
            st = engine.state
            seen.append((st.target.copy(), st.belief.copy(), engine.world.keys.copy()))
            for name in ("grid", "rescue_tick", "rng", "episode"):
                with pytest.raises(AttributeError, match="withheld"):
                    getattr(st, name)
            with pytest.raises(AttributeError, match="withheld"):
                engine.world.base_seed  # noqa: B018 - the map set's seed names the maps
            with pytest.raises(AttributeError, match="may not call engine.step"):
                engine.step  # noqa: B018 - reading the attribute is what fails
            return engine.masks.argmax(-1)

    evaluate("looks", SETTING, episodes=2, seed=0, policy=Looks(), episode_indices=[1, 0])
    assert all(k.tolist() == [world_key(0, 1), world_key(0, 0)] for _, _, k in seen)  # keys, not indices
    unknown = [t for t, _, _ in seen if (t == -1).all()]
    known = [(t, bel) for t, bel, _ in seen if (t >= 0).all()]
    assert unknown and known  # every robot's target unknown at first, known to someone later
    for t, bel in known:  # only where some robot's belief holds it
        assert any((bel[0, i, t[0, 0], t[0, 1]] & 8) for i in range(bel.shape[1]))


def test_isolated_a_policy_walking_the_heap_finds_no_engine(policy_file):
    honest = evaluate(f"py:{policy_file}:make_first", SETTING, episodes=3, seed=0, isolated=False)
    isolated = evaluate(f"py:{policy_file}:make_walker", SETTING, episodes=3, seed=0)  # the default
    assert _ticks(isolated) == _ticks(honest) and isolated.summary["isolated"]
    cheat = evaluate(f"py:{policy_file}:make_walker", SETTING, episodes=3, seed=0, isolated=False)  # it can
    assert _ticks(cheat) != _ticks(honest)


@pytest.mark.parametrize("factory", ["make_first", "make_honest", "make_columns"])
def test_isolated_plays_the_same_episodes(policy_file, factory):
    setting = EvalSetting("task2", "4", 0.05)
    here = evaluate(f"py:{policy_file}:{factory}", setting, episodes=3, seed=1000, isolated=False)
    there = evaluate(f"py:{policy_file}:{factory}", setting, episodes=3, seed=1000)
    assert here.episodes == there.episodes
    differ = ("seconds", "isolated", "policy_calls")  # what the worker counted: None in-process
    assert {k: v for k, v in here.summary.items() if k not in differ} == {
        k: v for k, v in there.summary.items() if k not in differ
    }


def test_isolated_plays_the_marl_policy_exactly():
    spec = "py:run-records/marl-pool4/policies.py:mappo_s0"
    setting = EvalSetting("task2", "2")
    here = evaluate(spec, setting, episodes=3, seed=1000, isolated=False)
    there = evaluate(spec, setting, episodes=3, seed=1000)
    assert here.episodes == there.episodes and here.summary["policy_files"] == there.summary["policy_files"]
    assert here.summary["sampled_success_rate"] == there.summary["sampled_success_rate"]


@pytest.mark.parametrize("factory", ["make_exits", "make_exit_factory"])
def test_a_policy_that_ends_its_process_is_one_line(policy_file, tmp_path, capsys, factory):
    out = tmp_path / "out"
    code, err = _cli(f"py:{policy_file}:{factory}", out, capsys)
    assert code == 2 and "os._exit(0): the policy tried to end the process" in err, err
    assert len(err.strip().splitlines()) == 1 and not out.exists()
    with pytest.raises(PolicyError, match="os._exit"):  # isolated: reported from the worker
        evaluate(f"py:{policy_file}:{factory}", SETTING, episodes=1, isolated=True)


def test_a_worker_that_dies_is_reported(policy_file, tmp_path):
    killer = tmp_path / "killer.py"
    killer.write_text(
        "import os, signal\nclass K:\n    def act(self, engine):\n"
        "        os.kill(os.getpid(), signal.SIGKILL)\n"
        "def make(env_config, seed):\n    return K()\n"
    )
    with pytest.raises(PolicyError, match=r"its process ended during act\(engine\) \(signal 9\)"):
        evaluate(f"py:{killer}:make", SETTING, episodes=1, isolated=True)


def test_generator_exit_in_a_policy_is_one_line(policy_file, tmp_path, capsys):
    code, err = _cli(f"py:{policy_file}:make_genexit", tmp_path / "out", capsys)
    assert code == 2 and "act(observations, infos) raised GeneratorExit" in err, err
    assert len(err.strip().splitlines()) == 1


def test_isolated_is_refused_for_an_object():
    class P:
        def act(self, engine):
            return np.zeros((engine.num_worlds, engine.num_robots), np.int64)

    with pytest.raises(ValueError, match="isolated=True plays a py:"):
        evaluate("p", SETTING, episodes=1, policy=P(), isolated=True)
