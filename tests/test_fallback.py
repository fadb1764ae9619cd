"""``policy_kwargs={"fallback_confidence": k}``: an imitation-only actor trained beside POLA's, and ``predict``'s
confident choice between their actions by the critic's members."""

from __future__ import annotations

import pathlib

import numpy as np
import pytest
import torch as th
from helpers import light_kwargs
from torch import nn

from sb3_pola import POLA


def _model(dataset: str, k: float | None = 1.0, **overrides) -> POLA:
    policy_kwargs = {"net_arch": [32, 32], **({} if k is None else {"fallback_confidence": k})}
    return POLA("MlpPolicy", dataset=dataset, **light_kwargs(policy_kwargs=policy_kwargs, **overrides))


class _GainCritic(nn.Module):
    """A critic ensemble whose members' ``Q(s, a) - Q(s, a')`` is a table: member ``j`` gives the first batch half
    ``gains[j]`` and the second half 0 (``confident_choice`` stacks the action's rows before the fallback's)."""

    def __init__(self, gains: th.Tensor) -> None:
        super().__init__()
        self.gains = gains  # [N, B]

    def forward(self, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
        return th.cat([self.gains, th.zeros_like(self.gains)], dim=1)  # [N, 2B]


def test_confident_choice_takes_the_action_only_where_the_members_agree(tiny_dataset: str):
    policy = _model(tiny_dataset).policy
    # per state (columns): every member gains 1 (mean 1, std 0); gains +-1 around a mean of 0.1 (std ~1.05);
    # a mean of 0.5 with a std of ~0.41; every member loses 1
    gains = th.tensor([[1.0, 1.1, 0.0, -1.0], [1.0, -0.9, 0.5, -1.0], [1.0, 1.1, 1.0, -1.0], [1.0, -0.9, 0.5, -1.0]])
    policy.critic = _GainCritic(gains)  # type: ignore[assignment]
    obs = th.zeros(4, 3)
    action, fallback = th.ones(4, 2), -th.ones(4, 2)
    took = {k: policy.confident_choice(obs, action, fallback, k)[:, 0] > 0 for k in (0.0, 1.0, 2.0)}
    assert took[0.0].tolist() == [True, True, True, False]  # the ensemble mean's choice
    assert took[1.0].tolist() == [True, False, True, False]
    assert took[2.0].tolist() == [True, False, False, False]


def test_predict_chooses_between_the_two_actors(tiny_dataset: str):
    model = _model(tiny_dataset)
    model.learn(40)
    policy = model.policy
    assert policy.fallback_actor is not None and policy.fallback_actor_ema is not None
    obs = np.random.default_rng(0).normal(0.0, 2.0, (64, 3)).astype(np.float32)
    obs_t = th.as_tensor(obs)
    with th.no_grad():
        own = policy._actor_action(policy.actor_ema, obs_t, deterministic=True)
        fallback = policy._actor_action(policy.fallback_actor_ema, obs_t, deterministic=True)
        want = policy.unscale_action(policy.confident_choice(obs_t, own, fallback, 1.0).numpy())
    assert not th.allclose(own, fallback, atol=1e-4)  # two actors, trained apart
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], want)
    # a k no gain reaches gives the fallback's actions everywhere, one below every gain POLA's own
    policy.fallback_confidence = 1e9
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], policy.unscale_action(fallback.numpy()))
    policy.fallback_confidence = -1e9
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], policy.unscale_action(own.numpy()))
    # without the option predict is the actor's own action, and no second actor is built
    plain = _model(tiny_dataset, k=None).policy
    assert plain.fallback_actor is None and not any("fallback" in name for name in plain.state_dict())


def test_fallback_actor_imitates_whatever_the_q_term_does(tiny_dataset: str):
    """One update at eta 0 and at eta 5 from the same weights and random state: POLA's actor moves apart, the
    fallback actor moves to the same place (its loss is ``L_d`` alone, its optimizer its own); its EMA copies it
    before ``ema_start``."""
    models = [_model(tiny_dataset, eta=eta, ema_start=100, ema_update_freq=1) for eta in (0.0, 5.0)]
    models[1].policy.load_state_dict(models[0].policy.state_dict())
    before = [p.clone() for p in models[0].policy.fallback_actor.parameters()]  # type: ignore[union-attr]
    for model in models:
        buffer = model._setup_offline_data()
        th.manual_seed(0)
        batch = buffer._get_samples(buffer.sample_indices(16))
        th.manual_seed(1)
        stats = model._update(batch)
        assert "fallback_bc_loss" in stats
    fallback = [list(m.policy.fallback_actor.parameters()) for m in models]  # type: ignore[union-attr]
    for p0, p1 in zip(*fallback, strict=True):
        th.testing.assert_close(p0, p1, rtol=0, atol=0)
    assert any(not th.equal(p, b) for p, b in zip(fallback[0], before, strict=True))
    assert any(not th.equal(p0, p1) for p0, p1 in zip(models[0].actor.parameters(), models[1].actor.parameters(), strict=True))
    for model in models:
        ema = model.policy.fallback_actor_ema
        assert ema is not None
        for p, q in zip(model.policy.fallback_actor.parameters(), ema.parameters(), strict=True):  # type: ignore[union-attr]
            th.testing.assert_close(p, q, rtol=0, atol=0)


def test_fallback_actor_and_its_optimizer_are_saved(tiny_dataset: str, tmp_path: pathlib.Path):
    model = _model(tiny_dataset)
    model.learn(30)
    model.save(tmp_path / "m.zip")
    loaded = POLA.load(tmp_path / "m.zip", device="cpu")
    assert loaded.policy.fallback_confidence == 1.0
    obs = np.random.default_rng(1).normal(size=(8, 3)).astype(np.float32)
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])
    state = loaded.policy.fallback_actor.optimizer.state_dict()["state"]  # type: ignore[union-attr]
    want = model.policy.fallback_actor.optimizer.state_dict()["state"]  # type: ignore[union-attr]
    assert len(state) == len(want) > 0
    th.testing.assert_close(state[0]["exp_avg"], want[0]["exp_avg"])


@pytest.mark.parametrize(
    "policy_kwargs, message",
    [
        ({"fallback_confidence": float("inf")}, "fallback_confidence must be a finite number or None"),
        ({"fallback_confidence": 1.0, "n_action_samples": 4}, "it needs n_action_samples=1"),
    ],
)
def test_bad_fallback_confidence(tiny_dataset: str, policy_kwargs: dict, message: str):
    with pytest.raises(ValueError, match=message):
        POLA("MlpPolicy", dataset=tiny_dataset, **light_kwargs(policy_kwargs=policy_kwargs))
