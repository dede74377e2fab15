"""Clean occupancy: a cell-goal model's active robots read which explored cells are occupied from their
action masks (the engine computes them from the clean belief), not from the noisy occupied channel."""

import numpy as np
import pytest
import torch

from catmip_env.config import make_config
from catmip_env.constants import CH_OCCUPIED, EXPLORED, OBS_ONE, OCCUPIED
from catmip_env.engines.events import EventEngine, random_valid_actions
from catmip_rl.amat.inputs import clean_occupancy
from catmip_rl.amat.onboard.execution import CellGoalExecutor
from catmip_rl.benchmark.entry import entry_actions
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate
from catmip_rl.evaluation.methods import make_policy, parse_method
from catmip_rl.store.checkpoint import save_model
from tests.rl.amat.test_pointer import shaken


def decision_events(noise, events=25, worlds=4, seed=0):
    """(engine, active) at each of ``events`` decision events of Task-2 worlds in cell goal mode."""
    eng = EventEngine(
        make_config("task2", slam_noise=noise, comm_sigma=2.0), worlds, seed=seed, goal_mode="cell"
    )
    eng.reset()
    rng = np.random.default_rng(seed)
    for _ in range(events):
        yield eng, eng.active & ~eng.state.done[:, None]
        eng.step(random_valid_actions(eng.masks, rng))


def cleaned(eng, active):
    st = eng.state
    return clean_occupancy(eng.obs_global, eng.obs_local, eng.masks, st.pos, st.comp, active)


def test_under_slam_noise_active_robots_read_the_clean_beliefs_occupancy():
    noisy_cells = checked = 0
    for eng, active in decision_events(noise=0.1):
        g, loc = cleaned(eng, active)
        belief = eng.state.belief
        h, w = belief.shape[-2:]
        for b, i in zip(*np.nonzero(active), strict=True):
            explored = (belief[b, i] & EXPLORED) != 0
            clean = explored & ((belief[b, i] & OCCUPIED) != 0)
            mates = np.zeros((h, w), bool)  # a teammate of its neighbourhood stands there: free
            for j in np.flatnonzero(eng.state.comp[b] == eng.state.comp[b, i]):
                mates[tuple(eng.state.pos[b, j])] |= j != i
            pockets = explored & ~clean & ~mates & (eng.masks[b, i].reshape(h, w) == 0)  # free, no goal
            assert all(_walled(clean, r, c) for r, c in zip(*np.nonzero(pockets), strict=True))
            occupied = g[b, i, CH_OCCUPIED] >= OBS_ONE
            assert (occupied[~pockets] == clean[~pockets]).all()
            noisy_cells += int(((eng.obs_global[b, i, CH_OCCUPIED] >= OBS_ONE) != clean).sum())
            # the local window shows the same cells (outside the map: occupied, as before)
            half = loc.shape[-1] // 2
            padded = np.pad(g[b, i, CH_OCCUPIED].astype(int), half, constant_values=-1)
            r, c = eng.state.pos[b, i]
            window = padded[r : r + 2 * half + 1, c : c + 2 * half + 1]
            inside = window >= 0
            assert (loc[b, i, CH_OCCUPIED][inside] == window[inside]).all()
            assert (loc[b, i, CH_OCCUPIED][~inside] == eng.obs_local[b, i, CH_OCCUPIED][~inside]).all()
            checked += 1
        busy = ~active
        assert (g[busy] == eng.obs_global[busy]).all() and (loc[busy] == eng.obs_local[busy]).all()
        assert (np.delete(g, CH_OCCUPIED, axis=2) == np.delete(eng.obs_global, CH_OCCUPIED, axis=2)).all()
    assert checked > 20 and noisy_cells > 100  # the noise was there, and the copies do not show it


def _walled(occupied, r, c):
    h, w = occupied.shape
    return all(
        occupied[rr, cc]
        for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1))
        if 0 <= rr < h and 0 <= cc < w
    )


