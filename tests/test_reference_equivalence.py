"""The fast paths give the numbers of the readable ones written from the paper's equations.

The gradient step against a plain reference of eq. 3-6, the fast samplers (:mod:`sb3_pola.pola.fast_sampling`)
against :meth:`DiffusionActor.sample` (eq. 5), the compiled update against the eager one, the fused Mish against
``F.mish``. No timings here (speed is measured by ``sb3-pola bench``).
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import torch as th
from helpers import model_on_dataset
from stable_baselines3.common.utils import polyak_update
from torch.nn import functional as F

from sb3_pola.common import activations
from sb3_pola.common.activations import FusedMish, compiled_mish, mish_exp
from sb3_pola.common.datasets import synthetic_dataset
from sb3_pola.pola import fast_sampling
from sb3_pola.pola.actor import kernel_mode
from sb3_pola.pola.fast_sampling import inference_mish, sample_chain, sample_no_grad
from sb3_pola.pola.policies import observation_noise

RTOL, ATOL = 1e-4, 1e-5


def _model(**kwargs):
    data = synthetic_dataset(2_000, 5, 2, env_id="Hopper-v5" if kwargs.pop("hopper", False) else None)
    if kwargs.get("critic_bc_coef"):  # episodes of 7 rows, each row's next state the next row's state
        goes_on = np.arange(len(data) - 1) % 7 != 6
        data.next_observations[:-1][goes_on] = data.observations[1:][goes_on]
    params = dict(
        n_critics=4,
        top_k=2,
        rollout_length=2,
        batch_size=32,
        max_grad_norm=None,
        ema_update_freq=1,
        ema_start=0,
        policy_kwargs={"net_arch": [32, 32]},
        dynamics_kwargs={"n_members": 3, "n_elites": 2, "hidden_dim": 16, "n_layers": 2},
    )
    params.update(kwargs)
    return model_on_dataset(data, **params)


def ref_q(critic, obs: th.Tensor | None, actions: th.Tensor, detach: bool = False, features=None) -> th.Tensor:
    """``[N, B]`` Q-values, member by member with plain matmuls (no batched ensemble)."""
    x = th.cat((critic.features_extractor(obs) if features is None else features, actions), dim=-1)
    layers = [m for m in critic.q_net if getattr(m, "weight", None) is not None]  # the linear layers
    layer_norm = any(isinstance(m, th.nn.LayerNorm) for m in critic.q_net)  # before each hidden activation
    out = []
    for i in range(critic.n_critics):
        h = x
        for j, layer in enumerate(layers):
            w, b = layer.weight[i], layer.bias[i, 0]
            if detach:
                w, b = w.detach(), b.detach()
            h = h @ w + b
            if j < len(layers) - 1:
                h = F.mish(F.layer_norm(h, h.shape[-1:]) if layer_norm else h)
        out.append(h.squeeze(-1))
    return th.stack(out)


def ref_sample(actor, features: th.Tensor, generator: th.Generator | None = None) -> th.Tensor:
    """DDPM reverse chain (eq. 5) with the concatenated input layer and the schedule's own ``step``."""
    batch, n = features.shape[0], actor.n_diffusion_steps
    noise = th.randn((n + 1, batch, actor.action_dim), generator=generator)
    x = noise[-1]
    for t in reversed(range(n)):
        eps = actor.predict_noise(x, th.full((batch,), t, dtype=th.long), features)
        x = actor.schedule.step(eps, t, x, noise[t])
    return x.clamp(-1.0, 1.0)


