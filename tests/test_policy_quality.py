"""Issue #23's options for the policy's quality: x0-prediction, LayerNorm critics, a lower confidence bound in the
policy loss, the Q-to-BC gradient ratio and the deterministic rule of ``predict`` (the best candidate by Q)."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from helpers import light_kwargs, model_on_dataset

from sb3_pola.common.datasets import synthetic_dataset
from sb3_pola.common.diffusion import NoiseSchedule
from sb3_pola.common.torch_layers import vectorized_mlp
from sb3_pola.pola import pola as pola_module
from sb3_pola.pola.fast_sampling import sample_chain, sample_no_grad
from sb3_pola.pola.losses import (
    advantage_weights,
    lookahead_weights,
    pessimistic_q,
    value_expansion_objective,
    value_lower_bound,
)
from sb3_pola.pola.pola import PAPER_FORM, lookahead_q_objective
from sb3_pola.pola.policies import DiffusionActor


def light(**overrides) -> dict:
    """:func:`light_kwargs` without the seed and device that :func:`model_on_dataset` sets."""
    kwargs = light_kwargs(**overrides)
    del kwargs["seed"], kwargs["device"]
    return kwargs


# ---------------------------------------------------------------- x0-prediction
def test_sample_prediction_step_is_the_posterior_mean_of_the_clipped_output():
    schedule = NoiseSchedule(5, "vp", prediction_type="sample")
    x_t, out = th.randn(8, 3), 2.0 * th.randn(8, 3)
    for t in range(5):
        c1, c2 = schedule.posterior_mean_coef1[t], schedule.posterior_mean_coef2[t]
        expected = c1 * out.clamp(-1, 1) + c2 * x_t  # eq. 1's posterior mean with x_0 = the network's output
        assert th.allclose(schedule.step(out, t, x_t, None), expected, atol=1e-6)
        # the epsilon form reads the same output as noise: a different x_0
        assert not th.allclose(NoiseSchedule(5, "vp").step(out, t, x_t, None), expected, atol=1e-3)
    with pytest.raises(ValueError, match="prediction_type"):
        NoiseSchedule(5, "vp", prediction_type="v")


def test_sample_prediction_loss_regresses_the_action():
    th.manual_seed(0)
    actor = DiffusionActor(4, 2, [16], 5, prediction_type="sample")
    actions, features = th.rand(64, 2) * 2 - 1, th.randn(64, 4)
    th.manual_seed(1)
    loss = actor.loss(actions, features)
    th.manual_seed(1)  # the same t and noise draws
    t = th.randint(0, 5, (64,))
    x_t = actor.schedule.add_noise(actions, th.randn_like(actions), t)
    assert th.allclose(loss, ((actor.predict_noise(x_t, t, features) - actions) ** 2).mean())


@pytest.mark.parametrize("schedule", ["vp", "linear", "cosine"])
@pytest.mark.parametrize("deterministic", [True, False])
def test_fast_chains_equal_the_readable_chain_under_sample_prediction(schedule, deterministic):
    th.manual_seed(0)
    actor = DiffusionActor(6, 3, [32, 32], 5, schedule, prediction_type="sample")
    features = th.randn(300, 6)
    draws = [actor.sample, lambda f, **kw: sample_chain(actor, f, **kw), lambda f, **kw: sample_no_grad(actor, f, **kw)]
    outs = [draw(features, generator=th.Generator().manual_seed(3), deterministic=deterministic) for draw in draws]
    for out in outs[1:]:
        assert th.allclose(out, outs[0], atol=1e-5)


def test_sample_prediction_learns_a_regression_faster_than_epsilon():
    # a deterministic map a = tanh(W s): after the same steps, x0-prediction's noise-free chain is closer
    gen = th.Generator().manual_seed(0)
    w = th.randn(4, 2, generator=gen)
    errors = {}
    for kind in ("epsilon", "sample"):
        th.manual_seed(0)
        actor = DiffusionActor(4, 2, [64, 64], 5, prediction_type=kind)
        opt = th.optim.Adam(actor.parameters(), lr=1e-3)
        for _ in range(600):
            s = th.randn(128, 4)
            loss = actor.loss(th.tanh(s @ w), s)
            opt.zero_grad()
            loss.backward()
            opt.step()
        s = th.randn(2000, 4, generator=gen)
        errors[kind] = float(((sample_no_grad(actor, s, deterministic=True) - th.tanh(s @ w)) ** 2).mean())
    assert errors["sample"] < 0.8 * errors["epsilon"], errors


# ---------------------------------------------------------------- LayerNorm critics
def test_layer_norm_bounds_the_critic_off_the_data():
    th.manual_seed(0)
    plain = vectorized_mlp(5, 1, [32, 32], 3, th.nn.Mish)
    normed = vectorized_mlp(5, 1, [32, 32], 3, th.nn.Mish, layer_norm=True)
    assert sum(isinstance(m, th.nn.LayerNorm) for m in normed) == 2
    last = normed[-1]
    # with normalised features, |a_j| <= max(mish(sqrt(H)), 0.31): |Q| <= |W_last|_1 * that + |b|
    bound = float(
        last.weight.detach().abs().sum(dim=1).max() * th.nn.functional.mish(th.tensor(32**0.5))
        + last.bias.detach().abs().max()
    )
    far = 1e4 * th.randn(3, 256, 5)
    with th.no_grad():
        assert float(normed(far).abs().max()) <= bound + 1e-4
        assert float(plain(far).abs().max()) > 10 * bound  # unbounded without it


def test_critic_layer_norm_reaches_the_ensemble_and_survives_save_load(tmp_path):
    data = synthetic_dataset(300, 3, 2, seed=0)
    model = model_on_dataset(data, **light(rollout_length=0, policy_kwargs=dict(net_arch=[32, 32], critic_layer_norm=True)))
    assert any(isinstance(m, th.nn.LayerNorm) for m in model.critic.q_net)
    assert any(isinstance(m, th.nn.LayerNorm) for m in model.critic_target.q_net)
    model.save(tmp_path / "m.zip")
    from sb3_pola import POLA

    loaded = POLA.load(tmp_path / "m.zip")
    obs = th.randn(7, 3)
    act = th.rand(7, 2) * 2 - 1
    assert th.equal(loaded.critic(obs, act), model.critic(obs, act))


def test_critic_layer_norm_argument_sets_the_policy_and_files_without_it_load_plain(tmp_path):
    """``POLA(critic_layer_norm=...)`` reaches the critics through ``policy_kwargs`` (which take precedence); a model
    file saved before the argument existed has no such key and loads with plain critics."""
    from sb3_pola import POLA

    data = synthetic_dataset(300, 3, 2, seed=0)
    on = model_on_dataset(data, **light(rollout_length=0, critic_layer_norm=True))
    assert on.critic_layer_norm and on.policy.critic_layer_norm
    assert any(isinstance(m, th.nn.LayerNorm) for m in on.critic.q_net)
    off = model_on_dataset(data, **light(rollout_length=0, critic_layer_norm=False))
    assert not off.critic_layer_norm and not any(isinstance(m, th.nn.LayerNorm) for m in off.critic.q_net)
    given = light(rollout_length=0, critic_layer_norm=False, policy_kwargs=dict(net_arch=[32, 32], critic_layer_norm=True))
    assert model_on_dataset(data, **given).critic_layer_norm
    with pytest.raises(ValueError, match="critic_layer_norm"):
        model_on_dataset(data, **light(critic_layer_norm="yes"))
    # an old file: policy_kwargs without the key
    del off.policy_kwargs["critic_layer_norm"]
    off.save(tmp_path / "old.zip")
    loaded = POLA.load(tmp_path / "old.zip")
    assert not loaded.critic_layer_norm and not loaded.policy.critic_layer_norm
    obs, act = th.randn(5, 3), th.rand(5, 2) * 2 - 1
    assert th.equal(loaded.critic(obs, act), off.critic(obs, act))


# ---------------------------------------------------------------- lower confidence bound
def test_lcb_replaces_the_top_k_mean():
    q = th.tensor([[[1.0, 4.0]], [[3.0, 4.0]], [[5.0, 4.0]]])  # [N=3, T+1=1, B=2]
    alive, gammas = th.ones(1, 2), th.ones(1)
    _, per_step = lookahead_q_objective(q, alive, gammas, top_k=2, lcb_coef=1.0)
    # member mean 3 and 4, std 2 and 0: (3 - 2 + 4 - 0) / 2
    assert per_step.tolist() == pytest.approx([2.5])
    _, top_k = lookahead_q_objective(q, alive, gammas, top_k=2)
    assert top_k.tolist() == pytest.approx([(2.0 + 4.0) / 2])
    with pytest.raises(ValueError, match="lcb_coef"):
        model_on_dataset(synthetic_dataset(100, 3, 2), **light(lcb_coef=-1.0))


# ---------------------------------------------------------------- value expansion
def test_value_expansion_sums_predicted_rewards_then_q():
    """``V_h = sum_{i<h} gamma^i r_i + gamma^h Q_h`` with the ensemble's minimum (top_k=1); a terminal state ends
    the expansion after the reward of the step into it."""
    q = th.tensor([[[4.0], [6.0], [8.0]], [[5.0], [7.0], [2.0]]])  # [N=2, T+1=3, B=1]
    rewards = th.tensor([[2.0], [1.0]])  # [T=2, B=1]
    gammas = th.tensor([1.0, 0.5, 0.25])
    loss, per_step = value_expansion_objective(q, rewards, th.ones(3, 1), gammas, top_k=1)
    v = [4.0, 2.0 + 0.5 * 6.0, 2.0 + 0.5 * 1.0 + 0.25 * 2.0]
    assert per_step.tolist() == pytest.approx(v)
    assert loss.item() == pytest.approx(-sum(v) / 4.0)  # "first": summed, divided by |Q| at the current state
    mean_loss, _ = value_expansion_objective(q, rewards, th.ones(3, 1), gammas, top_k=1, normalization="weights")
    assert mean_loss.item() == pytest.approx(-sum(v) / 3 / 4.0)
    _, cut = value_expansion_objective(q, rewards, th.tensor([[1.0], [1.0], [0.0]]), gammas, top_k=1)
    assert cut.tolist() == pytest.approx([4.0, 5.0, 2.5])  # s_{t+2} terminal: r_0 + gamma r_1, no Q after it
    # with T = 0 it is eq. 4's single term
    first, _ = value_expansion_objective(q[:, :1], rewards[:0], th.ones(1, 1), gammas[:1], top_k=1)
    assert first.item() == pytest.approx(lookahead_q_objective(q[:, :1], th.ones(1, 1), gammas[:1], top_k=1)[0].item())


@pytest.mark.parametrize("target", ["q", "value_expansion"])
def test_value_expansion_reads_the_models_reward(target: str):
    """With ``lookahead_target="value_expansion"`` the look-ahead loss falls as the model's predicted reward rises,
    and ``V_h`` gains ``sum_{i<h} gamma^i`` per unit of reward; eq. 3's Q-only loss does not read it."""
    model = model_on_dataset(synthetic_dataset(200, 3, 2, seed=0), **light(lookahead_target=target, reward_scale=2.0))
    assert model_on_dataset(synthetic_dataset(200, 3, 2, seed=0), **light()).lookahead_target == "q"  # the default
    model.learn(1)
    assert model.policy.dynamics is not None
    obs = th.as_tensor(model.offline_data.observations[:16], dtype=th.float32)

    def loss_with_reward(value: float) -> tuple[float, dict[str, th.Tensor]]:
        model.policy.dynamics.step = lambda s, a: (s, th.full((len(s),), value), th.zeros(len(s)), th.zeros(len(s)))  # type: ignore[method-assign,union-attr]
        th.manual_seed(0)
        loss, stats = model._lookahead_q_loss(obs, model.policy.actor_features(obs))
        return loss.item(), stats

    (low, low_stats), (high, high_stats) = loss_with_reward(0.0), loss_with_reward(1.0)
    if target == "q":
        assert high == pytest.approx(low)
        return
    g = model.gamma
    # T = 2: V_1 gains 2 (reward_scale), V_2 gains 2 (1 + gamma); the loss is -(sum_h V_h) / |Q_0|
    assert (high_stats["lookahead_q_1"] - low_stats["lookahead_q_1"]).item() == pytest.approx(2.0, rel=1e-4)
    assert (high_stats["lookahead_q_2"] - low_stats["lookahead_q_2"]).item() == pytest.approx(2.0 * (1 + g), rel=1e-4)
    higher, _ = loss_with_reward(2.0)
    assert low > high and higher - high == pytest.approx(high - low, rel=1e-3)  # linear: a better reward, a lower loss
    with pytest.raises(ValueError, match="lookahead_target"):
        model_on_dataset(synthetic_dataset(100, 3, 2), **light(lookahead_target="mve"))


