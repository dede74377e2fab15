"""Your own policy on the protocol: both levels play the same maps as the planners, the PettingZoo level
sees exactly what the env gives, TorchRL modules go through the adapter, and every way a policy can
fail is one line (exit code 2) with nothing written."""

from __future__ import annotations

import csv
import json
import textwrap

import numpy as np
import pytest
import torch
from tensordict.nn import TensorDictModule

from catmip_env import search_rescue_v0
from catmip_rl.adapters import keys as K
from catmip_rl.adapters.torchrl_policy import TorchRLPolicy
from catmip_rl.cli.main import main
from catmip_rl.cli.render import render_episode
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate
from catmip_rl.evaluation.methods import amat_label, parse_method
from catmip_rl.evaluation.user_policy import PolicyError

POLICIES = textwrap.dedent(
    '''
    import numpy as np

    class FirstAllowed:
        """PettingZoo level: each active robot takes its first allowed action."""
        def __init__(self):
            self.resets = 0
        def reset(self):
            self.resets += 1
        def act(self, observations, infos):
            active = [r for r in observations if infos[r]["active"]]
            return {r: int(np.argmax(observations[r]["action_mask"])) for r in active}

    class FirstAllowedEngine:
        def act(self, engine):
            return engine.masks.argmax(-1)

    def make_pz(env_config, seed):
        return FirstAllowed()

    def make_engine(env_config, seed):
        return FirstAllowedEngine()

    def make_none(env_config, seed):
        return None

    def make_crash(env_config, seed):
        raise RuntimeError("no weights here")

    class Masked:
        def act(self, observations, infos):
            active = [r for r in observations if infos[r]["active"]]
            return {r: int(np.argmin(observations[r]["action_mask"])) for r in active}

    def make_masked(env_config, seed):
        return Masked()

    class Divides:
        def act(self, observations, infos):
            return 1 / 0

    def make_divides(env_config, seed):
        return Divides()

    class WrongShape:
        def act(self, engine):
            return np.zeros(3, np.int64)

    def make_wrong_shape(env_config, seed):
        return WrongShape()

    class TooLarge:
        def act(self, engine):
            return np.full((engine.num_worlds, engine.num_robots), 999)

    def make_too_large(env_config, seed):
        return TooLarge()

    class Missing:
        def act(self, observations, infos):
            return {}

    def make_missing(env_config, seed):
        return Missing()

    def make_task1_only(env_config, seed):
        from catmip_env.play import WorldNotSupported
        if env_config.map_size != 15:
            raise WorldNotSupported(f"built for 15x15 maps, not {env_config.map_size}")
        return FirstAllowedEngine()
    '''
)


@pytest.fixture
def policy_file(tmp_path):
    path = tmp_path / "elsewhere" / "mine.py"  # a file outside the repository
    path.parent.mkdir()
    path.write_text(POLICIES)
    return path


SETTING = EvalSetting("task2", "4")


def _records(res):
    return [(r["map_hash"], r["rescue_tick"], r["decisions"], r["stalls"]) for r in res.episodes]


def test_both_levels_play_the_planners_maps_and_agree(policy_file):
    pz = evaluate(f"mine=py:{policy_file}:make_pz", SETTING, episodes=6, seed=3)
    eng = evaluate(f"py:{policy_file}:make_engine", SETTING, episodes=6, seed=3)
    nearest = evaluate("nearest", SETTING, episodes=6, seed=3)
    assert pz.summary["method"] == "mine" and eng.summary["method"] == "mine"  # the file's stem by default
    assert [r["map_hash"] for r in pz.episodes] == [r["map_hash"] for r in nearest.episodes]
    # the same decisions through the PettingZoo dicts, one episode at a time, as through the batched engine
    assert _records(pz) == _records(eng)
    assert pz.summary["decisions"] > 0 and pz.summary["map_set_status"] == "not frozen"