def ref_next_data_actions(data, indices: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """The data's next action of each row and 1 where its episode goes on (the next row starts at its next state)."""
    next_actions, goes_on = [], []
    for i in indices.tolist():
        last = i == len(data) - 1 or bool(data.dones[i])
        last = last or not np.array_equal(data.next_observations[i], data.observations[i + 1])
        next_actions.append(data.actions[i if last else i + 1])
        goes_on.append(0.0 if last else 1.0)
    return th.as_tensor(np.stack(next_actions), dtype=th.float32), th.tensor(goes_on)


def ref_confidence(model, critic, obs, first_action, actions):
    """``q_term_confidence``'s mask ``[B]``: a state's terms count where the members agree a_t beats the data's."""
    confidence = model._dense_option("q_term_confidence")  # "auto": as it applies to the data
    if confidence is None:
        return None
    with th.no_grad():
        gain = ref_q(critic, obs, first_action) - ref_q(critic, obs, actions)  # [N, B]
        mean = gain.mean(dim=0)
        std = ((gain - mean).pow(2).sum(dim=0) / (gain.shape[0] - 1)).sqrt()
        confident = (mean > confidence * std).float()
    if model.q_term_confidence != "auto":  # the gate's own cases: states of both kinds in the batch
        assert 0 < float(confident.sum()) < obs.shape[0]
    return confident


def reference_step(model, policy, batch, next_data=None) -> dict[str, object]:
    """One POLA update written plainly from the paper: critic TD step, actor ``L_d + eta L_q``, EMA and targets."""
    obs, actions, next_obs = batch.observations, batch.actions, batch.next_observations
    rewards, dones = batch.rewards.flatten(), batch.dones.flatten()
    actor, critic = policy.actor, policy.critic
    feats = policy.features_extractor
    with th.no_grad():
        next_actions = ref_sample(policy.actor_ema, feats(next_obs))
        next_q = ref_q(policy.critic_target, next_obs, next_actions).min(dim=0).values
        if next_data is not None:  # ReBRAC's critic penalty on a' away from the data's next action
            next_q = next_q - model.critic_bc_coef * next_data[1] * ((next_actions - next_data[0]) ** 2).sum(dim=-1)
        target = rewards + model.gamma * (1.0 - dones) * next_q
    n = critic.n_critics
    # each member its own copy of the state features and the action, for the similarity term's gradients
    member_feats = [critic.features_extractor(obs).detach().requires_grad_(True) for _ in range(n)]
    member_actions = [actions.clone().requires_grad_(True) for _ in range(n)]
    q = th.stack([ref_q(critic, None, member_actions[i], features=member_feats[i])[i] for i in range(n)])
    critic_loss = sum(((q[i] - target) ** 2).mean() for i in range(n))
    if model.critic_diversity > 0:  # EDAC eq. 8: cosine similarity of every pair of members' input gradients
        if model.critic_diversity_inputs == "actions":
            grads = [th.autograd.grad(q[i].sum(), member_actions[i], create_graph=True)[0] for i in range(n)]
        else:
            grads = [
                th.cat(th.autograd.grad(q[i].sum(), (member_feats[i], member_actions[i]), create_graph=True), dim=-1)
                for i in range(n)
            ]
        units = [g / (g.pow(2).sum(dim=-1, keepdim=True) + 1e-12).sqrt() for g in grads]
        pairs = sum((units[i] * units[j]).sum(dim=-1) for i in range(n) for j in range(n) if i != j)
        critic_loss = critic_loss + model.critic_diversity * pairs.mean() / (n - 1)
    critic.optimizer.zero_grad()
    critic_loss.backward()
    critic_grads = [p.grad.clone() for p in critic.parameters()]
    critic.optimizer.step()

    # L_d (eq. 6)
    features = feats(obs)
    weights = th.ones(obs.shape[0])
    if model.bc_weight_temp is not None:  # AWR's exp(beta A), A = Q(s, a) - Q(s, a_ema) in batch std units
        with th.no_grad():
            q_data, q_ema = (
                ref_q(critic, obs, a).sort(dim=0).values[: model.top_k].mean(dim=0)
                for a in (actions, ref_sample(policy.actor_ema, features))
            )
            adv = q_data - q_ema
            weights = th.exp(model.bc_weight_temp * adv / adv.std())
            weights = (weights / weights.mean()).clamp(max=model.bc_max_weight)
    t = th.randint(0, actor.n_diffusion_steps, (actions.shape[0],))
    noise = th.randn_like(actions)
    x_t = actor.schedule.sqrt_alphas_cumprod[t, None] * actions + actor.schedule.sqrt_one_minus_alphas_cumprod[t, None] * noise
    target = actions if actor.prediction_type == "sample" else noise  # the clean action (the default) or the noise
    bc_loss = (weights * ((actor.predict_noise(x_t, t, features) - target) ** 2).mean(dim=-1)).mean()
    # L_q (eq. 3, 4): gamma^i-weighted top-K pessimistic Q along the model rollout, masked after termination
    state, action = obs, ref_sample(actor, features)
    first_action = action
    alive = th.ones(obs.shape[0])
    terms, penalties, rewards = [], [], []
    dyn = policy.dynamics
    for i in range(model.rollout_length + 1):
        q_i = ref_q(critic, state, action, detach=True)
        if model.lcb_coef is None:
            q_k = q_i.sort(dim=0).values[: model.top_k].mean(dim=0)
        else:  # the lower confidence bound, written out: mean - k * unbiased std over the members
            mean = q_i.mean(dim=0)
            q_k = mean - model.lcb_coef * ((q_i - mean).pow(2).sum(dim=0) / (q_i.shape[0] - 1)).sqrt()
        terms.append((q_k, alive))
        if i == model.rollout_length:
            break
        next_state, reward, term_prob, _ = dyn.step(state, action)
        rewards.append(model.gamma**i * alive * reward * model.reward_scale)  # r_i counts while s_i is alive
        # the elites' disagreement, member by member: std over elites of the mean state change (standardised)
        x = th.cat(((state - dyn.obs_mean) / dyn.obs_std, (action - dyn.act_mean) / dyn.act_std), dim=-1)
        means = th.stack([dyn._forward(x[None], dyn.elites[j : j + 1])[0][0] for j in range(dyn.n_elites)])
        doubt = means[..., : dyn.obs_dim].std(dim=0).pow(2).mean(dim=-1).sqrt()
        term = model._termination_fn(state, action, next_state).float() if model._termination_fn else term_prob.detach()
        if model.lookahead_uncertainty_cutoff is not None:
            term = th.maximum(term, (doubt.detach() > model.lookahead_uncertainty_cutoff).float())
        penalties.append((alive * doubt).mean())
        alive = alive * (1.0 - term)
        state = next_state if model.backprop_through_model else next_state.detach()
        action = ref_sample(actor, feats(state))
    if model.lookahead_trust_margin is not None:  # a predicted term counts where Q there <= Q(s_t) + m mean |Q(s_t)|
        bound = (terms[0][0] + model.lookahead_trust_margin * terms[0][0].abs().mean()).detach()
        judged = [q_k.detach() for q_k, _ in terms]
        if model.lookahead_trust_rule == "bellman":  # or the value the rollout implies for s_t
            judged = [sum(rewards[:i]) + model.gamma**i * judged[i] for i in range(len(judged))]
        terms = terms[:1] + [(q_k, a * (judged[i] <= bound).float()) for i, (q_k, a) in enumerate(terms) if i > 0]
    confident = ref_confidence(model, critic, obs, first_action, actions)
    if confident is not None:
        terms = [(q_k, a * confident) for q_k, a in terms]
    scale = terms[0][0].abs().mean().detach().clamp_min(max(model.q_scale_floor_value or 0.0, 1e-6))
    # eq. 3's gamma^i, times lookahead_weight at the predicted states
    weights = [model.gamma**i * (model.lookahead_weight if i else 1.0) for i in range(model.rollout_length + 1)]
    if model.lookahead_normalization == "weights":
        weights = [w / sum(weights) for w in weights]
    q_loss = -sum(w * (a * q_k).mean() for w, (q_k, a) in zip(weights, terms, strict=True)) / scale
    q_loss = q_loss + model.lookahead_uncertainty_penalty * sum(w * u for w, u in zip(weights[1:], penalties, strict=True))
    actor_loss = bc_loss + model.eta_schedule(model._current_progress_remaining) * q_loss
    actor.optimizer.zero_grad()
    actor_loss.backward()
    actor_grads = [p.grad.clone() for p in actor.parameters()]
    actor.optimizer.step()
    with th.no_grad():  # EMA (ema_start=0, every step) and Polyak targets
        for p, p_ema in zip(actor.parameters(), policy.actor_ema.parameters(), strict=True):
            p_ema.copy_(model.ema_decay * p_ema + (1 - model.ema_decay) * p)
        for p, p_t in zip(critic.parameters(), policy.critic_target.parameters(), strict=True):
            p_t.copy_((1 - model.tau) * p_t + model.tau * p)
    return {
        "critic_loss": critic_loss,
        "bc_loss": bc_loss,
        "q_loss": q_loss,
        "actor_loss": actor_loss,
        "critic_grads": critic_grads,
        "actor_grads": actor_grads,
    }


def _close(a: th.Tensor, b: th.Tensor) -> None:
    th.testing.assert_close(a.detach(), b.detach(), rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"hopper": True},
        {},
        {"rollout_length": 0},
        {"backprop_through_model": True, "eta": 2.5},
        # the options for the learning-quality suspects (#12), each against the plain reference
        {"lookahead_normalization": "weights"},
        {"q_scale_floor": 50.0},
        {"eta": lambda progress: 0.25 + progress},
        {"lookahead_uncertainty_penalty": 0.7, "lookahead_normalization": "weights"},
        {"lookahead_uncertainty_cutoff": 0.215, "lookahead_uncertainty_penalty": 0.3},
        {"critic_diversity": 0.8},
        {"critic_diversity": 0.6, "critic_diversity_inputs": "states_and_actions", "rollout_length": 1},
        # issue #23: the paper's noise target, and the lower confidence bound
        {"prediction_type": "epsilon"},
        {"lcb_coef": 1.5},
        {"critic_layer_norm": False},  # the paper's plain critics (LayerNorm ones are the default)
        {"lookahead_weight": 1.0, "eta": 1.0},  # the paper's eq. 3 weights (#23's twelfth pass: 1/16 and 3.94)
        # advantage-weighted imitation (#23's twenty-first pass), with and without the weights' clip
        {"bc_weight_temp": 1.0},
        {"bc_weight_temp": 3.0, "bc_max_weight": 1.5},
        # the look-ahead counted only where the critic values a predicted state no higher than the current one
        {"lookahead_trust_margin": 0.0},
        {"lookahead_trust_margin": 0.01, "lcb_coef": 1.0},
        # or where the value the rollout implies for the current state is (the model's rewards on the way)
        {"lookahead_trust_margin": 0.0, "lookahead_trust_rule": "bellman"},
        {"lookahead_trust_margin": 0.005, "lookahead_trust_rule": "bellman", "lcb_coef": 1.0},
        # ReBRAC's critic penalty
        {"critic_bc_coef": 0.5},
        {"critic_bc_coef": 2.0, "rollout_length": 0},
        # the Q term only where the critic's members agree the actor's action beats the data's
        {"q_term_confidence": 0.0},
        {"q_term_confidence": 0.5, "rollout_length": 0},
    ],
)
def test_update_matches_reference(kwargs):
    model = _model(**kwargs)
    policy = model.policy
    ref_policy = copy.deepcopy(policy)  # its optimizers follow the copied parameters
    model._n_updates = 10  # past ema_start, an EMA step (ema_update_freq=1)
    model._current_progress_remaining = 0.6
    buffer = model._setup_offline_data()
    th.manual_seed(0)
    indices = buffer.sample_indices(32)
    batch = buffer._get_samples(indices)
    next_data = None
    if model.critic_bc_coef > 0:
        model._next_data_mask = model._episode_goes_on()
        next_data = model._next_data(indices)
        ref_next = ref_next_data_actions(model._offline_data, indices)
        assert 0 < float(ref_next[1].sum()) < 32  # rows at episode ends and rows within episodes
    th.manual_seed(1)
    stats = model._update(batch, next_data=next_data)
    critic_grads = [p.grad for p in policy.critic.parameters()]
    actor_grads = [p.grad for p in policy.actor.parameters()]
    th.manual_seed(1)
    ref = reference_step(model, ref_policy, batch, None if next_data is None else ref_next)
    for key in ("critic_loss", "bc_loss", "q_loss", "actor_loss"):
        _close(stats[key], ref[key])
    for got, want in zip(critic_grads + actor_grads, ref["critic_grads"] + ref["actor_grads"], strict=True):
        _close(got, want)
    # parameters, EMA actor and target critics after the optimiser steps and the averaging
    for got, want in zip(policy.parameters(), ref_policy.parameters(), strict=True):
        _close(got, want)
    for got, want in zip(policy.critic_target.parameters(), ref_policy.critic_target.parameters(), strict=True):
        _close(got, want)