# ---------------------------------------------------------------- the look-ahead's weight at the predicted states
@pytest.mark.parametrize("normalization", ["first", "weights"])
def test_lookahead_weight_scales_the_predicted_states_terms(normalization: str):
    """``lookahead_weight`` (lambda): eq. 3's weights become ``1, lambda gamma, lambda gamma^2, ...`` before the
    normalisation; 1 is the paper's ``gamma^i``."""
    data = synthetic_dataset(200, 3, 2, seed=0)
    kwargs = light(lookahead_normalization=normalization)
    paper = model_on_dataset(data, **kwargs, lookahead_weight=1.0)
    assert th.allclose(paper._lookahead_powers, paper._gamma_powers)
    model = model_on_dataset(data, **kwargs, lookahead_weight=0.25)
    model._shift_critic_output(100.0)  # Q > 0, so the divisor mean |Q_0| is the first term's mean
    g = model.gamma
    assert th.allclose(model._lookahead_powers, th.tensor([1.0, 0.25 * g, 0.25 * g * g]))
    obs = th.as_tensor(data.observations[:32])
    th.manual_seed(0)
    loss, stats = model._lookahead_q_loss(obs, model.policy.actor_features(obs))
    per_step = th.stack([stats[f"lookahead_q_{i}"] for i in range(3)])
    weights = th.tensor([1.0, 0.25 * g, 0.25 * g * g])
    if normalization == "weights":
        weights = weights / weights.sum()
    assert loss.item() == pytest.approx((-(weights * per_step).sum() / per_step[0]).item(), rel=1e-5)