def test_the_pettingzoo_level_sees_what_the_env_gives():
    """Every call's (observations, infos) equal those of search_rescue_v0 on the same episode."""
    seen = []

    class Recorder:
        def act(self, observations, infos):
            seen.append((observations, infos))
            return {r: int(np.flatnonzero(o["action_mask"])[-1]) for r, o in observations.items()}

    setting = EvalSetting("task1", "2")
    res = evaluate("rec", setting, episodes=2, seed=5, policy=Recorder())
    env = search_rescue_v0.parallel_env(preset=setting.env_config())
    calls = iter(seen)
    for episode in range(2):
        obs, infos = env.reset(seed=5, options={"episode_index": episode})
        while env.agents:
            got_obs, got_infos = next(calls)
            assert got_infos == infos
            for r in obs:
                for key, value in obs[r]["observation"].items():
                    np.testing.assert_array_equal(got_obs[r]["observation"][key], value)
                np.testing.assert_array_equal(got_obs[r]["action_mask"], obs[r]["action_mask"])
            actions = {r: int(np.flatnonzero(o["action_mask"])[-1]) for r, o in obs.items()}
            obs, _, _, _, infos = env.step(actions)
    assert next(calls, None) is None and res.summary["episodes"] == 2


def test_reset_is_called_before_every_episode_on_a_fresh_copy_of_the_policy():
    class Counts:
        log: list[int] = []  # a class attribute: shared by the copies the episodes are played with

        def __init__(self):
            self.resets = 0

        def reset(self):
            self.resets += 1
            self.log.append(self.resets)

        def act(self, observations, infos):
            return {r: int(np.argmax(o["action_mask"])) for r, o in observations.items()}

    policy = Counts()
    evaluate("c", EvalSetting("task1"), episodes=4, seed=0, policy=policy)
    assert Counts.log == [1, 1, 1, 1] and policy.resets == 0  # each episode: the factory's state, reset


def test_a_torchrl_module_plays_through_the_adapter():
    class FirstAllowedNet(torch.nn.Module):  # reads float maps: fails on uint8 ones
        def forward(self, global_map, mask):
            assert global_map.dtype == torch.float32 and global_map.max() <= 1.0
            return mask.to(torch.int64).argmax(-1)

    module = TensorDictModule(FirstAllowedNet(), in_keys=[K.GLOBAL_MAP, K.ACTION_MASK], out_keys=[K.ACTION])
    res = evaluate("td", SETTING, episodes=4, seed=3, policy=TorchRLPolicy(module, float_maps=True))

    class Engine:
        def act(self, engine):
            return engine.masks.argmax(-1)

    ref = evaluate("ref", SETTING, episodes=4, seed=3, policy=Engine())
    assert _records(res) == _records(ref)
    # argmax by default, said on the summary, and a sampled pass on the same maps (TorchRLPolicy.sampled)
    assert res.summary["actions"] == "argmax" and res.summary["sampled_pass"]
    assert ref.summary["actions"] == "its own" and not ref.summary["sampled_pass"]


def test_cli_eval_render_and_bench_take_a_policy_file(policy_file, tmp_path, capsys):
    out = tmp_path / "eval"
    assert main(["eval", "--method", f"mine=py:{policy_file}:make_pz", "--episodes", "3", "--out", str(out),
                 "--no-progress", "--threads", "1"]) == 0  # fmt: skip
    summary = json.loads((out / "summary.json").read_text())
    assert summary["method"] == "mine" and summary["map_set"] == "task1/seed0"
    assert summary["map_set_status"] == "verified" and summary["map_set_verified_episodes"] == 3
    gif = tmp_path / "mine.gif"
    assert main(["render", "--method", f"py:{policy_file}:make_pz", "--out", str(gif), "--threads", "1"]) == 0
    assert gif.stat().st_size > 1000
    fig = tmp_path / "paper"
    assert main(["bench", "paper", "--figure", "11", "--methods", f"mine=py:{policy_file}:make_engine",
                 "--episodes", "2", "--jobs", "1", "--out", str(fig), "--no-progress"]) == 0  # fmt: skip
    assert "figure 11" not in capsys.readouterr().err  # no bar with --no-progress
    assert {"mine"} == {r.split(",")[2] for r in (fig / "fig11" / "summary.csv").read_text().splitlines()[1:]}