def test_readable_sample_is_the_reference_chain():
    actor = _model().policy.actor_ema
    feats = th.randn(16, actor.features_dim)
    with th.no_grad():
        _close(
            actor.sample(feats, generator=th.Generator().manual_seed(3)),
            ref_sample(actor, feats, th.Generator().manual_seed(3)),
        )
        # the deterministic chain: the posterior means from a_T = 0
        x = th.zeros(16, actor.action_dim)
        for t in reversed(range(actor.n_diffusion_steps)):
            x = actor.schedule.step(actor.predict_noise(x, th.full((16,), t), feats), t, x, None)
        _close(actor.sample(feats, deterministic=True), x.clamp(-1.0, 1.0))


@pytest.mark.parametrize("fast", ["sample_chain", "sample_no_grad", "sample_no_grad_copies"])
@pytest.mark.parametrize("deterministic", [False, True])
@pytest.mark.parametrize("activation", [th.nn.ReLU, th.nn.Mish])
def test_fast_samplers_equal_readable_sample(fast, deterministic, activation):
    """Each fast form of eq. 5 draws the same noise and gives the same actions as ``DiffusionActor.sample``,
    with either activation (the no-grad plan swaps both modules for functions of its own)."""
    fns = {
        "sample_chain": sample_chain,
        "sample_no_grad": sample_no_grad,
        "sample_no_grad_copies": lambda *args, **kwargs: sample_no_grad(*args, copy_weights=True, **kwargs),
    }
    policy_kwargs = {"net_arch": [32, 32], "actor_activation_fn": activation}
    actor = _model(n_diffusion_steps=4, policy_kwargs=policy_kwargs).policy.actor
    assert any(isinstance(m, activation) for m in actor.trunk)
    feats = th.randn(16, actor.features_dim, requires_grad=True)
    for _ in range(2):
        got = fns[fast](actor, feats, generator=th.Generator().manual_seed(3), deterministic=deterministic)
        want = actor.sample(feats, generator=th.Generator().manual_seed(3), deterministic=deterministic)
        _close(got, want)
        if fast == "sample_chain":  # differentiable, with the readable chain's gradients
            got_grads = th.autograd.grad(got.square().sum(), [feats, *actor.parameters()])
            want_grads = th.autograd.grad(want.square().sum(), [feats, *actor.parameters()])
            for g, w in zip(got_grads, want_grads, strict=True):
                _close(g, w)
        with th.no_grad():  # an in-place update: the next round must see it
            for p in actor.parameters():
                p.add_(0.05 * th.randn_like(p))