def test_default_lookahead_weighs_the_current_state_and_a_sixteenth_at_the_predicted_states():
    """#23, twelfth pass: the default Q weight is ``eta = 3.94`` on the current state (what the paper's ``eta = 1``
    gives all ``T + 1`` states at ``T = 3``) and ``3.94 gamma^i / 16`` at each predicted state; the paper's weights,
    ``gamma^i`` at ``eta = 1``, are ``**PAPER_FORM``'s."""
    data = synthetic_dataset(200, 3, 2, seed=0)
    default = model_on_dataset(data, **light(rollout_length=3))
    g = default.gamma
    assert (float(default.eta), default.lookahead_weight, default.lookahead_normalization) == (3.94, 0.0625, "first")
    actor_weights = float(default.eta) * lookahead_weights(default._lookahead_powers, default.lookahead_normalization)
    assert th.allclose(actor_weights, th.tensor([3.94] + [3.94 * g**i / 16 for i in (1, 2, 3)]))
    assert actor_weights[0] > 15 * actor_weights[1:].max()
    paper = model_on_dataset(data, **light(rollout_length=3, **PAPER_FORM))
    paper_weights = float(paper.eta) * lookahead_weights(paper._lookahead_powers, paper.lookahead_normalization)
    assert th.allclose(paper_weights, th.tensor([g**i for i in range(4)]))
    assert paper_weights.sum().item() == pytest.approx(3.94, abs=1e-3)  # the default's current-state weight


@pytest.mark.parametrize("normalization", ["first", "weights"])
def test_lookahead_weight_weighs_the_value_expansions(normalization: str):
    """With ``lookahead_target="value_expansion"``, ``lookahead_weight`` weighs each ``V_h``, ``h >= 1``, against
    ``V_0``; at 1 the expansions are summed or averaged as before."""
    q = th.randn(4, 4, 8) + 10.0  # [N, T+1, B]
    rewards, alive, powers = th.rand(3, 8), th.ones(4, 8), th.tensor([0.99**i for i in range(4)])
    loss_1, per_step = value_expansion_objective(q, rewards, alive, powers, 2, normalization)
    loss_w, per_step_w = value_expansion_objective(q, rewards, alive, powers, 2, normalization, expansion_weight=0.25)
    assert th.equal(per_step, per_step_w)
    scale = pessimistic_q(q, 2)[0].abs().mean()
    weights = th.tensor([1.0, 0.25, 0.25, 0.25])
    if normalization == "weights":
        weights, plain = weights / weights.sum(), per_step.mean()
    else:
        plain = per_step.sum()
    assert loss_1.item() == pytest.approx((-plain / scale).item(), rel=1e-5)
    assert loss_w.item() == pytest.approx((-(weights * per_step).sum() / scale).item(), rel=1e-5)
    data = synthetic_dataset(200, 3, 2, seed=0)
    model = model_on_dataset(data, **light(lookahead_target="value_expansion", lookahead_weight=0.5))
    assert model.lookahead_weight == 0.5  # accepted: the default 1/16 must not refuse value expansion


# ---------------------------------------------------------------- the critic's TD loss at model rollouts
def _stub_model(model, reward: float, terminal_at: int | None = None) -> None:
    """The dynamics model replaced by ``s' = s + 1``, reward ``reward``, termination on step ``terminal_at``."""
    calls = {"n": 0}

    def step(s, a):
        terminal = th.full((len(s),), float(calls["n"] % model.rollout_length == terminal_at))
        calls["n"] += 1
        return s + 1.0, th.full((len(s),), reward), terminal, th.zeros(len(s))

    model._termination_fn = None
    model.policy.dynamics.step = step  # type: ignore[method-assign,union-attr]


def test_model_rollout_loss_fits_the_rollouts_bellman_target():
    """``model_td_weight``: the critic's loss gains the TD loss of ``T``-step model rollouts of the EMA actor from
    the batch's next states: ``r + gamma (1 - done) min_j Q'_j(s', a')`` at each step, rows after an end left out,
    and no rows from a terminal next state."""
    data = synthetic_dataset(200, 3, 2, seed=0)
    model = model_on_dataset(data, **light(model_td_weight=0.5, reward_scale=2.0))
    assert model_on_dataset(data, **light()).model_td_weight == 0.0  # the default: off
    _stub_model(model, reward=0.25, terminal_at=0)  # the first model step ends the rollout
    next_obs = th.as_tensor(data.next_observations[:16])
    next_actions = th.rand(16, 2) * 2 - 1
    dones = th.zeros(16)
    dones[:4] = 1.0
    model.critic_target.q_values = lambda x: th.full((model.n_critics, x.shape[-2]), 3.0)  # type: ignore[method-assign]
    data_q = th.zeros(model.n_critics, 16)  # Q at the data's (s, a): only COMBO's term reads it
    loss, stats = model._model_rollout_loss(next_obs, next_actions, dones, data_q)
    # T = 2 rows per state: step 0 from (s, a) ends (target 2 * 0.25, no bootstrap); step 1 is never reached
    with th.no_grad():
        q = model.critic(next_obs[4:], next_actions[4:])  # [N, 12]
    want = 0.5 * (q - 0.5).pow(2).mean(dim=1).sum()
    assert loss.item() == pytest.approx(want.item(), rel=1e-5)
    assert stats["model_q_mean"].item() == pytest.approx(q.mean().item(), rel=1e-5)
    _stub_model(model, reward=0.25, terminal_at=None)  # no ends: every row bootstraps gamma * 3
    th.manual_seed(0)
    loss, _ = model._model_rollout_loss(next_obs, next_actions, th.zeros(16), data_q)
    th.manual_seed(0)  # the second step's actions: the EMA actor's at s + 1, the first draw of the rollout
    with th.no_grad():
        second = model._sample_target(model.policy.actor_features(next_obs + 1.0))
        q = model.critic(th.cat([next_obs, next_obs + 1.0]), th.cat([next_actions, second]))  # [N, 32]
    want = 0.5 * (q - (0.5 + model.gamma * 3.0)).pow(2).mean(dim=1).sum()
    assert loss.item() == pytest.approx(want.item(), rel=1e-5)
    # COMBO's term: beta times, per member, the mean Q over the rollouts' rows minus the mean Q at the data
    model.model_td_weight, model.model_conservatism = 0.0, 2.0
    data_q = th.randn(model.n_critics, 16)
    th.manual_seed(0)
    loss, stats = model._model_rollout_loss(next_obs, next_actions, th.zeros(16), data_q)
    want = 2.0 * (q.mean(dim=1) - data_q.mean(dim=1)).sum()
    assert loss.item() == pytest.approx(want.item(), rel=1e-5)
    assert stats["model_q_gap"].item() == pytest.approx((q.mean(dim=1) - data_q.mean(dim=1)).mean().item(), rel=1e-5)
    model.model_td_weight, model.model_conservatism = 0.5, 0.0
    # the data's critic loss gains it, times the weight
    batch = model._setup_offline_data().sample(16)
    th.manual_seed(1)
    with_term, stats = model._critic_loss(
        batch.observations, batch.actions, batch.next_observations, batch.rewards.flatten(), batch.dones.flatten()
    )
    assert "model_q_mean" in stats
    model.model_td_weight = 0.0
    th.manual_seed(1)
    without, stats = model._critic_loss(
        batch.observations, batch.actions, batch.next_observations, batch.rewards.flatten(), batch.dones.flatten()
    )
    assert "model_q_mean" not in stats and with_term.item() > without.item()


