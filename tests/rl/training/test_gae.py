"""Asynchronous GAE: a hand-computed sequence, and TorchRL's functional GAE in the degenerate case."""

import numpy as np
import pytest
import torch
from torchrl.objectives.value.functional import generalized_advantage_estimate

from catmip_rl.training.gae import async_gae, explained_variance

TRUNCATED = np.zeros(1, bool)  # one world that reached the horizon
RESCUED = np.ones(1, bool)


def test_hand_computed_asynchronous_sequence():
    # robot 0 decides at rows 0, 2, 3; robot 1 at rows 0, 3; gamma per tick, lambda
    g, lam = 0.9, 0.8
    active = np.zeros((4, 1, 2), bool)
    active[[0, 2, 3], 0, 0] = True
    active[[0, 3], 0, 1] = True
    valid = np.ones((4, 1), bool)
    values = np.zeros((4, 1, 2))
    values[[0, 2, 3], 0, 0] = [1.0, 2.0, 0.5]
    values[[0, 3], 0, 1] = [0.5, 1.5]
    ma_return = np.zeros((4, 1, 2))
    ma_ticks = np.zeros((4, 1, 2), np.int64)
    ma_return[2, 0, 0], ma_ticks[2, 0, 0] = 3.0, 4  # robot 0's first macro-action: rows 0 -> 2
    ma_return[3, 0, 0], ma_ticks[3, 0, 0] = 1.0, 2  # its second: rows 2 -> 3
    ma_return[3, 0, 1], ma_ticks[3, 0, 1] = 5.0, 6  # robot 1's first: rows 0 -> 3
    final = np.array([[2.0, 0.25]])  # the last macro-actions, cut off by the horizon
    adv, ret, trainable = async_gae(active, valid, values, ma_return, ma_ticks, final, TRUNCATED, g, lam)

    a0_3 = 2.0 - 0.5  # no bootstrap after the last macro-action
    a0_2 = (1.0 + g**2 * 0.5 - 2.0) + g**2 * lam * a0_3
    a0_0 = (3.0 + g**4 * 2.0 - 1.0) + g**4 * lam * a0_2
    a1_3 = 0.25 - 1.5
    a1_0 = (5.0 + g**6 * 1.5 - 0.5) + g**6 * lam * a1_3
    assert adv[[0, 2, 3], 0, 0] == pytest.approx([a0_0, a0_2, a0_3])
    assert adv[[0, 3], 0, 1] == pytest.approx([a1_0, a1_3])
    assert ret[[0, 2], 0, 0] == pytest.approx([a0_0 + 1.0, a0_2 + 2.0])
    assert trainable[:, 0, 0].tolist() == [True, False, True, False]  # the last one is not trained on
    assert trainable[:, 0, 1].tolist() == [True, False, False, False]
    assert adv[1, 0].tolist() == [0.0, 0.0]  # rows where the robot does not decide


def test_invalid_rows_are_ignored():
    active = np.ones((3, 2, 1), bool)
    valid = np.array([[True, True], [True, False], [False, False]])
    values = np.ones((3, 2, 1))
    ret_in = np.ones((3, 2, 1))
    ticks = np.ones((3, 2, 1), np.int64)
    adv, _, trainable = async_gae(
        active, valid, values, ret_in, ticks, np.zeros((2, 1)), np.zeros(2, bool), 1.0, 0.95
    )
    assert trainable[:, 0, 0].tolist() == [True, False, False]
    assert trainable[:, 1, 0].tolist() == [False, False, False]  # one decision only: unfinished
    assert adv[2].tolist() == [[0.0], [0.0]]


@pytest.mark.parametrize("gamma, lam", [(1.0, 0.95), (0.99, 0.9), (0.9, 0.0)])
def test_matches_torchrl_gae_when_every_robot_decides_every_tick(gamma, lam):
    rng = np.random.default_rng(0)
    t, n = 12, 3
    active = np.ones((t, 1, n), bool)
    valid = np.ones((t, 1), bool)
    values = rng.normal(size=(t, 1, n))
    rewards = rng.normal(size=(t, 1, n))  # reward of the macro-action started at row t
    ma_return = np.zeros((t, 1, n))
    ma_return[1:] = rewards[:-1]
    ticks = np.ones((t, 1, n), np.int64)
    adv, ret, _ = async_gae(active, valid, values, ma_return, ticks, rewards[-1], TRUNCATED, gamma, lam)
    v = torch.from_numpy(values[:, 0].T[..., None]).double()  # (N, T, 1)
    r = torch.from_numpy(rewards[:, 0].T[..., None]).double()
    next_v = torch.cat([v[:, 1:], torch.zeros_like(v[:, :1])], 1)
    done = torch.zeros_like(v, dtype=torch.bool)
    done[:, -1] = True  # the horizon ends the return: no bootstrap
    ref_adv, ref_target = generalized_advantage_estimate(gamma, lam, v, next_v, r, done, done.clone())
    np.testing.assert_allclose(
        adv[:, 0].T, ref_adv[..., 0].numpy(), atol=1e-6
    )  # TorchRL works in float32 internally
    np.testing.assert_allclose(
        ret[:, 0].T, ref_target[..., 0].numpy(), atol=1e-6
    )  # TorchRL works in float32 internally


