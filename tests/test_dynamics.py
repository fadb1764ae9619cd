"""EnsembleDynamics: vectorised forward, fitting, differentiable step, save/load, termination head."""

from __future__ import annotations

import io
from collections.abc import Iterator

import numpy as np
import pytest
import torch as th
import torch.nn.functional as F

from sb3_pola.common.dynamics import EnsembleDynamics, _split_statistics
from sb3_pola.common.torch_layers import VectorizedLinear

OBS_DIM, ACT_DIM = 5, 2


@pytest.fixture(autouse=True)
def _one_thread() -> Iterator[None]:
    """One torch thread per test (pytest runs with -n 2): small matmuls gain nothing from more, and
    oversubscribed OpenMP threads are an order of magnitude slower on a busy machine. Restored afterwards."""
    threads = th.get_num_threads()
    th.set_num_threads(1)
    yield
    th.set_num_threads(threads)


def _synthetic(n: int, nonlinear: bool, seed: int = 0) -> dict[str, th.Tensor]:
    """Transitions of a known system: s' = s + f(s, a) + noise, r = g(s, a) + noise, done = s'[0] > 1.

    The system is fixed; ``seed`` only draws the samples.
    """
    system = th.Generator().manual_seed(1234)
    a_mat = th.randn(OBS_DIM, OBS_DIM, generator=system) * 0.2
    b_mat = th.randn(ACT_DIM, OBS_DIM, generator=system) * 0.5
    gen = th.Generator().manual_seed(seed)
    obs = th.randn(n, OBS_DIM, generator=gen)
    act = th.rand(n, ACT_DIM, generator=gen) * 2 - 1
    delta = obs @ a_mat + act @ b_mat
    if nonlinear:
        delta = th.tanh(delta) + 0.3 * th.sin(2 * obs)
        reward = obs[:, 0] * act[:, 0] - 0.1 * (act**2).sum(-1)
    else:
        reward = obs[:, 0] + act[:, 0]
    next_obs = obs + delta + 0.01 * th.randn(n, OBS_DIM, generator=gen)
    reward = reward + 0.01 * th.randn(n, generator=gen)
    dones = (next_obs[:, 0] > 1.0).float()
    return {"obs": obs, "act": act, "next_obs": next_obs, "rew": reward, "done": dones}


def _small(**kwargs: object) -> EnsembleDynamics:
    return EnsembleDynamics(OBS_DIM, ACT_DIM, n_members=4, n_elites=3, hidden_dim=64, n_layers=2, **kwargs)  # type: ignore[arg-type]


def test_vectorized_forward_equals_member_loop() -> None:
    th.manual_seed(0)
    model = EnsembleDynamics(OBS_DIM, ACT_DIM, n_members=5, n_elites=3, hidden_dim=32, n_layers=3, learn_termination=True)
    obs, act = th.randn(8, OBS_DIM), th.randn(8, ACT_DIM)
    mean, logvar, logit = model(obs, act)  # [E, B, D]
    assert mean.shape == logvar.shape == (5, 8, OBS_DIM + 1)
    assert logit is not None and logit.shape == (5, 8)
    x = model.normalize_inputs(obs, act)
    layers = model.linear_layers
    for m in range(model.n_members):
        h = x
        for i, layer in enumerate(layers):
            h = F.linear(h, layer.weight[m].T, layer.bias[m, 0])
            if i < len(layers) - 1:
                h = F.silu(h)
        d = OBS_DIM + 1
        raw_logvar = h[:, d : 2 * d]
        lv = model.max_logvar - F.softplus(model.max_logvar - raw_logvar)
        lv = model.min_logvar + F.softplus(lv - model.min_logvar)
        th.testing.assert_close(mean[m], h[:, :d])
        th.testing.assert_close(logvar[m], lv)
        th.testing.assert_close(logit[m], h[:, 2 * d])
    # the member-subset path of step() agrees with the full forward
    members = th.tensor([4, 1])
    sub_mean, _, _ = model._forward(x.unsqueeze(0).expand(2, -1, -1), members)
    th.testing.assert_close(sub_mean, mean[members])
    assert all(isinstance(layer, VectorizedLinear) for layer in layers) and len(layers) == 4