def test_model_rollout_losses_move_q_at_model_states():
    """Trained with the rollouts' TD loss, the critic's Q at the EMA actor's actions follows the model's reward (a
    terminal reward of 40, far above the data's value); trained on the data alone it does not. COMBO's term lowers
    Q at the rollouts' off-data states (``s + 1``) below its value without it."""
    data = synthetic_dataset(300, 3, 2, seed=0)

    def q_after(weight: float, conservatism: float = 0.0, shift: float = 0.0) -> float:
        kwargs = light(model_td_weight=weight, model_conservatism=conservatism, rollout_length=1 + (shift > 0), eta=0.0)
        model = model_on_dataset(data, **kwargs)
        _stub_model(model, reward=40.0, terminal_at=0 if weight else None)
        model.train(gradient_steps=300, batch_size=32)
        obs = th.as_tensor(data.next_observations[:64]) + shift
        with th.no_grad():
            return model.critic(obs, model._sample_target(model.policy.actor_features(obs))).mean().item()

    td_only = q_after(1.0)
    assert td_only > q_after(0.0) + 5.0
    assert q_after(0.0, conservatism=1.0, shift=1.0) < q_after(0.0, shift=1.0) - 1.0


# ---------------------------------------------------------------- the Q-to-BC gradient ratio
def test_gradient_ratio_is_logged_and_leaves_training_unchanged(monkeypatch):
    data = synthetic_dataset(400, 3, 2, seed=0)

    def train(freq: int) -> tuple[dict[str, th.Tensor], dict[str, float]]:
        monkeypatch.setattr(pola_module, "GRADIENT_RATIO_FREQ", freq)
        model = model_on_dataset(data, **light(rollout_length=1))
        model.train(gradient_steps=6, batch_size=32)
        values = dict(model.logger.name_to_value)
        return {k: v.clone() for k, v in model.policy.state_dict().items()}, values

    with_ratio, logged = train(2)
    without, logged_none = train(1000)
    assert logged["train/q_bc_grad_ratio"] > 0
    assert "train/q_bc_grad_ratio" not in logged_none
    for key in with_ratio:
        assert th.equal(with_ratio[key], without[key]), key


def test_gradient_ratio_scales_with_eta():
    data = synthetic_dataset(400, 3, 2, seed=0)
    model = model_on_dataset(data, **light(rollout_length=0))
    batch = model._setup_offline_data().sample(64)
    ratios = []
    for eta in (1.0, 3.0):
        model._eta_value.fill_(eta)
        with th.random.fork_rng():
            th.manual_seed(0)
            ratios.append(model.q_bc_gradient_ratio(batch.observations, batch.actions))
    assert ratios[1] == pytest.approx(3.0 * ratios[0], rel=1e-4)


# ---------------------------------------------------------------- advantage-weighted imitation (bc_weight_temp)
def test_advantage_weights_are_scale_free_mean_one_and_clipped():
    adv = th.tensor([0.0, 1.0, 2.0, 3.0])
    assert th.equal(advantage_weights(adv, 0.0, 20.0), th.ones(4))  # temperature 0: plain imitation
    w = advantage_weights(adv, 1.0, 20.0)
    assert w.mean().item() == pytest.approx(1.0)
    assert (w.diff() > 0).all()  # the better the data's action, the more it is imitated
    # exp(beta A / std(A)), normalised: the rewards' scale and a constant baseline do not matter
    expected = th.exp(adv / adv.std())
    assert th.allclose(w, expected / expected.mean())
    assert th.allclose(advantage_weights(100.0 * adv - 7.0, 1.0, 20.0), w)
    clipped = advantage_weights(adv, 5.0, 1.5)
    assert clipped.max().item() == pytest.approx(1.5)
    assert th.allclose(clipped[:2], advantage_weights(adv, 5.0, 20.0)[:2])


def _mixture_data() -> object:
    """One-dimensional actions, half the rows at +0.5 and half at -0.5 under every state."""
    data = synthetic_dataset(512, 3, 1, seed=0)
    data.actions[:] = np.where(np.arange(512)[:, None] % 2 == 0, 0.5, -0.5).astype(np.float32)
    return data


@pytest.mark.parametrize("temp", [None, 2.0])
def test_bc_weight_temp_imitates_the_better_mode_of_a_mixture(temp):
    """A critic that prefers +0.5: the plain L_d imitates both modes (mean action 0), the weighted one the better."""
    model = model_on_dataset(_mixture_data(), **light(rollout_length=0, eta=0.0, bc_weight_temp=temp))
    model.critic = lambda obs, actions: -(actions - 0.5).pow(2).sum(dim=-1).expand(3, -1)  # [N, B]
    buffer = model._setup_offline_data()
    optimizer = model.actor.optimizer
    model._bc_temp_value.fill_(temp or 0.0)
    for _ in range(300):
        batch = buffer.sample(64)
        optimizer.zero_grad()
        loss, stats = model._bc_loss(batch.observations, batch.actions, model._bc_temp_value)
        loss.backward()
        optimizer.step()
    with th.no_grad():
        actions = model.actor.sample(model.policy.actor_features(th.randn(400, 3)))
    if temp is None:
        assert "imitation_ess" not in stats
        assert abs(actions.mean().item()) < 0.15
    else:
        assert 0.0 < stats["imitation_ess"].item() < 0.8
        assert actions.mean().item() > 0.3


def test_bc_weight_temp_is_checked_and_logged():
    with pytest.raises(ValueError, match="bc_weight_temp"):
        model_on_dataset(synthetic_dataset(100, 3, 2), **light(bc_weight_temp=-1.0))
    with pytest.raises(ValueError, match="bc_max_weight"):
        model_on_dataset(synthetic_dataset(100, 3, 2), **light(bc_weight_temp=1.0, bc_max_weight=0.0))
    # q_term_confidence off: on an untrained critic its gate passes no state, and the ratio below would be 0
    kwargs = light(rollout_length=1, bc_weight_temp=1.0, q_term_confidence=None)
    model = model_on_dataset(synthetic_dataset(400, 3, 2), **kwargs)
    model.train(gradient_steps=4, batch_size=32)
    model._record_train_stats()
    logged = model.logger.name_to_value
    assert 0.0 < logged["train/imitation_ess"] < 1.0
    assert logged["train/imitation_weight_max"] <= 20.0
    batch = model._setup_offline_data().sample(32)  # the diagnostic measures the weighted L_d as trained
    assert model.q_bc_gradient_ratio(batch.observations, batch.actions) > 0