def _write_data(model):
    with th.no_grad():
        for p in model.policy.actor_ema.parameters():
            p.data.mul_(1.5)  # bumps no version counter


def _write_polyak(model):
    polyak_update(model.policy.actor.parameters(), model.policy.actor_ema.parameters(), 0.5)


def _write_data_assignment(model):
    for p in model.policy.actor_ema.parameters():
        p.data = p.data * 0.5 + 0.1  # new storage


def _write_load_state_dict(model):
    other = _model(seed=7)
    model.policy.load_state_dict(other.policy.state_dict())


def _write_set_parameters(model):
    other = _model(seed=8)
    model.set_parameters(other.get_parameters())


def _write_training_step(model):
    model._n_updates = 10  # past ema_start; ema_update_freq=1: this step moves the EMA actor
    model.train(gradient_steps=1, batch_size=32)


@pytest.mark.parametrize(
    "write",
    [_write_data, _write_polyak, _write_data_assignment, _write_load_state_dict, _write_set_parameters, _write_training_step],
)
def test_predict_is_fresh_after_every_weight_write(write):
    """predict (the cached fast path) after a write of the weights == the readable sampler on the new weights."""
    model = _model()
    policy = model.policy
    obs = th.randn(8, 5)
    with th.no_grad():
        policy.actor.input_layer.weight.add_(0.1)  # the online actor differs from the EMA actor (polyak moves it)
        before = policy._predict(obs, deterministic=True).clone()
    write(model)
    with th.no_grad():
        after = policy._predict(obs, deterministic=True)
        # the default deterministic rule: the kernel mode of the chains with the observation's own noise
        k, steps = policy.mode_samples, policy.actor_ema.n_diffusion_steps
        noise = observation_noise(obs, steps, policy.actor_ema.action_dim * k, policy.predict_seed)
        noise = noise.reshape(steps + 1, obs.shape[0] * k, -1)  # row b k + j: sample j of observation b
        feats = policy.actor_features(obs).repeat_interleave(k, dim=0)
        want_samples = policy.actor_ema.sample(feats, noise=noise)
        fast_samples = sample_no_grad(policy.actor_ema, feats, noise=noise)
        want = kernel_mode(want_samples.view(obs.shape[0], k, -1), policy.mode_bandwidth)
    assert not th.allclose(before, want), "the write did not change the policy: the test would prove nothing"
    _close(fast_samples, want_samples)
    # the mode of the fast samples (a near tie between two samples' densities may pick another start on rounding)
    _close(after, kernel_mode(fast_samples.view(obs.shape[0], k, -1), policy.mode_bandwidth))
    with th.no_grad():
        noise_free = policy.actor_ema.sample(policy.actor_features(obs), deterministic=True)
    _close(sample_no_grad(policy.actor_ema, policy.actor_features(obs), deterministic=True), noise_free)