def test_logvar_is_bounded() -> None:
    th.manual_seed(0)
    model = _small()
    _, logvar, _ = model(th.randn(64, OBS_DIM) * 1e3, th.randn(64, ACT_DIM) * 1e3)
    # soft bounds: exceeded by at most softplus(-(max - min)) ~ 3e-5
    assert (logvar <= model.max_logvar + 1e-4).all() and (logvar >= model.min_logvar - 1e-4).all()


@pytest.mark.parametrize("nonlinear", [False, True])
def test_fit_beats_no_change_baseline(nonlinear: bool) -> None:
    data = _synthetic(2000, nonlinear)
    th.manual_seed(0)
    model = _small()
    metrics = model.fit(data["obs"], data["act"], data["next_obs"], data["rew"], max_epochs=40, learning_rate=1e-2)
    assert metrics["holdout_mse"] < 0.2 * metrics["no_change_mse"], metrics
    assert metrics["holdout_reward_mse"] < 0.2 * float(data["rew"].var()), metrics
    assert metrics["epochs"] <= 40 and metrics["steps"] > 0 and metrics["fit_time"] > 0
    assert model.elites.dtype == th.long and model.elites.shape == (3,)
    assert len(set(model.elites.tolist())) == 3
    # the normalisation statistics come from the data
    assert not th.allclose(model.target_std, th.ones_like(model.target_std))


def test_fit_accepts_numpy_and_respects_max_steps() -> None:
    data = _synthetic(600, nonlinear=False)
    th.manual_seed(0)
    model = _small()
    np_data = {k: v.numpy().astype(np.float64) for k, v in data.items()}
    metrics = model.fit(np_data["obs"], np_data["act"], np_data["next_obs"], np_data["rew"], max_steps=7, batch_size=64)
    assert metrics["steps"] == 7


def test_fit_is_reproducible_with_seed() -> None:
    data = _synthetic(800, nonlinear=True)
    states = []
    for _ in range(2):
        th.manual_seed(123)
        model = _small()
        model.fit(data["obs"], data["act"], data["next_obs"], data["rew"], max_epochs=3, batch_size=128)
        states.append(model.state_dict())
    for key in states[0]:
        th.testing.assert_close(states[0][key], states[1][key], rtol=0, atol=0)


def test_split_statistics_match_materialised_split() -> None:
    gen = th.Generator().manual_seed(0)
    n = 1000
    obs = th.randn(n, OBS_DIM, generator=gen) * 5 + 100  # large offset: a naive sum-of-squares std would lose it
    obs[:, 1] = 3.0  # constant column: std 1
    act = th.rand(n, ACT_DIM, generator=gen)
    next_obs = obs + 0.01 * th.randn(n, OBS_DIM, generator=gen)
    rew = th.randn(n, 1, generator=gen)
    rows = th.randperm(n, generator=gen, dtype=th.int32)[100:]
    x = th.cat((obs, act), dim=-1)[rows.long()].double()
    y = th.cat((next_obs - obs, rew), dim=-1)[rows.long()].double()
    for chunk_size in (1, 7, 900, 4096):  # merging of uneven chunks, and a single chunk
        in_mean, in_std, t_mean, t_std = _split_statistics(obs, act, next_obs, rew, rows, chunk_size=chunk_size)
        assert all(t.dtype == th.float32 for t in (in_mean, in_std, t_mean, t_std))
        th.testing.assert_close(in_mean, x.mean(0).float())
        th.testing.assert_close(t_mean, y.mean(0).float())
        expected_in_std = x.std(0).float()
        expected_in_std[1] = 1.0
        th.testing.assert_close(in_std, expected_in_std)
        th.testing.assert_close(t_std, y.std(0).float())
    # one row: no spread to measure
    _, in_std, _, t_std = _split_statistics(obs, act, next_obs, rew, rows[:1])
    assert (in_std == 1).all() and (t_std == 1).all()