# ---------------------------------------------------------------- the deterministic rule of predict
def test_deterministic_predict_picks_the_best_candidate_by_the_pessimistic_critic():
    data = synthetic_dataset(300, 3, 2, seed=0)
    model = model_on_dataset(data, **light(rollout_length=0, policy_kwargs=dict(net_arch=[32, 32], n_action_samples=6)))
    model.train(gradient_steps=20, batch_size=32)
    policy = model.policy
    obs = th.randn(5, 3)
    action = policy._predict(obs, deterministic=True)
    # candidates by hand: candidate 0 is the noise-free chain, the rest from predict_seed's noise
    noise = policy.candidate_noise(policy.actor_ema)
    assert th.equal(noise[:, 0], th.zeros_like(noise[:, 0]))
    for row in range(5):
        feats = policy.actor_features(obs[row : row + 1].expand(6, -1))
        candidates = sample_no_grad(policy.actor_ema, feats, noise=noise)
        q = policy.critic_target(obs[row : row + 1].expand(6, -1), candidates).min(dim=0).values
        assert th.allclose(action[row], candidates[q.argmax()], atol=1e-6)
        noise_free = sample_no_grad(policy.actor_ema, feats[:1], deterministic=True)
        assert th.allclose(candidates[0], noise_free[0], atol=1e-6)
    # each row's action does not depend on the batch it came in
    singles = th.cat([policy._predict(obs[i : i + 1], deterministic=True) for i in range(5)])
    assert th.allclose(singles, action, atol=1e-6)
    assert th.equal(policy._predict(obs, deterministic=True), action)


def test_best_candidate_leaves_the_mean_of_a_symmetric_mixture():
    # actions +-0.8 at every state (a symmetric mixture): the noise-free chain returns about their mean (0);
    # the best of several candidates under a critic that prefers +0.8 lands on that mode
    th.manual_seed(0)
    n = 2000
    obs = np.random.default_rng(0).normal(size=(n, 3)).astype(np.float32)
    sign = np.where(np.arange(n) % 2 == 0, 1.0, -1.0).astype(np.float32)
    data = synthetic_dataset(n, 3, 1, seed=0)
    data.observations[:] = obs
    data.actions[:] = 0.8 * sign[:, None]
    data.rewards[:] = 0.0
    model = model_on_dataset(
        data,
        **light(
            rollout_length=0,
            eta=0.0,
            policy_kwargs=dict(net_arch=[64, 64], n_action_samples=8, predict_actor="online"),
            prediction_type="sample",
            bc_top_fraction=None,  # the mixture at every state: all episodes (a tenth of them, it memorises each sign)
        ),
    )
    model.learning_rate = 1e-3
    model._setup_lr_schedule()
    model.train(gradient_steps=1500, batch_size=128)
    policy = model.policy
    test_obs = th.as_tensor(obs[:200])
    noise_free = sample_no_grad(policy.actor, policy.actor_features(test_obs), deterministic=True)
    assert float(noise_free.abs().mean()) < 0.4
    # a critic that prefers positive actions: Q = a for every member
    policy.critic_target.forward = lambda o, a: a[:, 0].unsqueeze(0).expand(3, -1)  # type: ignore[method-assign]
    chosen = policy._predict(test_obs, deterministic=True)
    assert float(chosen.mean()) > 0.6


# ---------------------------------------------------------------- cosine learning-rate decay
def test_cosine_schedule_values_and_use_as_learning_rate():
    from sb3_pola.common.schedules import CosineSchedule, cosine_schedule

    schedule = cosine_schedule(1e-3, 1e-4)
    # progress_remaining 1 -> 0 over learn
    assert [schedule(p) for p in (1.0, 0.5, 0.0)] == pytest.approx([1e-3, 5.5e-4, 1e-4])
    assert schedule(0.75) == pytest.approx(1e-4 + 9e-4 * 0.5 * (1 + np.cos(np.pi / 4)))
    with pytest.raises(ValueError, match=">= 0"):
        CosineSchedule(-1.0)
    # held for the first 80%, then the same cosine over the last 20%
    late = cosine_schedule(1e-3, 0.0, start=0.8)
    assert [late(p) for p in (1.0, 0.5, 0.2, 0.1, 0.0)] == pytest.approx([1e-3, 1e-3, 1e-3, 5e-4, 0.0])
    with pytest.raises(ValueError, match="start"):
        CosineSchedule(1e-3, 0.0, start=1.0)
    model = model_on_dataset(synthetic_dataset(200, 3, 2), **light(rollout_length=0, learning_rate=cosine_schedule(1e-3)))
    model._current_progress_remaining = 0.5
    model.train(gradient_steps=1, batch_size=16)
    assert model.actor.optimizer.param_groups[0]["lr"] == pytest.approx(5e-4)
    assert model.critic.optimizer.param_groups[0]["lr"] == pytest.approx(5e-4)


def test_critic_learning_rate_is_the_critics_own_and_survives_save(tmp_path):
    """#23: ``critic_learning_rate`` sets the critics' rate apart from ``learning_rate`` (the actor's); unset, both
    follow ``learning_rate`` as in SB3."""
    from sb3_pola.common.schedules import cosine_schedule

    data = synthetic_dataset(200, 3, 2)
    model = model_on_dataset(data, **light(rollout_length=0, learning_rate=cosine_schedule(1e-3), critic_learning_rate=5e-4))
    model._current_progress_remaining = 0.5
    model.train(1, batch_size=32)
    actor_lr = model.actor.optimizer.param_groups[0]["lr"]
    assert actor_lr == pytest.approx(cosine_schedule(1e-3)(0.5))
    assert all(group["lr"] == 5e-4 for group in model.critic.optimizer.param_groups)
    model.save(tmp_path / "m.zip")
    loaded = type(model).load(tmp_path / "m.zip", dataset=data)
    assert loaded.critic_learning_rate == 5e-4 and loaded.critic_lr_schedule(0.0) == 5e-4
    same = model_on_dataset(data, **light(rollout_length=0, learning_rate=2e-4))
    same.train(1, batch_size=32)
    assert same.critic_lr_schedule is None and same.critic.optimizer.param_groups[0]["lr"] == 2e-4
    with pytest.raises(ValueError, match="critic_learning_rate"):
        model_on_dataset(data, **light(critic_learning_rate=0.0))