def _rescue_sequence():
    """One world, two robots. Robot 0 (the rescuer) decides at rows 0, 1, 3 and its last macro-action
    (from row 3) reaches the target; robot 1 decides at rows 0, 2 and is busy when the rescue happens."""
    active = np.zeros((4, 1, 2), bool)
    active[[0, 1, 3], 0, 0] = True
    active[[0, 2], 0, 1] = True
    values = np.zeros((4, 1, 2))
    values[[0, 1, 3], 0, 0] = [10.0, 20.0, 50.0]
    values[[0, 2], 0, 1] = [5.0, 30.0]
    ma_return = np.zeros((4, 1, 2))
    ma_ticks = np.zeros((4, 1, 2), np.int64)
    ma_return[1, 0, 0], ma_ticks[1, 0, 0] = -0.1, 2
    ma_return[3, 0, 0], ma_ticks[3, 0, 0] = -0.2, 4
    ma_return[2, 0, 1], ma_ticks[2, 0, 1] = 99.0, 3  # it found the target
    final = np.array([[280.0, 279.9]])  # the success reward rides on everyone's last macro-action
    return active, np.ones((4, 1), bool), values, ma_return, ma_ticks, final


def test_a_rescue_completes_and_trains_every_robots_last_macro_action():
    active, valid, values, ma_return, ma_ticks, final = _rescue_sequence()
    adv, ret, trainable = async_gae(active, valid, values, ma_return, ma_ticks, final, RESCUED, 1.0, 0.5)
    # the rescuer's move that reached the target and the busy explorer's macro-action: R - V, trained
    assert adv[3, 0, 0] == pytest.approx(280.0 - 50.0) and trainable[3, 0, 0]
    assert adv[2, 0, 1] == pytest.approx(279.9 - 30.0) and trainable[2, 0, 1]
    assert ret[3, 0, 0] == pytest.approx(280.0) and ret[2, 0, 1] == pytest.approx(279.9)
    # earlier macro-actions bootstrap into them as usual
    a0_1 = (-0.2 + 50.0 - 20.0) + 0.5 * (280.0 - 50.0)
    assert adv[1, 0, 0] == pytest.approx(a0_1)
    assert adv[0, 0, 0] == pytest.approx((-0.1 + 20.0 - 10.0) + 0.5 * a0_1)
    assert adv[0, 0, 1] == pytest.approx((99.0 + 30.0 - 5.0) + 0.5 * (279.9 - 30.0))
    assert trainable[:, 0, 0].tolist() == [True, True, False, True]
    assert trainable[:, 0, 1].tolist() == [True, False, True, False]


def test_the_same_sequence_cut_off_by_the_horizon_drops_the_last_macro_actions():
    active, valid, values, ma_return, ma_ticks, final = _rescue_sequence()
    adv, _, trainable = async_gae(active, valid, values, ma_return, ma_ticks, final, TRUNCATED, 1.0, 0.5)
    assert trainable[:, 0, 0].tolist() == [True, True, False, False]
    assert trainable[:, 0, 1].tolist() == [True, False, False, False]
    assert adv[3, 0, 0] == pytest.approx(280.0 - 50.0)  # no bootstrap either way; only the flag differs


def test_worlds_of_one_batch_are_told_apart():
    active, valid, values, ma_return, ma_ticks, final = _rescue_sequence()
    two = [np.concatenate([x, x], 1) for x in (active, valid, values, ma_return, ma_ticks)]
    _, _, trainable = async_gae(*two, np.concatenate([final, final]), np.array([True, False]), 1.0, 0.5)
    assert trainable[3, 0, 0] and not trainable[3, 1, 0]
    assert trainable[2, 0, 1] and not trainable[2, 1, 1]


def test_explained_variance_reads_how_well_values_predict_returns():
    rng = np.random.default_rng(0)
    returns = rng.normal(10.0, 3.0, 500)
    assert explained_variance(returns, returns) == 1.0
    assert explained_variance(returns, np.full(500, returns.mean())) == pytest.approx(0.0, abs=1e-12)
    noisy = returns + rng.normal(0.0, 3.0, 500)  # errors as large as the returns' spread
    assert explained_variance(returns, noisy) == pytest.approx(0.0, abs=0.25)
    assert explained_variance(returns, -returns) < -1
    assert np.isnan(explained_variance(returns[:1], returns[:1]))
    assert np.isnan(explained_variance(np.ones(5), np.zeros(5)))
