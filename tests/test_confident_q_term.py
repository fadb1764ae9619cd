"""``experiments/policy_quality/confident_q_term.py``: the Q term only where the critic's members agree the actor's
action beats the data's."""

from __future__ import annotations

import importlib.util
import pathlib

import pytest
import torch as th
from helpers import light_kwargs
from stable_baselines3.common.logger import configure

from sb3_pola import POLA

SCRIPT = pathlib.Path(__file__).resolve().parents[1] / "experiments" / "policy_quality" / "confident_q_term.py"


@pytest.fixture(scope="module")
def module():
    spec = importlib.util.spec_from_file_location("confident_q_term", SCRIPT)
    assert spec is not None and spec.loader is not None
    loaded = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(loaded)
    return loaded


def _model(module, path: str, k: float):
    model = module.ConfidentQTerm("MlpPolicy", dataset=path, **light_kwargs(n_critics=4))
    model.gate_k = k
    model.set_logger(configure(None, [""]))
    model.policy.dynamics.freeze()
    return model, model.replay_buffer.observations[:64], model.replay_buffer.actions[:64]


def _q_term(model, obs, actions, plain: bool = False):
    """The actor step's Q term on fixed draws: the gated class's, or POLA's own (``plain``)."""
    th.manual_seed(0)
    model._bc_loss(obs, actions, model._bc_temp_value)
    th.manual_seed(1)
    with model._critic_frozen():
        if plain:
            return POLA._q_term(model, obs, model._eta_value)
        return model._q_term(obs, model._eta_value)


def test_gate_shut_leaves_no_q_gradient_and_open_is_the_plain_term(module, pendulum_path):
    model, obs, actions = _model(module, pendulum_path, 1e9)  # no state passes
    loss, stats = _q_term(model, obs, actions)
    assert float(stats["gate_share"]) == 0.0 and float(loss.detach()) == 0.0
    loss.backward()
    assert all(p.grad is None or not p.grad.any() for p in model.actor.parameters())

    model.gate_k = -1e9  # every state passes: the plain Q term on the same draws
    gated, stats = _q_term(model, obs, actions)
    plain, _ = _q_term(model, obs, actions, plain=True)
    assert float(stats["gate_share"]) == 1.0
    th.testing.assert_close(gated, plain, rtol=0, atol=0)


def test_gate_counts_the_states_where_the_members_agree(module, pendulum_path):
    model, obs, actions = _model(module, pendulum_path, 0.0)
    _, stats = _q_term(model, obs, actions)
    th.manual_seed(1)  # the actor's action at s_t is the Q term's first draw
    with th.no_grad():
        action = model._sample_actor(model.policy.actor_features(obs))
        gain = model.critic(obs, action) - model.critic(obs, actions)  # [N, B]
    want = (gain.mean(dim=0) > 0).float().mean()
    assert 0.0 < float(want) < 1.0
    th.testing.assert_close(stats["gate_share"], want)