def test_bc_learning_rate_moves_the_imitation_term_at_its_own_rate(tmp_path):
    """#23: ``bc_learning_rate`` is L_d's rate in the actor's Adam: with eta = 0 the actor's rate; equal to
    ``learning_rate``, the one-rate step to the bit; else a step of its own (sb3_pola.common.term_rates)."""
    from sb3_pola.common.schedules import cosine_schedule
    from sb3_pola.common.term_rates import TERM_MOMENT

    data = synthetic_dataset(200, 3, 2)

    def actor_after(n_steps: int = 4, **kwargs) -> list[th.Tensor]:
        model = model_on_dataset(data, **light(**kwargs))
        model._current_progress_remaining = 0.5
        model.train(n_steps, batch_size=32)
        return [p.detach().clone() for p in model.actor.parameters()]

    def same(a: list[th.Tensor], b: list[th.Tensor]) -> bool:
        return all(th.equal(x, y) for x, y in zip(a, b, strict=True))

    # behaviour cloning: the BC rate is the actor's rate (the critic's rate held apart, so the draws match)
    bc = {"eta": 0.0, "rollout_length": 0, "critic_learning_rate": 1e-3}
    split = actor_after(bc_learning_rate=cosine_schedule(1e-3), learning_rate=1e-3, **bc)
    for got, want in zip(split, actor_after(learning_rate=cosine_schedule(1e-3), **bc), strict=True):
        th.testing.assert_close(got, want)
    assert not same(split, actor_after(learning_rate=1e-3, **bc))
    # with the Q term: equal rates are the one-rate step; a decayed BC rate moves the actor elsewhere
    one_rate = actor_after(learning_rate=1e-3)
    assert same(actor_after(learning_rate=1e-3, bc_learning_rate=1e-3), one_rate)
    decayed = actor_after(learning_rate=1e-3, bc_learning_rate=cosine_schedule(1e-3))
    assert not same(decayed, one_rate)
    assert not same(decayed, actor_after(learning_rate=cosine_schedule(1e-3), critic_learning_rate=1e-3))
    # the rate and the term's moment survive save and load
    model = model_on_dataset(data, **light(bc_learning_rate=cosine_schedule(1e-3)))
    model.train(2, batch_size=32)
    assert model._bc_lr == pytest.approx(1e-3)
    model.save(tmp_path / "m.zip")
    loaded = type(model).load(tmp_path / "m.zip", dataset=data)
    assert loaded.bc_lr_schedule is not None and loaded.bc_lr_schedule(0.5) == pytest.approx(5e-4)
    assert all(TERM_MOMENT in state for state in loaded.actor.optimizer.state.values())
    with pytest.raises(ValueError, match="bc_learning_rate"):
        model_on_dataset(data, **light(bc_learning_rate=0.0))
    with pytest.raises(ValueError, match="Adam"):
        model_on_dataset(data, **light(bc_learning_rate=1e-4, policy_kwargs={"optimizer_class": th.optim.SGD}))


# ---------------------------------------------------------------- the dynamics fit
def test_default_dynamics_fit_beats_the_plain_nll_on_the_shipped_data():
    from sb3_pola.common.datasets import load_offline_dataset
    from sb3_pola.common.dynamics import EnsembleDynamics
    from sb3_pola.common.dynamics_trainer import DynamicsTrainer

    data = load_offline_dataset("invertedpendulum/medium-v0", use_cache=False)
    errors = {}
    for mean_loss in (None, "nll"):
        th.manual_seed(0)
        kwargs = {} if mean_loss is None else {"mean_loss": mean_loss}
        model = EnsembleDynamics(4, 1, n_members=2, n_elites=1, hidden_dim=32, n_layers=2, **kwargs)
        info = DynamicsTrainer(model, max_steps=600, max_epoch_steps=100, patience=100).fit(
            data.observations, data.actions, data.next_observations, data.rewards, data.dones
        )
        errors[mean_loss] = info["holdout_mse"]
    assert errors[None] < 0.75 * errors["nll"], errors


# ---------------------------------------------------------------- observation-seeded noise
def test_observation_noise_is_standard_normal_per_observation_and_batch_free():
    from sb3_pola.pola.policies import observation_noise

    obs = th.randn(20000, 5, generator=th.Generator().manual_seed(0))
    noise = observation_noise(obs, 4, 2)  # [5, B, 2]
    assert noise.shape == (5, 20000, 2)
    assert abs(float(noise.mean())) < 0.02 and abs(float(noise.std()) - 1.0) < 0.02
    assert float((noise.abs() > 1.96).float().mean()) == pytest.approx(0.05, abs=0.005)
    # the draws of different (step, action) slots are uncorrelated
    corr = th.corrcoef(noise.reshape(10, -1))
    assert float((corr - th.eye(10)).abs().max()) < 0.05
    assert th.equal(observation_noise(obs[3:9], 4, 2), noise[:, 3:9])  # each row its own, whatever the batch
    assert not th.equal(observation_noise(obs[:4], 4, 2, seed=1), noise[:, :4])


def test_deterministic_predict_draws_the_observations_noise():
    from sb3_pola.pola.policies import observation_noise

    data = synthetic_dataset(300, 3, 2, seed=0)
    model = model_on_dataset(
        data, **light(rollout_length=0, policy_kwargs=dict(net_arch=[32, 32], deterministic_rule="observation_noise"))
    )
    model.train(gradient_steps=5, batch_size=32)
    policy = model.policy
    obs = th.randn(6, 3)
    action = policy._predict(obs, deterministic=True)
    feats = policy.actor_features(obs)
    noise = observation_noise(obs, policy.actor_ema.n_diffusion_steps, 2, policy.predict_seed)
    expected = sample_no_grad(policy.actor_ema, feats, noise=noise)
    assert th.allclose(action, expected, atol=1e-6)
    singles = th.cat([policy._predict(obs[i : i + 1], deterministic=True) for i in range(6)])
    assert th.allclose(singles, action, atol=1e-5)
    # the cached projection follows predict_seed
    policy.predict_seed = 1
    reseeded = sample_no_grad(policy.actor_ema, feats, noise=observation_noise(obs, policy.actor_ema.n_diffusion_steps, 2, 1))
    assert th.allclose(policy._predict(obs, deterministic=True), reseeded, atol=1e-6)
    assert not th.allclose(reseeded, action)
    policy.deterministic_rule = "noise_free"
    assert th.allclose(policy._predict(obs, deterministic=True), sample_no_grad(policy.actor_ema, feats, deterministic=True))
    with pytest.raises(ValueError, match="deterministic_rule"):
        model_on_dataset(data, **light(rollout_length=0, policy_kwargs=dict(net_arch=[32, 32], deterministic_rule="medoid")))


def test_kernel_mode_averages_one_mode_and_picks_one_of_two():
    from sb3_pola.pola.actor import kernel_mode

    g = th.Generator().manual_seed(0)
    unimodal = 0.3 + 0.15 * th.randn(500, 16, 3, generator=g)  # [B, K, A]
    mode = kernel_mode(unimodal, bandwidth=0.2)
    # nearer the centre than one sample, about as near as the samples' mean
    assert (mode - 0.3).abs().mean() < 0.4 * (unimodal[:, 0] - 0.3).abs().mean()
    sign = th.where(th.rand(500, 16, 1, generator=g) < 0.5, -1.0, 1.0)
    mixture = 0.6 * sign + 0.1 * th.randn(500, 16, 3, generator=g)
    mode = kernel_mode(mixture, bandwidth=0.2)
    assert ((mode.abs() - 0.6).abs().mean(dim=-1) < 0.1).all()  # in a mode, every row
    assert mixture.mean(dim=1).abs().mean() < 0.3  # where the mean would stand


