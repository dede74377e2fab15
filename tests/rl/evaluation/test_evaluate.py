"""Evaluation protocol, distributed execution, paper-figure runs, rendering and their CLI."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch

from catmip_env.engines.episode_stats import success_curve
from catmip_env.engines.events import EventEngine
from catmip_env.maps.map_sets import map_hash
from catmip_rl import AMAT, AmatConfig, save_model
from catmip_rl.amat.model import decision_order
from catmip_rl.amat.onboard.execution import AmatExecutor
from catmip_rl.amat.onboard.neighbourhoods import GOAL_BYTES, message_bytes
from catmip_rl.benchmark.paper import FIGURES, run_figure, summary_cell
from catmip_rl.cli.main import main as cli
from catmip_rl.cli.render import render_episode
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate
from catmip_rl.evaluation.methods import Method, parse_method, parse_runs


def _sharp_model(window: int = 7, seed: int = 0) -> AMAT:
    """A small AMAT whose policy logits are far apart (no near-ties for argmax to flip on)."""
    torch.manual_seed(seed)
    model = AMAT(AmatConfig(window=window, embed_dim=32))
    with torch.no_grad():
        model.policy_head[3].weight.mul_(300.0)
    return model.eval()


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    return str(save_model(_sharp_model(), tmp_path_factory.mktemp("m") / "model.pt"))


def test_evaluation_is_reproducible(ckpt):
    setting = EvalSetting("task1", "2", 0.05)
    for method in ("nearest", f"amat:{ckpt}"):
        a = evaluate(method, setting, episodes=3, seed=4)
        b = evaluate(method, setting, episodes=3, seed=4)
        assert a.episodes == b.episodes
        np.testing.assert_array_equal(a.curve, b.curve)


def test_every_method_sees_the_same_maps(ckpt, tmp_path):
    small_window = save_model(_sharp_model(window=5), tmp_path / "d5.pt")
    setting = EvalSetting("task2", "4")
    hashes = {}
    methods = ("nearest", "rrt", "random-rescue", "window:nearest", "window-noheading:rrt", f"amat:{ckpt}",
               f"amat:{small_window}")  # fmt: skip
    for method in methods:
        res = evaluate(method, setting, episodes=3, seed=11)
        hashes[method] = [r["map_hash"] for r in res.episodes]
    assert len({tuple(h) for h in hashes.values()}) == 1
    assert len(set(hashes["nearest"])) == 3  # three different maps
    other = evaluate("nearest", setting, episodes=3, seed=12)
    assert [r["map_hash"] for r in other.episodes] != hashes["nearest"]
    # a map depends on the episode index only: episode 1 alone equals episode 1 of the batch
    eng = EventEngine(setting.env_config(), 1, seed=11)
    eng.reset(episode_indices=[1])
    assert map_hash(eng, 0) == hashes["nearest"][1]


def test_curve_is_monotone_and_matches_the_episodes(ckpt):
    res = evaluate("random-rescue", EvalSetting("task1"), episodes=8, seed=2)
    curve = res.curve
    assert curve.shape == (301,)
    assert np.all(np.diff(curve) >= 0)
    ticks = [r["rescue_tick"] for r in res.episodes]
    for t in (0, 50, 100, 200, 300):
        assert curve[t] == pytest.approx(np.mean([x is not None and x <= t for x in ticks]))
    assert res.summary["success_rate"] == pytest.approx(np.mean([r["rescued"] for r in res.episodes]))
    assert res.summary["success_by_100"] == curve[100]
    np.testing.assert_array_equal(success_curve(np.array([-1, 3, 3, 5]), 5), [0, 0, 0, 0.5, 0.5, 0.75])


def _centralised(model: AMAT, eng: EventEngine) -> np.ndarray:
    st = eng.state
    obs = {
        "global_map": torch.from_numpy(eng.obs_global),
        "local_map": torch.from_numpy(eng.obs_local),
        "agent_class": torch.nn.functional.one_hot(torch.from_numpy(st.cls), 2).float(),
    }
    active = torch.from_numpy(eng.active & ~st.done[:, None])
    with torch.no_grad():
        rep, _ = model.encode(model.embed(obs))
        a, _ = model.decode_autoregressive(
            rep, torch.from_numpy(eng.masks), decision_order(active), active, obs["agent_class"], True
        )
    return np.where(active.numpy(), a.numpy(), eng.masks.argmax(-1))


@pytest.mark.parametrize("task", ["task1", "task2"])
def test_distributed_execution_equals_centralised_under_full_communication(task):
    model = _sharp_model()
    eng = EventEngine(EvalSetting(task).env_config(), 3, seed=5)
    eng.reset()
    executor = AmatExecutor(model)
    compared = 0
    for _ in range(40):
        if eng.state.done.all():
            break
        live_active = eng.active & ~eng.state.done[:, None]
        want = _centralised(model, eng)
        got = executor.act(eng)
        np.testing.assert_array_equal(got[live_active], want[live_active])
        compared += int(live_active.sum())
        eng.step(got)
    assert compared > 40


@pytest.mark.parametrize("setting", [("task2", "full"), ("task3", "2")])
def test_the_batch1_runtime_decides_as_the_torch_batch(setting):
    """AmatExecutor's argmax decisions on FastAmat (one neighbourhood at a time) equal the padded torch
    batch's, with the same neighbourhood rows and so the same message counts."""
    model = _sharp_model()
    cfg = EvalSetting(*setting).env_config()
    engines = [EventEngine(cfg, 4, seed=2) for _ in range(2)]
    fast, torch_batch = AmatExecutor(model), AmatExecutor(model, fast=False)
    assert fast.fast is not None and torch_batch.fast is None
    for eng in engines:
        eng.reset()
    decided = 0
    for _ in range(30):
        if engines[0].state.done.all():
            break
        a, b = fast.act(engines[0]), torch_batch.act(engines[1])
        active = engines[0].active & ~engines[0].state.done[:, None]
        np.testing.assert_array_equal(a[active], b[active])
        decided += int(active.sum())
        for eng in engines:
            eng.step(a)
    assert decided > 30
    np.testing.assert_array_equal(fast.messages, torch_batch.messages)
    np.testing.assert_array_equal(fast.bytes_embedding, torch_batch.bytes_embedding)


