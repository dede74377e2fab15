"""The evaluator asks a policy for the optional members of catmip_env.play.Policy (a sampled variant,
per-episode columns, a start-of-batch call, one world at a time) and never checks its class: a user's
policy reports what AMAT reports. And an env-only install plays the planners."""

from __future__ import annotations

import hashlib
import subprocess
import sys

import numpy as np
import pytest

from catmip_env.play import MESSAGE_COLUMNS
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate
from catmip_rl.evaluation.user_policy import PolicyError

SETTING = EvalSetting("task1")


class Counting:
    """Engine level: first allowed goal (``last``: last allowed), counting its decisions per world."""

    def __init__(self, last: bool = False):
        self.last, self.started, self.seeds = last, [], []

    def start_episodes(self, num_worlds, num_robots):
        self.started.append((num_worlds, num_robots))
        self.count = np.zeros(num_worlds, np.int64)

    def act(self, engine):
        self.count += engine.active.sum(-1)
        masks = engine.masks[..., ::-1] if self.last else engine.masks
        index = masks.argmax(-1)
        return masks.shape[-1] - 1 - index if self.last else index

    def episode_columns(self):
        return {"my_decisions": self.count}

    def sampled(self, seed):
        self.seeds.append(seed)
        return Counting(last=True)


def test_a_users_policy_gets_a_sampled_pass_and_its_own_columns():
    policy = Counting()
    res = evaluate("mine", SETTING, episodes=4, seed=5, policy=policy)
    assert policy.started == [(4, 2)] and policy.seeds == [0]  # Task 1: two robots; told nothing of the maps
    assert [r["my_decisions"] for r in res.episodes] == policy.count.tolist()
    assert [r["my_decisions"] for r in res.episodes] == [
        r["decisions"] for r in res.episodes
    ]  # what it counted
    assert all(r["messages"] == 0 for r in res.episodes)  # no traffic reported: none sent
    assert "sampled_success_rate" in res.summary and all("sampled_rescue_tick" in r for r in res.episodes)
    last = evaluate("last", SETTING, episodes=4, seed=5, policy=Counting(last=True), sampled_too=False)
    assert [r["sampled_rescue_tick"] for r in res.episodes] == [r["rescue_tick"] for r in last.episodes]
    assert "sampled_success_rate" not in last.summary
    assert (
        res.summary["actions"] == "its own"
        and res.summary["sampled_pass"]
        and not last.summary["sampled_pass"]
    )


def test_the_summary_says_argmax_or_sampled(capsys, tmp_path):
    from catmip_rl.cli.main import main

    class Sampling(Counting):
        deterministic = False

    assert evaluate("s", SETTING, episodes=2, seed=0, policy=Sampling()).summary["actions"] == "sampled"
    assert (
        main(["eval", "--method", "amat:task1", "--episodes", "2", "--out", str(tmp_path), "--no-progress"])
        == 0
    )
    out = capsys.readouterr().out
    assert "amat_task1 (argmax actions) on task1" in out and "with sampled actions on the same maps" in out
    assert (tmp_path / "curve.png").stat().st_size > 5000 and "curve.png" in out  # with its 95 % band


def test_a_policy_without_hooks_reports_no_traffic_and_no_sampled_pass():
    class Plain:
        def act(self, engine):
            return engine.masks.argmax(-1)

    res = evaluate("plain", SETTING, episodes=2, seed=0, policy=Plain())
    assert all(r[c] == 0 for r in res.episodes for c in MESSAGE_COLUMNS)
    assert "sampled_success_rate" not in res.summary


def test_a_pettingzoo_policy_reports_one_value_per_episode():
    class PerEpisode:
        def __init__(self):
            self.decisions = []

        def reset(self):
            self.decisions.append(0)

        def act(self, observations, infos):
            active = [r for r in observations if infos[r]["active"]]
            self.decisions[-1] += len(active)
            return {r: int(np.argmax(observations[r]["action_mask"])) for r in active}

        def episode_columns(self):
            return {"pz_decisions": self.decisions}

    res = evaluate("pz", SETTING, episodes=3, seed=1, policy=PerEpisode())
    assert [r["pz_decisions"] for r in res.episodes] == [r["decisions"] for r in res.episodes]


@pytest.mark.parametrize(
    ("columns", "message"),
    [
        ({"mine": [1, 2]}, "column 'mine' holds int64 values of shape (2,), expected 3 numbers"),
        ({"mine": ["a", "b", "c"]}, "column 'mine' holds <U1 values"),
        ({"rescued": [0, 0, 0]}, "names the protocol's own column(s) ['rescued']"),
        ({"two words": [0, 0, 0]}, "column name 'two words' is not an identifier"),
    ],
)
def test_bad_columns_are_one_line_naming_the_column(columns, message):
    class Bad:
        def act(self, engine):
            return engine.masks.argmax(-1)

        def episode_columns(self):
            return columns

    with pytest.raises(ValueError, match="policy bad: episode_columns") as err:
        evaluate("bad", SETTING, episodes=3, seed=0, policy=Bad())
    assert message in str(err.value)


def test_a_crashing_hook_is_a_policy_error():
    class Crash(Counting):
        def sampled(self, seed):
            raise RuntimeError("no sampler")

    with pytest.raises(PolicyError, match=r"policy crash: sampled\(seed\) raised RuntimeError: no sampler"):
        evaluate("crash", SETTING, episodes=2, seed=0, policy=Crash())


def test_the_files_a_policy_reads_are_hashed_on_the_summary(tmp_path):
    weights = tmp_path / "weights.bin"
    weights.write_bytes(b"first weights")

    class Loaded(Counting):
        files = [weights]

    res = evaluate("loaded", SETTING, episodes=2, seed=0, policy=Loaded(), sampled_too=False)
    assert res.summary["policy_files"] == [
        {"file": str(weights), "sha256": hashlib.sha256(b"first weights").hexdigest()}
    ]
    assert evaluate("plain", SETTING, episodes=2, seed=0, policy=Counting()).summary["policy_files"] is None


@pytest.mark.parametrize(
    ("files", "message"),
    [("weights.bin", "files must be a list of paths"), (["missing.bin"], "files names 'missing.bin'")],
)
def test_bad_files_are_one_line_naming_them(files, message):
    class Bad(Counting):
        pass

    Bad.files = files
    with pytest.raises(PolicyError, match="policy bad: ") as err:
        evaluate("bad", SETTING, episodes=2, seed=0, policy=Bad())
    assert message in str(err.value)


ENV_ONLY = """
import sys
for name in ("torch", "torchrl", "tensordict"):
    sys.modules[name] = None  # as if only the env were installed
from catmip_rl.cli.main import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.slow
def test_an_env_only_install_evaluates_the_planners_and_names_the_extra_for_a_model(tmp_path):
    def catmip(*args):
        return subprocess.run([sys.executable, "-c", ENV_ONLY, *args], capture_output=True, text=True)

    done = catmip(
        "eval", "--method", "nearest", "--episodes", "2", "--out", str(tmp_path / "n"), "--no-progress"
    )
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "n" / "summary.json").is_file() and "nearest on task1" in done.stdout
    model = catmip("eval", "--method", "amat:task1", "--episodes", "2", "--out", str(tmp_path / "a"))
    assert model.returncode == 2 and "Traceback" not in model.stderr
    assert "this needs the 'rl' extra: pip install torch==2.13.0" in model.stderr
    assert not (tmp_path / "a").exists()