def test_mode_rule_is_the_kernel_mode_of_the_observations_samples():
    from sb3_pola.pola.actor import kernel_mode, observation_noise

    data = synthetic_dataset(300, 3, 2, seed=0)
    policy_kwargs = dict(net_arch=[32, 32], deterministic_rule="mode", mode_samples=8)
    model = model_on_dataset(data, **light(rollout_length=0, policy_kwargs=policy_kwargs))
    model.train(gradient_steps=5, batch_size=32)
    policy = model.policy
    obs = th.randn(5, 3)
    action = policy._predict(obs, deterministic=True)
    steps = policy.actor_ema.n_diffusion_steps
    noise = observation_noise(obs, steps, 2 * 8, policy.predict_seed).reshape(steps + 1, 5 * 8, 2)
    samples = sample_no_grad(policy.actor_ema, policy.actor_features(obs).repeat_interleave(8, dim=0), noise=noise)
    assert th.allclose(action, kernel_mode(samples.view(5, 8, 2), policy.mode_bandwidth), atol=1e-6)
    singles = th.cat([policy._predict(obs[i : i + 1], deterministic=True) for i in range(5)])
    assert th.allclose(singles, action, atol=1e-5)  # each observation its own, whatever the batch
    assert policy._get_constructor_parameters()["mode_samples"] == 8


@pytest.mark.parametrize("rule", ["observation_noise", "noise_free", "mode"])
def test_exported_graph_follows_the_deterministic_rule(rule, tmp_path):
    data = synthetic_dataset(300, 3, 2, seed=0)
    model = model_on_dataset(data, **light(rollout_length=0, policy_kwargs=dict(net_arch=[32, 32], deterministic_rule=rule)))
    model.train(gradient_steps=5, batch_size=32)
    path = model.export_policy(tmp_path / "policy.pt", format="torchscript")
    graph = th.jit.load(str(path))
    obs = np.random.default_rng(1).normal(size=(9, 3)).astype(np.float32)
    actions, _ = model.predict(obs, deterministic=True)
    assert np.allclose(graph(th.as_tensor(obs)).numpy(), actions, atol=1e-5)


# ---------------------------------------------------------------- the Q term gated by the critic's maturity
def _gate(model, q_mean):
    span = model.data_value - model.data_value_floor
    return float(((q_mean - model.data_value_floor) / (model.eta_gate_fraction * span)).clamp(0.0, 1.0))


def test_critic_maturity_gate_is_the_default_and_off_in_the_paper_form():
    data = synthetic_dataset(200, 3, 2, seed=0)
    model = model_on_dataset(data, **light(rollout_length=0))
    assert (model.eta_gate, model.eta_gate_fraction) == ("critic_maturity", 0.1)
    assert PAPER_FORM["eta_gate"] is None


def test_critic_maturity_gate_scales_eta_from_the_data_floor_to_a_fraction_of_the_data_value():
    data = synthetic_dataset(400, 3, 2, seed=0)
    model = model_on_dataset(data, **light(rollout_length=1, eta_gate="critic_maturity", eta_gate_fraction=1.0))
    model._before_training()
    returns = data.returns_to_go(model.gamma)
    assert model.data_value == pytest.approx(float(returns.mean()))
    assert model.data_value_floor == pytest.approx(float(returns.min()))
    # a floor at Q's level and a value far above it: the gate is strictly inside (0, 1)
    q0 = float(model._update(model._setup_offline_data().sample(32))["q_mean"])
    model.data_value_floor, model.data_value = q0 - 1.0, q0 + 1e3
    stats = model._update(model._setup_offline_data().sample(32))
    expected = _gate(model, stats["q_mean"])
    assert 0.0 < expected < 0.1
    assert float(stats["critic_maturity"]) == pytest.approx(expected, rel=1e-5)
    assert float(stats["eta"]) == pytest.approx(expected * float(model.eta), rel=1e-5)
    # the fraction: the same distance covered opens the gate tenfold at f = 0.1
    model.eta_gate_fraction = 0.1
    stats = model._update(model._setup_offline_data().sample(32))
    assert float(stats["critic_maturity"]) == pytest.approx(_gate(model, stats["q_mean"]), rel=1e-5)
    assert float(stats["critic_maturity"]) > 5 * expected
    # a critic below the data's floor (a sparse task's pessimism bias): the Q term is closed, the actor imitates
    model.data_value_floor, model.data_value = q0 + 1e3, q0 + 2e3
    stats = model._update(model._setup_offline_data().sample(32))
    assert float(stats["eta"]) == pytest.approx(0.0, abs=1e-6)
    assert float(stats["actor_loss"]) == pytest.approx(float(stats["bc_loss"]), rel=1e-5)
    for bad in (0.0, -1.0):
        with pytest.raises(ValueError, match="eta_gate_fraction"):
            model_on_dataset(data, **light(eta_gate="critic_maturity", eta_gate_fraction=bad))
    with pytest.raises(ValueError, match="eta_gate"):
        model_on_dataset(data, **light(eta_gate="maturity"))


def test_critic_maturity_gate_stays_open_without_a_value_span():
    data = synthetic_dataset(200, 3, 2, seed=0)
    data.rewards[:] = 0.0  # every return-to-go is 0: nothing to measure the critic against
    model = model_on_dataset(data, **light(rollout_length=0))
    model._before_training()
    stats = model._update(model._setup_offline_data().sample(32))
    assert "critic_maturity" not in stats
    assert float(stats["eta"]) == pytest.approx(float(model.eta))


def test_value_lower_bound_is_the_lowest_value_of_any_policy():
    assert value_lower_bound(th.tensor([0.0, 1.0, 0.0]), 0.99) == 0.0  # sparse: no policy's value is below 0
    assert value_lower_bound(th.tensor([0.5, 2.0]), 0.99) == 0.5  # an episode may end after one reward
    assert value_lower_bound(th.tensor([-1.0, 3.0]), 0.99) == pytest.approx(-100.0)  # it may also never end
    assert value_lower_bound(th.tensor([-1.0, 3.0]), 1.0) == float("-inf")


def test_target_q_floor_bounds_the_bootstrapped_minimum_and_is_off_in_the_papers_form():
    data = synthetic_dataset(200, 3, 2, seed=0)
    data.rewards[:] = 0.0
    data.rewards[::50] = 1.0  # sparse: r_min = 0
    model = model_on_dataset(data, **light(rollout_length=0, target_q_floor=None))
    assert PAPER_FORM["target_q_floor"] is None
    model._before_training()
    assert model.target_q_floor_value is None
    floored = model_on_dataset(data, **light(rollout_length=0, target_q_floor="auto"))
    floored._before_training()
    assert floored.target_q_floor_value == 0.0
    # target critics far below the floor: the floored target is the reward alone (plus gamma * 0)
    for m in (model, floored):
        with th.no_grad():
            m.critic_target.q_net[-1].weight.zero_()
            m.critic_target.q_net[-1].bias.fill_(-50.0)
    batch = floored._setup_offline_data().sample(64)
    args = (batch.observations, batch.actions, batch.next_observations, batch.rewards.flatten(), batch.dones.flatten())
    _, stats = floored._critic_loss(*args)
    assert float(stats["target_q"]) == pytest.approx(float(batch.rewards.mean()), abs=1e-5)
    _, stats = model._critic_loss(*args)
    assert float(stats["target_q"]) < -10.0
    with pytest.raises(ValueError, match="target_q_floor"):
        model_on_dataset(data, **light(target_q_floor="lowest"))


