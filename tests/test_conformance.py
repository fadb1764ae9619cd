"""One SB3-contract tester run on every configuration (in the spirit of d3rlpy's algo tester)."""

from __future__ import annotations

import pathlib

import numpy as np
import pytest
import torch as th
from helpers import light_kwargs, record_random_dataset

from sb3_pola import POLA


def params_equal(a: dict, b: dict) -> bool:
    return all(th.equal(a[k], b[k]) for k in a) and a.keys() == b.keys()


def check_conformance(dataset: str, tmp_path: pathlib.Path, **config) -> None:
    """learn / predict shapes / save-load identical deterministic actions / continue / parameters / seeding."""
    n_steps = 12
    model = POLA("MlpPolicy", dataset=dataset, **light_kwargs(**config))
    model.learn(n_steps)
    assert model.num_timesteps == n_steps and model._n_updates == n_steps

    obs_space, act_space = model.observation_space, model.action_space
    rng = np.random.default_rng(0)
    single = rng.normal(size=obs_space.shape).astype(np.float32)
    batch = rng.normal(size=(5, *obs_space.shape)).astype(np.float32)
    action, state = model.predict(single, deterministic=True)
    assert action.shape == act_space.shape and state is None
    assert np.all(action >= act_space.low) and np.all(action <= act_space.high)
    actions, _ = model.predict(batch, deterministic=True)
    assert actions.shape == (5, *act_space.shape)
    model.set_random_seed(3)
    stochastic, _ = model.predict(batch, deterministic=False)
    assert stochastic.shape == actions.shape
    assert np.all(stochastic >= act_space.low) and np.all(stochastic <= act_space.high)
    model.set_random_seed(3)  # a seeded draw repeats
    np.testing.assert_array_equal(model.predict(batch, deterministic=False)[0], stochastic)
    # the next draw, and the noise-free chain, differ (where the untrained actor is not saturated at the bounds)
    if not np.isin(stochastic, np.stack([act_space.low, act_space.high])).all():
        assert not np.array_equal(model.predict(batch, deterministic=False)[0], stochastic)
        assert not np.array_equal(stochastic, actions)
    np.testing.assert_array_equal(model.predict(batch, deterministic=True)[0], actions)

    # save / load without env or dataset: identical deterministic actions
    path = tmp_path / "model.zip"
    model.save(path)
    loaded = POLA.load(path, device="cpu")
    np.testing.assert_array_equal(loaded.predict(batch, deterministic=True)[0], actions)
    assert params_equal(model.policy.state_dict(), loaded.policy.state_dict())

    # get_parameters / set_parameters round trip
    fresh = POLA("MlpPolicy", dataset=dataset, **light_kwargs(**config, seed=123))
    fresh.set_parameters(model.get_parameters())
    np.testing.assert_array_equal(fresh.predict(batch, deterministic=True)[0], actions)

    # continue training after load: the dataset is recorded in the zip
    loaded.learn(4, reset_num_timesteps=False)
    assert loaded.num_timesteps == n_steps + 4
    assert not params_equal(model.policy.state_dict(), loaded.policy.state_dict())

    # seeded runs reproduce exactly
    again = POLA("MlpPolicy", dataset=dataset, **light_kwargs(**config)).learn(n_steps)
    assert params_equal(model.policy.state_dict(), again.policy.state_dict())


CONFIGS = {
    "default": {},
    "T0_diffusion_ql": dict(rollout_length=0),
    "T3_detached_states": dict(rollout_length=3, backprop_through_model=False),
    "no_products_cosine": dict(use_state_products=False, beta_schedule="cosine", n_diffusion_steps=3),
    "behaviour_cloning": dict(eta=0.0),
    "candidates_and_critic_products": dict(policy_kwargs=dict(net_arch=[16], n_action_samples=4, critic_state_products=True)),
}


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_conformance(name, pendulum_path, tmp_path):
    check_conformance(pendulum_path, tmp_path, **CONFIGS[name])


def test_conformance_mujoco_termination_rule(tmp_path_factory, tmp_path):
    # InvertedPendulum terminates: the look-ahead uses its known rule, the model learns no termination head
    path = str(record_random_dataset(tmp_path_factory.mktemp("ip"), "invertedpendulum/random-v0", "InvertedPendulum-v5", 300))
    check_conformance(path, tmp_path)
    model = POLA("MlpPolicy", dataset=path, **light_kwargs())
    assert model._termination_fn is not None
