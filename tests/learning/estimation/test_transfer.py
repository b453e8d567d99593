"""Policies trained on an estimate and scored on the truth (the NFPDE paper's Fig. 3): training
draws xi from the training sampler only, evaluation from the true sampler only, for our PPO and for
stable-baselines3's SAC; bad configurations and a missing sb3 are refused with clear errors."""

from __future__ import annotations

import sys

import gymnasium
import numpy as np
import pytest

from assembly.samplers import FullDR
from learning.estimation.transfer import SACConfig, TransferConfig, train_and_evaluate
from learning.ppo import PPOConfig

ENV = "goflow/Cartpole-v0"


class Recording(FullDR):
    """FullDR that keeps every draw."""

    def __init__(self, space):
        super().__init__(space)
        self.draws = []

    def sample(self, n, rng):
        xi = super().sample(n, rng)
        self.draws.append(xi)
        return xi


@pytest.fixture
def samplers():
    space = gymnasium.make(ENV).unwrapped.space
    return Recording(space), Recording(space)


def test_ppo_trains_on_the_estimate_and_scores_on_the_truth(samplers):
    train, truth = samplers
    cfg = TransferConfig(
        env=ENV,
        iterations=3,
        eval_every=2,
        eval_episodes=4,
        ppo=PPOConfig(num_envs=2, num_steps=32, num_minibatches=2, update_epochs=1),
    )
    res = train_and_evaluate(train, truth, cfg)
    assert [pt[0] for pt in res["curve"]] == [2 * 64, 3 * 64]  # at eval_every and at the end
    assert res["final_mean_return"] == res["curve"][-1][1] and np.isfinite(res["final_mean_return"])
    assert 0.0 <= res["final_success"] <= 1.0
    assert train.draws and truth.draws  # each sampler fed its own envs


def test_sac_trains_on_the_estimate_and_scores_on_the_truth(samplers):
    pytest.importorskip("stable_baselines3", reason="the optional extra sb3 is not installed")
    train, truth = samplers
    cfg = TransferConfig(
        env=ENV, algo="sac", eval_episodes=3, sac=SACConfig(steps=250, eval_every=100, learning_starts=50)
    )
    res = train_and_evaluate(train, truth, cfg)
    assert [pt[0] for pt in res["curve"]] == [100, 200, 250]
    assert len(truth.draws) == 3 * 3  # one draw per evaluation episode, nothing else
    assert train.draws
    again = train_and_evaluate(*(Recording(train.space), Recording(train.space)), cfg)
    assert again["curve"] == res["curve"]  # same seed, same curve


def test_bad_configurations_are_refused(samplers, monkeypatch):
    train, truth = samplers
    with pytest.raises(ValueError, match=r"TransferConfig.algo = 'td3'; expected one of \['ppo', 'sac'\]"):
        TransferConfig(algo="td3")
    with pytest.raises(ValueError, match=r"SACConfig.steps = 0; expected an integer >= 1"):
        SACConfig(steps=0)
    other = FullDR(gymnasium.make("goflow/Hopper-v0").unwrapped.space)
    with pytest.raises(ValueError, match="true_sampler's ParamSpace differs"):
        train_and_evaluate(train, other, TransferConfig(env=ENV))
    monkeypatch.setitem(sys.modules, "stable_baselines3", None)
    with pytest.raises(ImportError, match=r"pip install -e '\.\[sb3\]'"):
        train_and_evaluate(train, truth, TransferConfig(env=ENV, algo="sac"))
