"""catmip leaderboard --replay: an entry is played again from the files it names and refused in one line
when a replayed rescue tick differs from the one it states, or a file is not the one it played."""

from __future__ import annotations

import json
import textwrap
from dataclasses import replace

import numpy as np
import pytest

from catmip_rl.benchmark.entry import SETTINGS
from catmip_rl.benchmark.suite import run_suite
from catmip_rl.cli.main import main

POLICY = textwrap.dedent(
    """
    from pathlib import Path

    class LastAllowed:
        files = [Path(__file__).with_name("weights.bin")]

        def act(self, engine):
            return engine.masks.shape[-1] - 1 - engine.masks[..., ::-1].argmax(-1)

    def make_policy(env_config, seed):
        return LastAllowed()
    """
)


@pytest.fixture(scope="module")
def entries(tmp_path_factory):
    out = tmp_path_factory.mktemp("replay")
    (out / "mine.py").write_text(POLICY)
    (out / "weights.bin").write_bytes(b"trained")
    methods = ["rrt", f"mine=py:{out / 'mine.py'}:make_policy"]
    about = {"classes": {"mine": "learned"}, "chosen_on": {"rrt": "nothing", "mine": "validation split"}}
    run_suite(methods, out / "s", episodes=3, progress=False, split="test", **about)
    return out


def _board(folder, out, k=2, episodes=3):
    return ["leaderboard", "--entries", str(folder), "--episodes", str(episodes), "--replay", str(k),
            "--fresh", "0", "--jobs", "1", "--no-progress", "--out", str(out)]  # fmt: skip


@pytest.mark.slow
def test_replayed_entries_are_marked_verified(entries, capsys):
    assert main(_board(entries / "s" / "entries", entries / "lb")) == 0
    md = (entries / "lb" / "leaderboard.md").read_text()
    assert md.count("✓ 2 replayed") == 2 and "(test split)" in md


def test_an_entry_with_one_edited_tick_is_refused_in_one_line(entries, tmp_path, capsys):
    """One rescue tick edited by hand, and every number the entry states restated to fit it: the checks
    of the numbers pass, the replay does not."""
    from catmip_rl.benchmark.entry import iqm_interval, rescued_by_100, setting_numbers
    from catmip_rl.benchmark.entry_check import check_entry

    entry = json.loads((entries / "s" / "entries" / "rrt.json").read_text())
    label = SETTINGS[7].label
    setting = entry["settings"][label]
    ticks = setting["rescue_tick"][0]
    ticks[1] = ticks[1] - 1 if ticks[1] > 0 else 57
    setting.update(setting_numbers(np.array([ticks]), setting["horizon"]))
    success = [rescued_by_100(np.array(s["rescue_tick"]), s["horizon"]) for s in entry["settings"].values()]
    iqm, low, high = iqm_interval(success)
    entry["aggregate"] = {"iqm_success_by_100": iqm, "iqm_success_by_100_ci": [low, high]}
    check_entry(entry, 3)
    (tmp_path / "rrt.json").write_text(json.dumps(entry))
    assert main(_board(tmp_path, tmp_path / "lb", k=3)) == 2
    err = capsys.readouterr().err
    assert (
        err.count("\n") == 1
        and f"refused: rrt.json: replaying map 1 of {label} (run 0) gave rescue tick" in err
    )
    md = (tmp_path / "lb" / "leaderboard.md").read_text()  # the page lists it, ranks none of it
    assert "**Refused** (1):" in md and "| rrt |" not in md


def test_an_entry_whose_weights_changed_is_refused(entries, capsys):
    (entries / "weights.bin").write_bytes(b"trained again")
    try:
        assert main(_board(entries / "s" / "entries", entries / "lb2")) == 2
    finally:
        (entries / "weights.bin").write_bytes(b"trained")
    err = capsys.readouterr().err
    assert "weights.bin, whose SHA-256 differs from the entry's" in err and err.count("\n") == 1
    assert "| 1 | rrt |" in (entries / "lb2" / "leaderboard.md").read_text()  # the honest one ranked


WALKER = textwrap.dedent(
    """
    import gc
    import warnings
    import numpy as np

    warnings.simplefilter("ignore", FutureWarning)  # the walk touches torch's deprecated names

    class Walker:
        '''PettingZoo level: finds the engine through the garbage collector and puts the rescuer next to
        the target (in-process it can; in the replay's worker there is no engine to find).'''
        def act(self, observations, infos):
            from catmip_env.engines.events import EventEngine
            for eng in (o for o in gc.get_objects() if isinstance(o, EventEngine)):
                eng.state.pos[:, 0] = eng.state.target + (0, 1)
            active = (r for r in observations if infos[r]["active"])
            return {r: int(np.argmax(observations[r]["action_mask"])) for r in active}

    def make_policy(env_config, seed):
        return Walker()
    """
)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::FutureWarning")  # the walk touches torch's deprecated names
def test_a_policy_that_reached_the_world_in_its_suite_is_refused_by_the_isolated_replay(
    tmp_path, capsys, monkeypatch
):
    from catmip_rl.benchmark import suite
    from catmip_rl.evaluation.methods import parse_runs

    # its suite played in-process (isolated=False), as no suite plays a py: policy now: a forged entry
    in_process = lambda spec: [replace(m, isolated=False) for m in parse_runs(spec)]  # noqa: E731
    monkeypatch.setattr(suite, "parse_runs", in_process)
    (tmp_path / "walker.py").write_text(WALKER)
    spec = f"cheat=py:{tmp_path / 'walker.py'}:make_policy"
    run_suite([spec], tmp_path / "s", episodes=2, progress=False, split="test",
              classes={"cheat": "learned"}, chosen_on={"cheat": "nothing"})  # fmt: skip
    assert main(_board(tmp_path / "s" / "entries", tmp_path / "lb", k=2, episodes=2)) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "refused: cheat.json: replaying map 0 of" in err