def test_predict_uses_one_cached_plan_until_a_write():
    """Between writes, predict reuses its plan (the fast path stays fast); a write through .data rebuilds it."""
    actor = _model().policy.actor_ema
    feats = th.randn(4, actor.features_dim)
    plan = fast_sampling.cached_view_plan(actor)
    sample_no_grad(actor, feats, deterministic=True)
    assert fast_sampling.cached_view_plan(actor) is plan
    actor.time_mlp[1].weight.data.mul_(2.0)
    assert fast_sampling.cached_view_plan(actor) is not plan


def test_kernel_mode_fast_equals_kernel_mode():
    """The mean shift in the samples' weights lands where the readable one lands: on random samples, on two
    separated modes (the same mode chosen), and at the start itself with no step."""
    g = th.Generator().manual_seed(0)
    uniform = th.rand(64, 16, 6, generator=g) * 2 - 1
    centres = th.tensor([[0.6, -0.2, 0.1], [-0.6, 0.3, -0.4]])
    mixture = centres[th.randint(0, 2, (32, 16), generator=g)] + 0.05 * th.randn(32, 16, 3, generator=g)
    for samples in (uniform, mixture):
        for bandwidth in (0.1, 0.2, 0.4):
            _close(fast_sampling.kernel_mode_fast(samples, bandwidth), kernel_mode(samples, bandwidth))
        assert th.equal(fast_sampling.kernel_mode_fast(samples, 0.2, 0), kernel_mode(samples, 0.2, 0))