def test_target_q_floor_returns_floors_the_target_at_the_datas_return_to_go():
    data = synthetic_dataset(300, 3, 2, seed=1)
    model = model_on_dataset(data, **light(rollout_length=0, target_q_floor="returns"))
    model._before_training()
    returns = data.returns_to_go(model.gamma)
    np.testing.assert_allclose(model._data_returns.cpu().numpy(), returns, rtol=1e-5, atol=1e-5)
    with th.no_grad():  # target critics far below every return: the floor decides every target
        model.critic_target.q_net[-1].weight.zero_()
        model.critic_target.q_net[-1].bias.fill_(-1e3)
    buffer = model._setup_offline_data()
    indices = buffer.sample_indices(64)
    batch = buffer._get_samples(indices)
    args = (batch.observations, batch.actions, batch.next_observations, batch.rewards.flatten(), batch.dones.flatten())
    _, stats = model._critic_loss(*args, model._data_returns[indices])
    assert float(stats["target_q"]) == pytest.approx(float(returns[indices.cpu().numpy()].mean()), rel=1e-5)
    _, stats = model._critic_loss(*args)  # without the returns: the plain pessimistic target
    assert float(stats["target_q"]) < -100.0
    # train() hands each batch its own returns: one step with the floor differs from one without
    calls = []
    original = model._critic_loss_fn
    model._critic_loss_fn = lambda *a: calls.append(a[5]) or original(*a)  # (obs, actions, s', r, dones, returns, ...)
    model.train(1, batch_size=16)
    assert calls[0] is not None and calls[0].shape == (16,)


def test_reward_scale_puts_the_critic_its_targets_and_floors_in_scaled_units():
    data = synthetic_dataset(300, 3, 2, seed=2)
    gamma = 0.99
    plain = model_on_dataset(data, **light(rollout_length=0, target_q_floor="returns", q_scale_floor="auto"))
    scaled = model_on_dataset(
        data, **light(rollout_length=0, target_q_floor="returns", q_scale_floor="auto", reward_scale=0.1)
    )
    assert plain.reward_scale == 1.0
    for m in (plain, scaled):
        m._before_training()
    returns = data.returns_to_go(gamma)
    np.testing.assert_allclose(scaled._data_returns.cpu().numpy(), 0.1 * returns, rtol=1e-5, atol=1e-6)
    assert scaled.data_value == pytest.approx(0.1 * plain.data_value, rel=1e-5)
    assert scaled.data_value_floor == pytest.approx(0.1 * plain.data_value_floor, rel=1e-5)
    assert scaled.q_scale_floor_value == pytest.approx(0.1 * plain.q_scale_floor_value, rel=1e-5)
    # the critic sees the scaled rewards; the dynamics model's data are left as they are
    seen = []
    original = scaled._critic_loss_fn
    scaled._critic_loss_fn = lambda *a: seen.append(a[3]) or original(*a)
    buffer = scaled._setup_offline_data()
    batch = buffer.sample(16)
    scaled._update(batch)
    np.testing.assert_allclose(seen[0].cpu().numpy(), 0.1 * batch.rewards.flatten().cpu().numpy(), rtol=1e-6)
    np.testing.assert_allclose(buffer.rewards.flatten().cpu().numpy(), data.rewards, rtol=1e-6)
    for bad in (0.0, -1.0):
        with pytest.raises(ValueError, match="reward_scale"):
            model_on_dataset(data, **light(reward_scale=bad))


def test_critic_init_value_starts_q_at_the_data_mean_return_once():
    data = synthetic_dataset(300, 3, 2, seed=3)
    data.rewards += 10.0  # a value scale well away from the layer's own init
    model = model_on_dataset(data, **light(rollout_length=0, critic_init_value="returns", reward_scale=0.5))
    critic, target = model.policy.critic, model.policy.critic_target
    before = critic.output_layer.bias.detach().clone()  # [N, 1, 1]
    model._before_training()
    mean_return = 0.5 * float(data.returns_to_go(model.gamma).mean())  # in the critic's units
    assert abs(mean_return) > 1.0  # the shift is visible against the layer's own init
    np.testing.assert_allclose(critic.output_layer.bias.detach(), before + mean_return, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(target.output_layer.bias.detach(), critic.output_layer.bias.detach(), rtol=1e-6)
    # Q at the data starts near the data's value, not near 0
    buffer = model._setup_offline_data()
    batch = buffer.sample(64)
    with th.no_grad():
        q = critic(batch.observations, batch.actions)  # [N, B]
    assert abs(float(q.mean()) - mean_return) < 0.1 * abs(mean_return)
    # once: a later learn (or a resumed model) keeps the trained critics
    model._n_updates = 5
    model._critic_init_done = False
    model._before_training()
    np.testing.assert_allclose(critic.output_layer.bias.detach(), before + mean_return, rtol=1e-5, atol=1e-5)
    # a float shifts by that value; None leaves the layer's init
    fixed = model_on_dataset(data, **light(rollout_length=0, critic_init_value=7.0))
    plain = model_on_dataset(data, **light(rollout_length=0, critic_init_value=None))
    assert PAPER_FORM["critic_init_value"] is None
    before_fixed = fixed.policy.critic.output_layer.bias.detach().clone()
    before_plain = plain.policy.critic.output_layer.bias.detach().clone()
    fixed._before_training()
    plain._before_training()
    np.testing.assert_allclose(fixed.policy.critic.output_layer.bias.detach(), before_fixed + 7.0, rtol=1e-6)
    np.testing.assert_allclose(plain.policy.critic.output_layer.bias.detach(), before_plain)
    with pytest.raises(ValueError, match="critic_init_value"):
        model_on_dataset(data, **light(critic_init_value="mean"))


def test_the_defaults_floor_the_target_at_the_returns_and_start_the_critics_at_the_datas_value():
    """#23's seventh pass: both "returns" options are the package defaults (the main job needs them), the paper's form
    turns them off."""
    data = synthetic_dataset(200, 3, 2, seed=4)
    model = model_on_dataset(data, **light(rollout_length=0))
    assert model.target_q_floor == "returns" and model.critic_init_value == "returns"
    model._before_training()
    assert model._data_returns is not None and model._critic_init_done
    paper = model_on_dataset(data, **light(rollout_length=0, **PAPER_FORM))
    paper._before_training()
    assert paper._data_returns is None and not paper._critic_init_done