def test_without_noise_the_maps_are_unchanged():
    for eng, active in decision_events(noise=0.0):
        g, loc = cleaned(eng, active)
        assert (g == eng.obs_global).all() and (loc == eng.obs_local).all()
        assert g is not eng.obs_global and loc is not eng.obs_local  # copies: the engine's arrays untouched


def test_the_executor_gives_the_model_the_cleaned_maps(monkeypatch):
    eng = next(e for e, active in decision_events(noise=0.1, events=8) if active.sum() >= 2)
    active = eng.active & ~eng.state.done[:, None]
    model = shaken(3)
    seen = []
    embed = model.embed
    monkeypatch.setattr(model, "embed", lambda obs: seen.append(obs["global_map"].clone()) or embed(obs))
    plain = CellGoalExecutor(model).act(eng)
    clean = CellGoalExecutor(model, clean_occupancy=True).act(eng)
    w = np.flatnonzero(active.any(1))
    expected, _ = cleaned(eng, active)
    assert torch.equal(seen[0], torch.from_numpy(eng.obs_global[w]))
    assert torch.equal(seen[1], torch.from_numpy(expected[w])) and not torch.equal(seen[0], seen[1])
    assert np.take_along_axis(eng.masks, clean[..., None], -1).all() and plain.shape == clean.shape
    sampled = CellGoalExecutor(model, clean_occupancy=True, loop_guard=True).sampled(0)
    assert sampled.clean_occupancy and sampled.loop_guard and not sampled.deterministic


def test_amat_clean_and_a_file_that_asks_play_with_clean_occupancy(tmp_path):
    model = shaken(0)
    plain = save_model(model, tmp_path / "plain.pt")
    asks = save_model(
        model, tmp_path / "asks.pt", extra={"play": {"loop_guard": True, "clean_occupancy": True}}
    )
    assert not parse_method(f"amat:{plain}").clean_occupancy
    method = parse_method(f"amat-clean:{plain}")
    assert method.clean_occupancy and not method.loop_guard and method.name == "plain-clean"
    assert parse_method(f"amat:{asks}").clean_occupancy and parse_method(f"amat:{asks}").loop_guard
    setting = EvalSetting("task2", "2", 0.05, 10)
    summary = evaluate(f"amat-clean:{plain}", setting, 2, 0, sampled_too=False).summary
    assert summary["clean_occupancy"] is True and summary["loop_guard"] is False
    assert entry_actions(summary) == "argmax + clean occupancy"
    assert entry_actions({"actions": "argmax", "loop_guard": True, "clean_occupancy": True}) == (
        "argmax + loop guard + clean occupancy"
    )


def test_a_window_model_cannot_play_with_clean_occupancy(tmp_path):
    from catmip_rl.amat.config import AmatConfig
    from catmip_rl.amat.model import AMAT

    path = save_model(AMAT(AmatConfig(embed_dim=32)), tmp_path / "window.pt")
    with pytest.raises(ValueError, match="window model"):
        make_policy(parse_method(f"amat-clean:{path}"), make_config("task1"), seed=0)


def test_a_resumed_run_does_not_read_back_results_played_without_clean_occupancy(tmp_path):
    """The same name, file and setting played another way is another run: resuming it is an error."""
    from dataclasses import replace

    from catmip_rl.benchmark.jobs import Job, run_one

    path = save_model(shaken(0), tmp_path / "m.pt")
    setting = EvalSetting("task2", "2", 0.05, 10)
    plain = Job(
        parse_method(f"m=amat:{path}"), setting, 2, 0, str(tmp_path / "run"), resume=True, sampled=False
    )
    first = run_one(plain)
    assert run_one(plain)["summary"] == first["summary"]  # read back: the same way of playing
    clean = replace(plain, method=parse_method(f"m=amat-clean:{path}"))
    with pytest.raises(ValueError, match="holds other results .*clean_occupancy False"):
        run_one(clean)