def test_mish_exp_equals_mish():
    x = th.cat((th.linspace(-30, 30, 2001), th.tensor([-100.0, 100.0, 0.0]))).requires_grad_(True)
    y = x.detach().clone().requires_grad_(True)
    _close(mish_exp(x), F.mish(y))
    mish_exp(x).sum().backward()
    F.mish(y).sum().backward()
    _close(x.grad, y.grad)
    assert th.isfinite(x.grad).all()


@pytest.mark.slow
def test_compiled_mish_equals_mish():
    x = th.randn(4, 64, 128, requires_grad=True)  # above MIN_COMPILED_NUMEL: the compiled kernel runs
    y = x.detach().clone().requires_grad_(True)
    _close(compiled_mish(x), F.mish(y))
    compiled_mish(x).sum().backward()
    F.mish(y).sum().backward()
    _close(x.grad, y.grad)
    _close(FusedMish()(x), F.mish(x))


@pytest.mark.slow  # torch.compile for minutes; the fallback path: test_compile_update_falls_back_to_eager
@pytest.mark.parametrize(
    "cudagraph_path, critic_diversity, model_td_weight, lookahead_actions, bc_weight_temp, lookahead_trust",
    [
        (False, 0.0, 0.0, "actor", None, None),
        (True, 0.0, 0.0, "actor", None, None),
        (False, 0.5, 1.0, "actor", None, None),
        (False, 0.0, 0.0, "ema", None, None),
        (False, 0.0, 0.0, "actor", 1.0, None),
        pytest.param(False, 0.0, 0.0, "actor", None, (0.0, "value"), id="trust-value"),
        pytest.param(False, 0.0, 0.0, "actor", None, (0.0, "bellman"), id="trust-bellman"),
        pytest.param(False, 0.0, 0.0, "actor", None, "critic-bc", id="critic-bc"),
        pytest.param(False, 0.0, 0.0, "actor", None, "fallback", id="fallback"),
        pytest.param(False, 0.0, 0.0, "actor", None, "q-confidence", id="q-confidence"),
    ],
)
def test_compiled_update_matches_eager(
    monkeypatch,
    cudagraph_path,
    critic_diversity,
    model_td_weight,
    lookahead_actions,
    bc_weight_temp,
    lookahead_trust,
):
    """``compile_update=True`` (torch.compile of both losses, forward and backward) == the eager update, step by step.

    ``cudagraph_path`` runs the CUDA code path on CPU (inductor's ``triton.cudagraphs`` option, step marks, output
    copies); inductor captures graphs only on CUDA, so this checks the plumbing, not the capture. With
    ``critic_diversity`` the critic loss holds the similarity term's input gradients written out
    (sb3_pola.common.input_gradients), which a compiled graph differentiates once; with ``model_td_weight`` it also
    holds the model rollouts' TD loss; with ``lookahead_actions="ema"`` the EMA actor acts in the look-ahead, the
    gradient through the model; with ``bc_weight_temp`` the imitation term's advantage weights (the EMA actor's chain
    and a critic call inside the BC graph); with ``lookahead_trust`` (margin, rule) the look-ahead's mask from the
    critic's own values (and, by the Bellman rule, the model's rewards); ``"critic-bc"`` in its place: ReBRAC's
    critic penalty, the data's next actions in the critic's graph; ``"fallback"``: ``fallback_confidence``'s
    imitation-only actor, its own loss graph and step; ``"q-confidence"``: ``q_term_confidence``'s mask from a critic
    call at the data's actions inside the Q term's graph.
    """
    from torch._dynamo.utils import counters

    from sb3_pola.pola import POLA

    if cudagraph_path:
        monkeypatch.setattr(POLA, "_cudagraphs", property(lambda self: self.compile_update))

    kwargs = dict(
        rollout_length=1,
        n_critics=3,
        hopper=True,
        max_grad_norm=1.0,
        n_diffusion_steps=2,
        policy_kwargs={"net_arch": [16]},
        dynamics_kwargs={"n_members": 2, "n_elites": 2, "hidden_dim": 8, "n_layers": 1},
        critic_diversity=critic_diversity,
        model_td_weight=model_td_weight,
        lookahead_actions=lookahead_actions,
        backprop_through_model=lookahead_actions == "ema",
        bc_weight_temp=bc_weight_temp,
    )
    if lookahead_trust == "critic-bc":
        kwargs["critic_bc_coef"] = 0.5
    elif lookahead_trust == "q-confidence":
        kwargs["q_term_confidence"] = 0.0
    elif lookahead_trust == "fallback":
        kwargs["policy_kwargs"] = {"net_arch": [16], "fallback_confidence": 1.0}
    elif lookahead_trust:
        kwargs.update(lookahead_trust_margin=lookahead_trust[0], lookahead_trust_rule=lookahead_trust[1])
    # dynamo's counters are global and its cache outlives a test: both reset, so the first step's graphs are this test's
    th._dynamo.reset()
    counters.clear()
    eager, compiled = _model(**kwargs), _model(compile_update=True, **kwargs)
    compiled.policy.load_state_dict(eager.policy.state_dict())
    buffer = eager._setup_offline_data()
    if eager.critic_bc_coef > 0:
        eager._next_data_mask = eager._episode_goes_on()
    graphs = []
    for step in range(3):
        th.manual_seed(step)
        indices = buffer.sample_indices(32)
        batch = buffer._get_samples(indices)
        next_data = None if eager._next_data_mask is None else eager._next_data(indices)
        th.manual_seed(100 + step)
        want = eager._update(batch, next_data=next_data)
        th.manual_seed(100 + step)
        got = compiled._update(batch, next_data=next_data)
        for key in want:
            _close(got[key], want[key])
        for model in (eager, compiled):
            model._n_updates += 1
        graphs.append(counters["stats"]["unique_graphs"])
    assert graphs[0] > 0 and graphs[-1] == graphs[0], "the compiled losses were recompiled after the first step"
    for got, want in zip(compiled.policy.parameters(), eager.policy.parameters(), strict=True):
        _close(got, want)
    assert compiled._bc_loss_fn.compiled_ok and compiled._q_term_fn.compiled_ok
    assert compiled._critic_loss_fn.compiled_ok  # with the similarity term too, in its written-out form
    assert eager._critic_loss_fn.compiled is None and eager._bc_loss_fn.compiled is None
    if compiled.policy.fallback_actor is not None:
        assert compiled._fallback_loss_fn.compiled_ok