def test_distributed_execution_splits_neighbourhoods():
    """Under partial communication each neighbourhood decides on its own members' tokens only, and
    the messages are counted per neighbourhood."""
    model = _sharp_model()
    cfg = EvalSetting("task3", "2").env_config()
    eng = EventEngine(cfg, 2, seed=1)
    eng.reset()
    executor = AmatExecutor(model)
    seen_split = False
    for _ in range(30):
        st = eng.state
        active = eng.active & ~st.done[:, None]
        before = executor.messages.copy() if executor.messages is not None else np.zeros(2, np.int64)
        got = executor.act(eng)
        sizes = message_bytes(model.config, eng.shape)
        for b in range(2):
            expect_msgs, expect_bytes = 0, 0
            for label in np.unique(st.comp[b]):
                members = np.flatnonzero(st.comp[b] == label)
                if not active[b, members].any():
                    continue
                seen_split |= len(members) < cfg.num_robots
                sub = {
                    "global_map": torch.from_numpy(eng.obs_global[b, members])[None],
                    "local_map": torch.from_numpy(eng.obs_local[b, members])[None],
                    "agent_class": torch.nn.functional.one_hot(
                        torch.from_numpy(st.cls[b, members]), 2
                    ).float()[None],
                }
                act = torch.from_numpy(active[b, members])[None]
                with torch.no_grad():
                    rep, _ = model.encode(model.embed(sub))
                    a, _ = model.decode_autoregressive(
                        rep, torch.from_numpy(eng.masks[b, members])[None], decision_order(act), act,
                        sub["agent_class"], True,
                    )  # fmt: skip
                sel = active[b, members]
                np.testing.assert_array_equal(got[b, members][sel], a[0].numpy()[sel])
                others = members[1:]
                goals = int(active[b, others].sum())
                expect_msgs += len(others) + goals
                expect_bytes += len(others) * sizes["embedding"] + goals * GOAL_BYTES
            assert executor.messages[b] - before[b] == expect_msgs
        eng.step(got)
    assert seen_split, "no event with more than one neighbourhood: pick another seed"
    assert executor.bytes_raw.sum() > 20 * executor.bytes_embedding.sum() > 0