@pytest.mark.parametrize(
    ("factory", "message"),
    [
        ("make_none", "the factory returned NoneType, not a policy"),
        ("make_crash", "the factory raised RuntimeError: no weights here (at "),
        ("make_masked", "is forbidden by its action mask"),
        ("make_divides", "act(observations, infos) raised ZeroDivisionError"),
        ("make_wrong_shape", "returned shape (3,), expected (1, 2)"),
        ("make_missing", "missing actions for active robots"),
        ("make_too_large", "action 999 of robot_0 in world 0 at tick 0 is out of range (actions are 0..48)"),
        ("nope", "has no 'nope'"),
    ],
)
def test_a_bad_policy_is_one_line_and_writes_nothing(policy_file, tmp_path, capsys, factory, message):
    out = tmp_path / "out"
    code = main(["eval", "--method", f"py:{policy_file}:{factory}", "--episodes", "1", "--out", str(out),
                 "--no-progress", "--threads", "1"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


@pytest.mark.slow
def test_a_policy_for_other_worlds_is_left_out_of_those_panels(policy_file, tmp_path, capsys):
    """bench paper plays a policy on the panels it can play and says which it left out; a single
    evaluation of a world it cannot play is a one-line error."""
    fig = tmp_path / "paper"
    mine = f"mine=py:{policy_file}:make_task1_only"
    mix = f"mix=py:{policy_file}:make_task1_only,py:{policy_file}:make_engine"
    assert main(["bench", "paper", "--figure", "9", "--methods", "nearest", "--method", mine, "--method", mix,
                 "--episodes", "1", "--jobs", "1", "--out", str(fig)]) == 0  # fmt: skip
    with open(fig / "fig9" / "summary.csv") as f:
        runs = {(r["panel"], r["method"]): int(r["runs"]) for r in csv.DictReader(f)}
    panels = ("Task 1", "Task 2", "Task 3")
    # mix plays Task 1 with both of its runs, Tasks 2 and 3 with the one that can
    assert runs == {**{(p, "nearest"): 1 for p in panels}, ("Task 1", "mine"): 1, ("Task 1", "mix"): 2,
                    ("Task 2", "mix"): 1, ("Task 3", "mix"): 1}  # fmt: skip
    md = (fig / "fig9" / "summary.md").read_text()
    assert "| mine | " in md and "| — | — |" in md
    assert (
        "mine on Task 2: not played (policy mine cannot play this world: built for 15x15 maps, not 20)" in md
    )
    assert not (fig / "fig9" / "Task 3" / "mine").exists()
    capsys.readouterr()
    out = tmp_path / "eval"
    code = main(["eval", "--task", "task2", "--method", f"py:{policy_file}:make_task1_only",
                 "--episodes", "1", "--out", str(out), "--no-progress"])  # fmt: skip
    err = capsys.readouterr().err
    assert (
        code == 2
        and "cannot play this world: built for 15x15 maps, not 20" in err
        and len(err.splitlines()) == 1
    )
    assert not out.exists()


def test_bad_specs_are_refused_before_any_work(tmp_path, capsys):
    broken = tmp_path / "broken.py"
    broken.write_text("def make(:\n")
    for spec, message in ((f"py:{tmp_path / 'none.py'}:make", "no such file"),
                          ("py:not a module:make", "neither a .py file nor a dotted module name"),
                          ("py:catmip_no_such_module:make", "importing catmip_no_such_module failed"),
                          (f"py:{broken}:make", "SyntaxError")):  # fmt: skip
        code = main(
            ["eval", "--method", spec, "--episodes", "1", "--out", str(tmp_path / "o"), "--no-progress"]
        )
        err = capsys.readouterr().err
        assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    with pytest.raises(PolicyError, match="act\\(\\) takes 0 required arguments"):

        class NoArgs:
            def act(self):
                return {}

        evaluate("x", SETTING, episodes=1, policy=NoArgs())


def test_a_module_path_and_the_method_names(tmp_path, monkeypatch, policy_file):
    monkeypatch.syspath_prepend(str(policy_file.parent))
    res = evaluate("py:mine:make_engine", EvalSetting("task1"), episodes=2)
    assert res.summary["method"] == "mine" and res.summary["policy"] == "py:mine:make_engine"
    assert parse_method("amat:task1").name == "amat_task1"
    assert parse_method("amat-guard:task1").name == "amat_task1-guard"
    run = tmp_path / "runs" / "p"
    (run / "checkpoints").mkdir(parents=True)
    assert amat_label(run) == "p"
    assert amat_label(run / "checkpoints" / "latest.pt") == "p"
    assert amat_label(run / "checkpoints" / "iter_20.pt") == "p@iter_20"


def test_the_two_random_floors():
    """random-uniform has no rescue rule: on Task 1 it rescues far less by tick 100 than random-rescue."""
    uniform = evaluate("random-uniform", EvalSetting("task1"), episodes=40, seed=0).summary
    rescue = evaluate("random-rescue", EvalSetting("task1"), episodes=40, seed=0).summary
    assert uniform["success_by_100"] + 0.25 < rescue["success_by_100"]


def test_render_plays_a_pettingzoo_policy(policy_file, tmp_path):
    path = render_episode(f"py:{policy_file}:make_pz", EvalSetting("task1"), tmp_path / "a.gif", episode=1)
    assert path.stat().st_size > 1000


def test_a_policy_file_imports_the_modules_beside_it(tmp_path, capsys):
    (tmp_path / "helper_mod.py").write_text("STEP = 'argmax'\n")
    (tmp_path / "pol.py").write_text(
        "import numpy as np\nimport helper_mod\n\n"
        "class P:\n    def act(self, engine):\n        return engine.masks.argmax(-1)\n\n"
        "def make(env_config, seed):\n    return P()\n"
    )
    assert (
        evaluate(f"py:{tmp_path / 'pol.py'}:make", EvalSetting("task1"), episodes=1).summary["method"]
        == "pol"
    )
    code = main(["eval", "--method", f"mine={tmp_path / 'pol.py'}:make", "--out", str(tmp_path / "o")])
    assert code == 2 and f"(your policy? write py:{tmp_path / 'pol.py'}:make)" in capsys.readouterr().err


def test_sync_plays_a_policy_file_in_the_synchronous_world(tmp_path):
    seen = tmp_path / "seen.txt"  # the factory writes down the world it was asked to play
    (tmp_path / "pol.py").write_text(
        "from catmip_env.planners.baselines import make_planner\n"
        "def make(env_config, seed):\n"
        f"    open({str(seen)!r}, 'a').write(str(env_config.synchronous) + ' ')\n"
        "    policy = make_planner('nearest', seed=seed)\n"
        "    policy.goal_mode = 'cell'\n"
        "    return policy\n"
    )
    setting = EvalSetting("task1", max_ma_ticks=4)
    ticks = set()  # the tick of every decision event of a world that goes on, modulo the beat

    def hook(eng):
        ticks.update(int(t) % 4 for t in eng.state.ticks[~eng.state.done])

    res = evaluate(f"sync:py:{tmp_path / 'pol.py'}:make", setting, episodes=2, engine_hook=hook)
    assert res.summary["synchronous"] and res.summary["method"] == "sync:pol" and ticks == {0}
    plain = evaluate(f"py:{tmp_path / 'pol.py'}:make", setting, episodes=2)
    assert not plain.summary["synchronous"]
    assert [r["map_hash"] for r in res.episodes] == [r["map_hash"] for r in plain.episodes]
    assert seen.read_text().split() == ["True", "False"]


def test_a_policy_whose_act_fails_stops_a_bench_before_anything_is_played(policy_file, tmp_path, capsys):
    fig = tmp_path / "paper"
    code = main(["bench", "paper", "--figure", "11", "--methods", "nearest", "--method",
                 f"b=py:{policy_file}:make_divides", "--episodes", "1", "--jobs", "1",
                 "--out", str(fig)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "policy b: act(observations, infos) raised ZeroDivisionError" in err, err
    assert not list(fig.rglob("summary.json"))  # Nearest was not played first