def test_compile_update_falls_back_to_eager(monkeypatch):
    """A compiler that fails (no C++ compiler, unsupported platform) leaves an eager update and a warning."""

    def broken_compile(fn, **kwargs):
        def compiled(*args):
            raise RuntimeError("no compiler here")

        return compiled

    monkeypatch.setattr(th, "compile", broken_compile)
    for name in ("_compiled", "_failed"):  # compiled Mish's module state is restored after the test
        monkeypatch.setattr(activations, name, getattr(activations, name))
    eager, compiled = _model(), _model(compile_update=True)
    compiled.policy.load_state_dict(eager.policy.state_dict())
    batch = eager._setup_offline_data().sample(32)
    th.manual_seed(5)
    want = eager._update(batch)
    th.manual_seed(5)
    with pytest.warns(UserWarning, match="compilation failed"):
        got = compiled._update(batch)
    for key in want:
        _close(got[key], want[key])


@pytest.mark.parametrize("shape", [(3, 5), (64, 256), (2, 64, 128)])
def test_inference_mish_equals_mish(shape):
    x = th.cat((th.linspace(-30, 30, math.prod(shape) - 3), th.tensor([-100.0, 100.0, 0.0]))).reshape(shape)
    _close(inference_mish(x.clone()), F.mish(x))