def test_fit_leaves_caller_tensors_untouched() -> None:
    data = _synthetic(700, nonlinear=True)
    data["rew"] = data["rew"].reshape(-1, 1)  # [N, 1] views, as the replay buffer passes them
    data["done"] = data["done"].reshape(-1, 1)
    before = {k: v.clone() for k, v in data.items()}
    th.manual_seed(0)
    model = _small(learn_termination=True)
    model.fit(data["obs"], data["act"], data["next_obs"], data["rew"], data["done"], max_epochs=2, batch_size=64)
    for key, value in data.items():
        assert th.equal(value, before[key]), key
    # the statistics are those of the training split: close to those of the whole data set
    th.testing.assert_close(model.obs_mean, data["obs"].mean(0), atol=0.1, rtol=0)
    th.testing.assert_close(model.target_std[-1], data["rew"].std(), atol=0.1, rtol=0.1)


def test_early_stopping_and_epoch_cap() -> None:
    data = _synthetic(1500, nonlinear=False)
    th.manual_seed(0)
    model = _small()
    # 1200 training samples / 64 = 38 steps per pass, capped at 10 per epoch
    metrics = model.fit(
        data["obs"], data["act"], data["next_obs"], data["rew"], batch_size=64, max_epochs=3, max_epoch_steps=5
    )
    assert metrics["steps"] == 15 and metrics["epochs"] == 3
    # patience=1 stops at the first epoch without a >1% improvement of any member
    th.manual_seed(0)
    model = _small()
    metrics = model.fit(
        data["obs"],
        data["act"],
        data["next_obs"],
        data["rew"],
        patience=1,
        max_epochs=300,
        max_epoch_steps=2,
        learning_rate=1e-2,
    )
    assert metrics["epochs"] < 300


def test_step_differentiable_after_freeze() -> None:
    th.manual_seed(0)
    model = _small(learn_termination=True)
    data = _synthetic(500, nonlinear=True)
    model.fit(data["obs"], data["act"], data["next_obs"], data["rew"], data["done"], max_epochs=2)
    model.freeze()
    assert not model.training
    obs = th.randn(16, OBS_DIM, requires_grad=True)
    act = th.randn(16, ACT_DIM, requires_grad=True)
    for deterministic in (True, False):
        obs.grad, act.grad = None, None
        next_obs, reward, term, _ = model.step(obs, act, deterministic=deterministic)
        assert next_obs.shape == (16, OBS_DIM) and reward.shape == (16,) and term.shape == (16,)
        (next_obs.sum() + reward.sum() + term.sum()).backward()
        assert obs.grad is not None and act.grad is not None
        assert obs.grad.abs().sum() > 0 and act.grad.abs().sum() > 0
        assert all(p.grad is None for p in model.parameters())


def test_deterministic_step_is_repeatable_and_stochastic_is_not() -> None:
    th.manual_seed(0)
    model = _small()
    data = _synthetic(500, nonlinear=True)
    model.fit(data["obs"], data["act"], data["next_obs"], data["rew"], max_epochs=2)
    obs, act = th.randn(32, OBS_DIM), th.randn(32, ACT_DIM)
    with th.no_grad():
        a = model.step(obs, act, deterministic=True)
        b = model.step(obs, act, deterministic=True)
        c = model.step(obs, act, deterministic=False)
    for x, y in zip(a, b, strict=True):
        th.testing.assert_close(x, y, rtol=0, atol=0)
    assert not th.allclose(a[0], c[0])
    # deterministic = mean over the elites' means (denormalised)
    mean, _, _ = model(obs, act)
    expected = mean[model.elites].mean(0) * model.target_std + model.target_mean
    th.testing.assert_close(a[0], obs + expected[:, :OBS_DIM])
    th.testing.assert_close(a[1], expected[:, OBS_DIM])
    assert (a[2] == 0).all()  # no termination head


def test_stochastic_step_uses_elite_members_only() -> None:
    th.manual_seed(0)
    model = _small()
    with th.no_grad():
        model.min_logvar.fill_(-30.0)
        model.max_logvar.fill_(-29.0)  # ~zero noise: samples equal one member's mean
        model.elites.copy_(th.tensor([0, 2, 3]))
        obs, act = th.randn(1, OBS_DIM).expand(200, -1), th.randn(1, ACT_DIM).expand(200, -1)
        next_obs, _, _, _ = model.step(obs, act, deterministic=False)
        mean, _, _ = model(obs[:1], act[:1])
        member_next = obs[:1] + (mean[:, 0] * model.target_std + model.target_mean)[:, :OBS_DIM]  # [E, obs_dim]
    dist = (next_obs[:, None] - member_next[None]).norm(dim=-1)  # [200, E]
    chosen = dist.argmin(dim=1)
    assert set(chosen.tolist()) == {0, 2, 3}
    assert dist.min(dim=1).values.max() < 1e-4