def test_parse_method_errors(tmp_path):
    assert parse_method("rrt").kind == "planner"
    assert parse_method("best=nearest").name == "best"
    with pytest.raises(ValueError, match="unknown method"):
        parse_method("astar")
    assert parse_method("window:rrt") == Method("window:rrt", "window", "rrt")
    assert parse_method("window-noheading:rrt") == Method("window-noheading:rrt", "window-noheading", "rrt")
    for spec in ("window:astar", "window-noheading:astar"):
        with pytest.raises(ValueError, match="unknown planner 'astar'"):
            parse_method(spec)
    # a near miss names the fix, and the choices list every kind of method
    typos = {"nearset": "nearest", "window:nearset": "window:nearest", "amta:task1": "amat:task1",
             "windw:rrt": "window:rrt", "sycn:rrt": "sync:rrt"}  # fmt: skip
    for typo, fix in typos.items():
        with pytest.raises(ValueError, match=f"did you mean {fix}\\?") as err:
            parse_method(typo)
    for kind in ("window:PLANNER", "amat-guard:PATH", "sync:METHOD", "py:FILE.py:FACTORY", "'rrt'"):
        assert kind in str(err.value)
    with pytest.raises(ValueError, match="unknown method 'dijkstra'; choose"):  # nothing close: no guess
        parse_method("dijkstra")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        parse_method(f"amat:{tmp_path / 'none.pt'}")
    with pytest.raises(ValueError, match="empty name"):
        parse_method("=nearest")
    for comm in ("far", "inf", "nan", "-4"):
        with pytest.raises(ValueError, match="comm must be 'full' or a positive, finite range sigma"):
            EvalSetting("task1", comm)
    with pytest.raises(ValueError, match="unknown task"):
        EvalSetting("task9")