def test_chunked_sampling_equals_one_pass():
    """The no-grad chain splits large batches into row chunks: same actions as the readable chain."""
    actor = _model().policy.actor_ema
    feats = th.randn(700, actor.features_dim)  # 256 + 256 + 188 rows
    for copy_weights in (False, True):
        fast = sample_no_grad(actor, feats, deterministic=True, copy_weights=copy_weights)
        noisy = sample_no_grad(actor, feats, generator=th.Generator().manual_seed(0), copy_weights=copy_weights)
        with th.no_grad():
            _close(fast, actor.sample(feats, deterministic=True))
            _close(noisy, actor.sample(feats, generator=th.Generator().manual_seed(0)))


def test_td_target_by_hand_with_diverged_targets_and_terminal_rows():
    """The critic's target ``r + gamma (1 - done) min_j Q'_j(s', a')``, ``a'`` from the EMA actor, computed by hand.

    The target critics and the EMA actor are moved away from the online networks (a fresh model has them equal, so a
    target built from the online ones would pass), and half the rows are terminal (the synthetic data has almost none).
    """
    model = _model(critic_diversity=0.0)
    policy = model.policy
    gen = th.Generator().manual_seed(7)
    with th.no_grad():
        for p in (*policy.critic_target.parameters(), *policy.actor_ema.parameters()):
            p.add_(0.3 * th.randn(p.shape, generator=gen))
    buffer = model._setup_offline_data()
    th.manual_seed(0)
    batch = buffer.sample(32)
    dones = th.zeros_like(batch.dones)
    dones[::2] = 1.0
    batch = batch._replace(dones=dones)
    obs, actions, next_obs = batch.observations, batch.actions, batch.next_observations
    rewards, done = batch.rewards.flatten().double(), dones.flatten().double()
    feats = policy.features_extractor
    with th.no_grad():
        q_online = ref_q(policy.critic, obs, actions).double()  # [N, B], before the step
        th.manual_seed(1)
        next_actions = ref_sample(policy.actor_ema, feats(next_obs))
        next_q = ref_q(policy.critic_target, next_obs, next_actions).double().min(dim=0).values
        target = rewards + model.gamma * (1.0 - done) * next_q
        # what a target from the online networks would give: far enough from the right one to be told apart
        th.manual_seed(1)
        wrong_q = ref_q(policy.critic, next_obs, ref_sample(policy.actor, feats(next_obs))).double().min(dim=0).values
        wrong = rewards + model.gamma * (1.0 - done) * wrong_q
    assert th.equal(target[::2], rewards[::2])  # terminal rows: the reward alone
    assert (target[1::2] - wrong[1::2]).abs().mean() > 0.05
    expected_loss = ((q_online - target) ** 2).mean(dim=1).sum()
    th.manual_seed(1)
    stats = model._update(batch)
    assert stats["target_q"].item() == pytest.approx(target.mean().item(), rel=1e-5, abs=1e-5)
    assert stats["critic_loss"].item() == pytest.approx(expected_loss.item(), rel=1e-5, abs=1e-5)