def test_state_dict_round_trip_weights_only() -> None:
    th.manual_seed(0)
    data = _synthetic(1000, nonlinear=True)
    data = {k: v * 3 + 1 if k != "done" else v for k, v in data.items()}  # non-trivial normalisation
    model = EnsembleDynamics(OBS_DIM, ACT_DIM, n_members=5, n_elites=2, hidden_dim=32, n_layers=2, learn_termination=True)
    model.fit(data["obs"], data["act"], data["next_obs"], data["rew"], data["done"], max_epochs=3)
    with th.no_grad():
        model.elites.copy_(th.tensor([1, 4]))  # not the default arange
    buffer = io.BytesIO()
    th.save(model.state_dict(), buffer)
    buffer.seek(0)
    state = th.load(buffer, weights_only=True)
    for key in ("obs_mean", "obs_std", "act_mean", "act_std", "target_mean", "target_std", "elites"):
        assert key in state
    clone = EnsembleDynamics(OBS_DIM, ACT_DIM, n_members=5, n_elites=2, hidden_dim=32, n_layers=2, learn_termination=True)
    clone.load_state_dict(state)
    assert clone.elites.tolist() == [1, 4]
    obs, act = data["obs"][:20], data["act"][:20]
    with th.no_grad():
        for x, y in zip(model.step(obs, act), clone.step(obs, act), strict=True):
            th.testing.assert_close(x, y, rtol=0, atol=0)


def test_termination_head_learns_rule() -> None:
    data = _synthetic(3000, nonlinear=False)
    assert 0.1 < float(data["done"].mean()) < 0.9
    th.manual_seed(0)
    model = _small(learn_termination=True)
    metrics = model.fit(
        data["obs"], data["act"], data["next_obs"], data["rew"], data["done"], max_epochs=10, learning_rate=1e-2
    )
    assert metrics["holdout_term_acc"] > 0.93, metrics
    # fresh points: predicted probability agrees with the rule
    test = _synthetic(1000, nonlinear=False, seed=1)
    with th.no_grad():
        _, _, prob, _ = model.step(test["obs"], test["act"])
    accuracy = float(((prob > 0.5).float() == test["done"]).float().mean())
    assert accuracy > 0.93, accuracy


def test_learn_termination_needs_dones() -> None:
    model = _small(learn_termination=True)
    data = _synthetic(100, nonlinear=False)
    with pytest.raises(ValueError, match="dones"):
        model.fit(data["obs"], data["act"], data["next_obs"], data["rew"], max_epochs=1)


def test_weight_decays_validation() -> None:
    model = EnsembleDynamics(3, 1)
    assert model.weight_decays == (2.5e-5, 5e-5, 7.5e-5, 7.5e-5, 1e-4)
    with pytest.raises(ValueError):
        EnsembleDynamics(3, 1, n_layers=2, weight_decays=[1e-4])
    with pytest.raises(ValueError):
        EnsembleDynamics(3, 1, n_members=3, n_elites=4)


def test_logger_records_dynamics_values() -> None:
    from stable_baselines3.common.logger import Logger

    class Capture(Logger):
        def __init__(self) -> None:
            super().__init__(folder=None, output_formats=[])
            self.dumps: list[dict[str, float]] = []

        def dump(self, step: int = 0) -> None:
            self.dumps.append(dict(self.name_to_value))
            super().dump(step)

    logger = Capture()
    th.manual_seed(0)
    data = _synthetic(500, nonlinear=False)
    _small().fit(data["obs"], data["act"], data["next_obs"], data["rew"], max_epochs=2, logger=logger)
    assert len(logger.dumps) == 3  # two epochs + the final summary
    assert "dynamics/holdout_mse" in logger.dumps[0] and "dynamics/no_change_mse" in logger.dumps[0]
    assert "dynamics/fit_time" in logger.dumps[-1]