def test_write_and_cli_eval(ckpt, tmp_path, capsys):
    assert cli(["eval", "--method", f"amat:{ckpt}", "--task", "task1", "--comm", "4", "--episodes", "2",
                "--out", str(tmp_path / "e"), "--no-progress", "--threads", "1"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert "bytes with embeddings" in out
    summary = json.loads((tmp_path / "e" / "summary.json").read_text())
    assert summary["episodes"] == 2 and summary["setting"]["comm"] == "4"
    with open(tmp_path / "e" / "episodes.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 and {"rescue_tick", "target_found_tick", "explored_fraction", "bytes_raw"} <= set(
        rows[0]
    )
    assert "with sampled actions on the same maps" in out and "stalls per episode" in out
    assert {"sampled_success_rate", "sampled_success_by_100", "stalls_per_episode", "stall_fraction_rescuer",
            "decisions_per_episode"} <= set(summary)  # fmt: skip
    curve = list(csv.DictReader(open(tmp_path / "e" / "curve.csv")))
    assert float(curve[-1]["sampled_success_rate"]) == summary["sampled_success_rate"]
    assert cli(["eval", "--method", "dijkstra", "--out", str(tmp_path / "x")]) == 2
    assert "unknown method" in capsys.readouterr().err


def test_figure_runs_on_a_tiny_budget(ckpt, tmp_path):
    fig_dir = run_figure(11, ["nearest", f"learned=amat:{ckpt}"], episodes=2, out=tmp_path, progress=False)
    assert (fig_dir / "fig11.png").stat().st_size > 1000
    assert "| learned |" in (fig_dir / "summary.md").read_text()
    assert "| learned (sampled) |" in (fig_dir / "summary.md").read_text()  # AMAT: sampled beside argmax
    with open(fig_dir / "curves.csv") as f:
        rows = list(csv.DictReader(f))
    assert {r["panel"] for r in rows} == {p for p, _ in FIGURES[11][1]}
    assert {r["method"] for r in rows} == {"nearest", "learned", "learned (sampled)"}
    # the plotted curve is the per-episode data
    for panel, setting in FIGURES[11][1]:
        episodes = json.loads((fig_dir / setting.label / "nearest" / "episodes.json").read_text())
        curve = [float(r["success_rate"]) for r in rows if r["panel"] == panel and r["method"] == "nearest"]
        assert len(curve) == 401
        assert np.all(np.diff(curve) >= 0)
        assert curve[-1] == np.mean([e["rescued"] for e in episodes])
        band = [
            (float(r["ci_low"]), float(r["ci_high"]))
            for r in rows
            if r["panel"] == panel and r["method"] == "nearest"
        ]
        assert all(low <= v <= high for (low, high), v in zip(band, curve))  # the 95 % band holds the curve
    marl = json.loads((fig_dir / "marl_eval.json").read_text())
    run = marl["catmip-fig11"]["task2-full-noise0-ma5"]["learned"]["seed_0"]
    assert len(run["step_0"]["success"]) == 2 and "success_rate" in run["absolute_metrics"]


def test_parse_runs_names_the_training_runs_of_one_method(ckpt):
    assert parse_runs("rrt") == [Method("rrt", "planner", "rrt")]
    runs = parse_runs(f"mine=amat:{ckpt}, amat:{ckpt}")
    assert [(m.name, m.kind) for m in runs] == [("mine", "amat"), ("mine", "amat")]
    with pytest.raises(ValueError, match="several runs need one name: write NAME=nearest,rrt"):
        parse_runs("nearest,rrt")
    with pytest.raises(ValueError, match="unknown method 'astar'"):
        parse_runs("two=nearest,astar")


def test_cli_bench_paper_names_a_nameless_group_of_runs(tmp_path, capsys):
    assert cli(["bench", "paper", "--figure", "6", "--method", "nearest,rrt", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "several runs need one name: write NAME=nearest,rrt" in err and "Traceback" not in err
    assert not any(tmp_path.iterdir())


def test_figure_summarises_several_runs_of_a_method_with_a_ci_over_runs_and_maps(tmp_path):
    """Two planners given as the "training runs" of one method: its row is their mean, its curve the mean
    curve, its CI over runs and maps; each run is written and enters marl-eval as its own seed."""
    fig = run_figure(11, ["nearest", "rrt", "pair=nearest,rrt"], episodes=6, out=tmp_path, progress=False)
    with open(fig / "summary.csv") as f:
        rows = {(r["panel"], r["method"]): r for r in csv.DictReader(f)}
    with open(fig / "curves.csv") as f:
        curves = list(csv.DictReader(f))
    marl = json.loads((fig / "marl_eval.json").read_text())["catmip-fig11"]
    for panel, setting in FIGURES[11][1]:
        one, two, pair = (rows[panel, m] for m in ("nearest", "rrt", "pair"))
        assert (int(one["runs"]), int(pair["runs"])) == (1, 2)
        assert (one["ci_over"], pair["ci_over"]) == ("maps", "runs and maps")
        for key in ("success_by_100", "success_rate", "mean_rescue_tick"):
            assert float(pair[key]) == pytest.approx((float(one[key]) + float(two[key])) / 2)
        low, high = float(pair["success_by_100_ci_low"]), float(pair["success_by_100_ci_high"])
        assert 0 <= low <= float(pair["success_by_100"]) <= high <= 1
        curve = {m: [float(r["success_rate"]) for r in curves if r["panel"] == panel and r["method"] == m]
                 for m in ("nearest", "rrt", "pair")}  # fmt: skip
        assert np.allclose(curve["pair"], (np.array(curve["nearest"]) + np.array(curve["rrt"])) / 2)
        for k, planner in enumerate(("nearest", "rrt")):
            run = json.loads((fig / setting.label / "pair" / f"run{k}" / "episodes.json").read_text())
            alone = json.loads((fig / setting.label / planner / "episodes.json").read_text())
            assert [e["rescue_tick"] for e in run] == [e["rescue_tick"] for e in alone]
            assert marl[setting.label]["pair"][f"seed_{k}"]["step_0"]["success"] == [
                float(e["rescued"]) for e in alone
            ]
    assert "| pair |" in (fig / "summary.md").read_text()


def test_summary_cell_shows_a_ci_where_the_row_has_one():
    row = {"success_by_100": 0.8512, "success_rate": 1.0, "mean_rescue_tick": 47.6}
    assert summary_cell(row) == "0.85 / 1.00 / 48"
    ci = {"success_by_100_ci_low": "0.781", "success_by_100_ci_high": "0.9", "mean_rescue_tick": ""}
    assert summary_cell(row | ci) == "0.85 [0.78, 0.90] / 1.00 / –"


@pytest.mark.parametrize("figure", sorted(FIGURES))
def test_cli_bench_paper_every_figure(figure, tmp_path):
    assert cli(["bench", "paper", "--figure", str(figure), "--methods", "nearest", "--episodes", "1",
                "--jobs", "1", "--out", str(tmp_path)]) == 0  # fmt: skip
    assert (tmp_path / f"fig{figure}" / f"fig{figure}.png").exists()


def test_render_gif(ckpt, tmp_path):
    iio = pytest.importorskip("imageio.v3")
    path = render_episode(f"amat:{ckpt}", EvalSetting("task1", "2"), tmp_path / "ep.gif", max_frames=25)
    frames = iio.imread(path)
    assert frames.shape[0] == 25 and frames.shape[-1] == 3
    assert cli(["render", "--method", "nearest", "--out", str(tmp_path / "n.gif"), "--threads", "1"]) == 0


def test_cli_bench_perf_needs_the_repository(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert cli(["bench", "perf", "--quick"]) == 2
    assert "benchmarks/run_all.py" in capsys.readouterr().err
    assert cli(["bench", "paper", "--figure", "6", "--all"]) == 2


def test_sampled_actions_and_stalls_are_reported_beside_argmax(ckpt):
    res = evaluate(f"amat:{ckpt}", EvalSetting("task1"), episodes=6, seed=3)
    again = evaluate(f"amat:{ckpt}", EvalSetting("task1"), episodes=6, seed=3)
    assert np.array_equal(res.sampled_curve, again.sampled_curve)  # seeded sampling
    ticks = [r["sampled_rescue_tick"] for r in res.episodes]
    assert res.summary["sampled_success_rate"] == pytest.approx(np.mean([t is not None for t in ticks]))
    assert res.summary["stalls_per_episode"] == pytest.approx(np.mean([r["stalls"] for r in res.episodes]))
    planner = evaluate("window:nearest", EvalSetting("task1"), episodes=6, seed=3)
    assert planner.sampled_curve is None and "sampled_success_rate" not in planner.summary
    assert planner.summary["success_rate"] >= 5 / 6


def test_the_loop_guard_breaks_argmax_loops_of_a_policy_that_always_stays(tmp_path):
    model = AMAT(AmatConfig(embed_dim=32))
    with torch.no_grad():
        model.policy_head[-1].bias[model.config.num_actions // 2] = 50.0  # argmax: always "stay"
    path = save_model(model, tmp_path / "stay.pt")
    setting = EvalSetting("task1")
    plain = evaluate(f"amat:{path}", setting, episodes=4, seed=0, sampled_too=False).summary
    guarded = evaluate(f"amat-guard:{path}", setting, episodes=4, seed=0, sampled_too=False).summary
    assert plain["stall_fraction_rescuer"] > 0.95 and plain["success_rate"] == 0.0
    # a stalled robot may not repeat its goal: at most every other macro-action stalls
    for cls in ("rescuer", "explorer"):
        assert guarded[f"stall_fraction_{cls}"] <= 0.55
    assert guarded["mean_explored_fraction"] > plain["mean_explored_fraction"]
    assert parse_method(f"amat-guard:{path}").loop_guard and not parse_method(f"amat:{path}").loop_guard


def test_a_model_trained_synchronously_plays_synchronously_on_the_same_maps(ckpt, tmp_path):
    sync_model = save_model(_sharp_model(), tmp_path / "sync.pt", extra={
        "train_config": {"env_overrides": {"synchronous": True}}})  # fmt: skip
    assert parse_method(f"amat:{sync_model}").synchronous and not parse_method(f"amat:{ckpt}").synchronous
    assert parse_method("sync:nearest") == Method("sync:nearest", "planner", "nearest", synchronous=True)
    assert parse_method("S=sync:window:rrt") == Method("S", "window", "rrt", synchronous=True)
    setting = EvalSetting("task2", "4", max_ma_ticks=5)
    seen: dict[str, set] = {}

    def hook(name):  # (the world's rule, the tick of each decision event of a world that goes on, modulo 5)
        def record(eng):
            for t in eng.state.ticks[~eng.state.done]:
                seen.setdefault(name, set()).add((eng.cfg.synchronous, int(t) % 5))

        return record

    hashes = {}
    for method in (f"amat:{sync_model}", "sync:nearest", "nearest", f"amat:{ckpt}"):
        res = evaluate(method, setting, episodes=2, seed=3, engine_hook=hook(method), sampled_too=False)
        hashes[method] = [r["map_hash"] for r in res.episodes]
        assert res.summary["synchronous"] == (method in (f"amat:{sync_model}", "sync:nearest"))
    assert len({tuple(h) for h in hashes.values()}) == 1
    for method in (f"amat:{sync_model}", "sync:nearest"):  # every decision on the 5-tick beat
        assert {sync for sync, _ in seen[method]} == {True}
        assert {phase for _, phase in seen[method]} <= {0}, seen[method]
    assert {sync for sync, _ in seen["nearest"]} == {False} and len(seen["nearest"]) > 1
