"""The algorithm's equations and its SB3 integration (callbacks, logger, errors)."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch as th
from helpers import light_kwargs
from stable_baselines3.common.callbacks import CheckpointCallback, EvalCallback

from sb3_pola import POLA
from sb3_pola.pola.fast_sampling import sample_chain, sample_no_grad
from sb3_pola.pola.pola import lookahead_q_objective


# ---------------------------------------------------------------- eq. 4: top-K, gamma^i, terminations
def test_top_k_averages_the_k_smallest_members():
    q = th.tensor([5.0, 1.0, 3.0, 2.0, 4.0]).view(5, 1, 1)  # N=5, T+1=1, B=1
    _, per_step = lookahead_q_objective(q, th.ones(1, 1), th.ones(1), top_k=2)
    assert per_step.item() == pytest.approx(1.5)  # mean of 1 and 2
    _, per_step = lookahead_q_objective(q, th.ones(1, 1), th.ones(1), top_k=1)
    assert per_step.item() == pytest.approx(1.0)  # K = 1: the pessimistic min


def test_lookahead_terms_are_gamma_weighted_and_masked_after_termination():
    gamma = 0.9
    # N=2 members, T=2 (3 steps), B=2; member 0 is always the smaller one
    q = th.stack([th.tensor([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]), th.full((3, 2), 100.0)])
    alive = th.tensor([[1.0, 1.0], [1.0, 0.0], [1.0, 0.0]])  # sample 1's first predicted state is terminal
    loss, per_step = lookahead_q_objective(q, alive, th.tensor([1.0, gamma, gamma**2]), top_k=1)
    assert th.allclose(per_step, th.tensor([1.5, 1.5, 2.5]))
    scale = 1.5  # mean |Q| at the current states
    expected = -(1.5 + gamma * 1.5 + gamma**2 * 2.5) / scale
    assert loss.item() == pytest.approx(expected)


def test_terminal_lookahead_state_stops_later_terms(pendulum_path):
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(rollout_length=2))
    model.learn(1)
    obs = model.replay_buffer.sample(8).observations
    model._termination_fn = lambda s, a, s2: th.ones(s.shape[0], dtype=th.bool)  # every predicted state terminal
    _, stats = model._lookahead_q_loss(obs, model.policy.actor_features(obs))
    assert stats["lookahead_q_1"].item() == 0 and stats["lookahead_q_2"].item() == 0
    assert stats["lookahead_alive"].item() == 0
    assert stats["lookahead_q_0"].item() != 0


# ---------------------------------------------------------------- gradients through the look-ahead
def _actor_grad_from_step(model: POLA, step: int, obs: th.Tensor) -> tuple[float, th.Tensor | None]:
    """Actor gradient norm (and d loss / d obs) of the Q term of look-ahead step ``step`` alone."""
    weights = th.zeros(model.rollout_length + 1)
    weights[step] = 1.0
    model._lookahead_powers = weights  # eq. 3's weights (gamma^i times lookahead_weight)
    model.actor.zero_grad(set_to_none=True)
    obs = obs.clone().requires_grad_(True)
    with model._critic_frozen():
        q_loss, _ = model._lookahead_q_loss(obs, model.policy.actor_features(obs))
    q_loss.backward()
    norm = sum(p.grad.norm() ** 2 for p in model.actor.parameters() if p.grad is not None) ** 0.5
    assert all(p.grad is None for p in model.critic.parameters()), "the actor loss must not train the critic"
    return float(norm), obs.grad


@pytest.mark.parametrize("backprop", [True, False])
def test_gradient_reaches_actor_through_every_lookahead_step(pendulum_path, backprop):
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(rollout_length=3, backprop_through_model=backprop))
    model.learn(2)
    obs = model.replay_buffer.sample(16).observations
    model.critic.zero_grad(set_to_none=True)
    for step in range(model.rollout_length + 1):
        norm, obs_grad = _actor_grad_from_step(model, step, obs)
        assert norm > 0, f"no actor gradient from the Q term at look-ahead step {step}"
        if step > 0:
            # s_{t+step} depends on s_t only through the dynamics model: a gradient reaches s_t iff we backprop through it
            reached = obs_grad is not None and obs_grad.abs().sum().item() > 0
            assert reached == backprop


@pytest.mark.parametrize("lookahead_actions", ["actor", "ema"])
def test_ema_lookahead_actions_train_the_actor_only_through_the_model(pendulum_path, lookahead_actions):
    """``lookahead_actions="ema"``: the EMA actor acts at the predicted states, so a predicted state's Q term reaches
    the actor only through ``a_t`` and the model. With a model whose ``s'`` ignores the action it reaches nothing;
    with the actor acting there (the paper) it still does."""
    kwargs = light_kwargs(rollout_length=2, backprop_through_model=True, lookahead_actions=lookahead_actions)
    model = POLA("MlpPolicy", dataset=pendulum_path, **kwargs)
    model.learn(2)
    obs = model.replay_buffer.sample(16).observations
    model.critic.zero_grad(set_to_none=True)
    assert _actor_grad_from_step(model, 2, obs)[0] > 0  # the real model carries it from a_t
    zeros = th.zeros(len(obs))
    model._termination_fn = None
    model.policy.dynamics.step = lambda s, a: (s + 1.0, zeros, zeros, zeros)  # type: ignore[method-assign,union-attr]
    norm, _ = _actor_grad_from_step(model, 2, obs)
    assert (norm > 0) == (lookahead_actions == "actor")
    with pytest.raises(ValueError, match="backprop_through_model=True"):
        POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(lookahead_actions="ema"))


def test_dynamics_is_fitted_frozen_and_logged(pendulum_path):
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(dynamics_fit_kwargs=dict(max_epochs=6)))
    assert not bool(model.policy.dynamics_fitted)
    model.learn(2)
    assert bool(model.policy.dynamics_fitted)
    assert all(not p.requires_grad for p in model.policy.dynamics.parameters())
    info = model.dynamics_fit_info
    assert info["holdout_mse"] < info["no_change_mse"], info
    before = {k: v.clone() for k, v in model.policy.dynamics.state_dict().items()}
    model.learn(3)  # no refit, the model stays frozen
    assert all(th.equal(before[k], v) for k, v in model.policy.dynamics.state_dict().items())


def test_no_dynamics_model_for_rollout_length_zero(pendulum_path):
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(rollout_length=0))
    assert model.policy.dynamics is None


def test_products_feed_the_actor_only(pendulum_path):
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(use_state_products=True))
    n = 3  # Pendulum
    assert model.policy.features_extractor.features_dim == n + n * (n - 1) // 2
    assert model.critic.features_extractor.features_dim == n
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs())  # the default since #23: the raw state
    assert model.policy.features_extractor.features_dim == n


def test_normalisation_statistics_come_from_the_dataset(pendulum_path):
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs())
    mean, std = model._offline_data.obs_stats()
    assert np.allclose(model.policy.features_extractor.obs_mean.numpy(), mean)
    assert np.allclose(model.critic_target.features_extractor.obs_std.numpy(), std)


def test_ema_copies_then_averages(pendulum_path):
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(ema_start=10, ema_update_freq=5))
    model.learn(5)  # step 5 < ema_start: a copy
    for p, q in zip(model.actor.parameters(), model.policy.actor_ema.parameters(), strict=True):
        assert th.equal(p, q)
    ema_5 = [q.detach().clone() for q in model.policy.actor_ema.parameters()]
    model.learn(5, reset_num_timesteps=False)  # step 10 >= ema_start: ema = decay ema + (1 - decay) actor
    decay = model.ema_decay
    for p, q, before in zip(model.actor.parameters(), model.policy.actor_ema.parameters(), ema_5, strict=True):
        th.testing.assert_close(q, decay * before + (1 - decay) * p, rtol=1e-6, atol=1e-7)
    assert any(not th.equal(p, q) for p, q in zip(model.actor.parameters(), model.policy.actor_ema.parameters(), strict=True))
    ema_10 = [q.detach().clone() for q in model.policy.actor_ema.parameters()]
    model.learn(4, reset_num_timesteps=False)  # step 14: not a multiple of ema_update_freq, no update
    for q, before in zip(model.policy.actor_ema.parameters(), ema_10, strict=True):
        assert th.equal(q, before)


def test_eta_zero_is_behaviour_cloning(pendulum_path):
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(eta=0.0))
    model.learn(3)
    stats = model._update(model.replay_buffer.sample(8))
    assert stats["q_loss"].item() == 0 and stats["actor_loss"].item() == pytest.approx(stats["bc_loss"].item())


# ---------------------------------------------------------------- SB3 integration
def test_logger_tensorboard_and_callbacks(pendulum_path, tmp_path):
    model = POLA("MlpPolicy", dataset=pendulum_path, tensorboard_log=str(tmp_path / "tb"), **light_kwargs())
    eval_cb = EvalCallback(model.get_env(), eval_freq=10, n_eval_episodes=1, log_path=str(tmp_path / "eval"), verbose=0)
    ckpt_cb = CheckpointCallback(save_freq=10, save_path=str(tmp_path / "ckpt"), name_prefix="pola")
    model.learn(20, callback=[eval_cb, ckpt_cb], log_interval=10, progress_bar=True)
    assert eval_cb.n_calls == 20 and len(eval_cb.evaluations_timesteps) == 2
    assert sorted(os.listdir(tmp_path / "ckpt")) == ["pola_10_steps.zip", "pola_20_steps.zip"]
    event_files = list((tmp_path / "tb").rglob("events.out.tfevents.*"))
    assert event_files
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(event_files[0].parent))
    acc.Reload()
    tags = set(acc.Tags()["scalars"])
    for key in [
        "train/critic_loss",
        "train/actor_loss",
        "train/bc_loss",
        "train/q_loss",
        "train/lookahead_q_2",
        "eval/mean_reward",
    ]:
        assert key in tags, f"{key} missing from {sorted(tags)}"
    # the training statistics were written at every log_interval (10 and 20 steps), finite
    critic_losses = acc.Scalars("train/critic_loss")
    assert [event.step for event in critic_losses] == [10, 20]
    assert all(np.isfinite(event.value) for event in critic_losses)


def test_invalid_hyperparameters_raise(pendulum_path):
    with pytest.raises(ValueError, match="top_k"):
        POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(n_critics=2, top_k=3))
    with pytest.raises(ValueError, match="rollout_length"):
        POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(rollout_length=-1))
    with pytest.raises(ValueError, match="beta_schedule"):
        POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(beta_schedule="sigmoid"))


def test_model_without_dataset_cannot_learn(pendulum_path, tmp_path):
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs())
    model.dataset = None
    model.save(tmp_path / "m.zip")
    loaded = POLA.load(tmp_path / "m.zip", device="cpu")
    with pytest.raises(ValueError, match="no dataset"):
        loaded.learn(1)
    # passing the dataset again at load time works
    POLA.load(tmp_path / "m.zip", device="cpu", dataset=pendulum_path).learn(2, reset_num_timesteps=False)


def test_normalized_score_from_reference_scores(pendulum_path):
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs())
    model.ref_min_score, model.ref_max_score = -100.0, 100.0
    assert model.normalized_score([0.0, 100.0]) == pytest.approx(75.0)
    model.ref_min_score = None
    assert model.normalized_score([1.0]) is None


def test_deterministic_sample_is_the_noise_free_chain(pendulum_path):
    # eq. 5 with z = 0 from a_T = 0: no fixed noise draw that would bias every action the same way
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs())
    actor = model.policy.actor_ema
    obs = th.randn(6, 3)
    features = model.policy.actor_features(obs)
    with th.no_grad():
        x = th.zeros(6, actor.action_dim)
        for t in reversed(range(actor.n_diffusion_steps)):
            x = actor.schedule.step(actor.predict_noise(x, th.full((6,), t), features), t, x, None)
        expected = x.clamp(-1, 1)
        assert th.allclose(actor.sample(features, deterministic=True), expected, atol=1e-5)
        # and the fast forms of the chain, which predict and training run, give the same numbers
        assert th.allclose(sample_no_grad(actor, features, deterministic=True), expected, atol=1e-5)
    assert th.allclose(sample_chain(actor, features, deterministic=True).detach(), expected, atol=1e-5)
    # predict(deterministic=True) under deterministic_rule="noise_free" is that action, rescaled to the env's bounds
    model.policy.deterministic_rule = "noise_free"
    action, _ = model.predict(obs.numpy(), deterministic=True)
    assert np.allclose(action, model.policy.unscale_action(expected.numpy()), atol=1e-4)
