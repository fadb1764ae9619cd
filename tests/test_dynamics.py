"""EnsembleDynamics and DynamicsTrainer: forward, fit and the trainer's pieces, differentiable step, save/load, termination."""

from __future__ import annotations

import io
import math
import time
from collections.abc import Iterator

import numpy as np
import pytest
import torch as th
import torch.nn.functional as F

from sb3_pola.common.dynamics import EnsembleDynamics
from sb3_pola.common.dynamics_data import BootstrapBatches, Transitions, holdout_split, split_statistics
from sb3_pola.common.dynamics_trainer import DynamicsTrainer, EarlyStopping, holdout_scores, select_elites
from sb3_pola.common.torch_layers import VectorizedLinear

OBS_DIM, ACT_DIM = 5, 2


def fit(model: EnsembleDynamics, *data, **options) -> dict[str, float]:
    """One fit of ``model`` by a fresh trainer with ``options``."""
    return DynamicsTrainer(model, **options).fit(*data)


@pytest.fixture(autouse=True)
def _one_thread() -> Iterator[None]:
    """One torch thread per test (pytest runs with -n 2): small matmuls gain nothing from more, and
    oversubscribed OpenMP threads slow down badly on a busy machine. Restored afterwards."""
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
    start = time.perf_counter()
    metrics = fit(model, data["obs"], data["act"], data["next_obs"], data["rew"], max_epochs=40, learning_rate=1e-2)
    elapsed = time.perf_counter() - start
    assert metrics["holdout_mse"] < 0.2 * metrics["no_change_mse"], metrics
    assert metrics["holdout_reward_mse"] < 0.2 * float(data["rew"].var()), metrics
    assert 1 <= metrics["epochs"] <= 40 and metrics["steps"] >= metrics["epochs"]
    assert 0 < metrics["fit_time"] <= elapsed  # the fit's own clock, inside the call
    assert model.elites.dtype == th.long and model.elites.shape == (3,)
    assert len(set(model.elites.tolist())) == 3
    # the normalisation statistics come from the data
    assert not th.allclose(model.target_std, th.ones_like(model.target_std))


def test_fit_accepts_numpy_and_respects_max_steps() -> None:
    data = _synthetic(600, nonlinear=False)
    th.manual_seed(0)
    model = _small()
    np_data = {k: v.numpy().astype(np.float64) for k, v in data.items()}
    metrics = fit(model, np_data["obs"], np_data["act"], np_data["next_obs"], np_data["rew"], max_steps=7, batch_size=64)
    assert metrics["steps"] == 7


def test_fit_is_reproducible_with_seed() -> None:
    data = _synthetic(800, nonlinear=True)
    states = []
    for _ in range(2):
        th.manual_seed(123)
        model = _small()
        fit(model, data["obs"], data["act"], data["next_obs"], data["rew"], max_epochs=3, batch_size=128)
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
        stats = split_statistics(obs, act, next_obs, rew, rows, chunk_size=chunk_size)
        in_mean, in_std, t_mean, t_std = stats.input_mean, stats.input_std, stats.target_mean, stats.target_std
        assert all(t.dtype == th.float32 for t in (in_mean, in_std, t_mean, t_std))
        th.testing.assert_close(in_mean, x.mean(0).float())
        th.testing.assert_close(t_mean, y.mean(0).float())
        expected_in_std = x.std(0).float()
        expected_in_std[1] = 1.0
        th.testing.assert_close(in_std, expected_in_std)
        th.testing.assert_close(t_std, y.std(0).float())
    # one row: no spread to measure
    stats = split_statistics(obs, act, next_obs, rew, rows[:1])
    assert (stats.input_std == 1).all() and (stats.target_std == 1).all()


def test_fit_leaves_caller_tensors_untouched() -> None:
    data = _synthetic(700, nonlinear=True)
    data["rew"] = data["rew"].reshape(-1, 1)  # [N, 1] views, as the replay buffer passes them
    data["done"] = data["done"].reshape(-1, 1)
    before = {k: v.clone() for k, v in data.items()}
    th.manual_seed(0)
    model = _small(learn_termination=True)
    fit(model, data["obs"], data["act"], data["next_obs"], data["rew"], data["done"], max_epochs=2, batch_size=64)
    for key, value in data.items():
        assert th.equal(value, before[key]), key
    # the statistics are those of the training split: close to those of the whole data set
    th.testing.assert_close(model.obs_mean, data["obs"].mean(0), atol=0.1, rtol=0)
    th.testing.assert_close(model.target_std[-1], data["rew"].std(), atol=0.1, rtol=0.1)


def test_early_stopping_and_epoch_cap() -> None:
    data = _synthetic(1500, nonlinear=False)
    th.manual_seed(0)
    model = _small()
    # 1200 training samples / 64: 19 steps per pass, capped at 5 per epoch
    metrics = fit(
        model, data["obs"], data["act"], data["next_obs"], data["rew"], batch_size=64, max_epochs=3, max_epoch_steps=5
    )
    assert metrics["steps"] == 15 and metrics["epochs"] == 3
    # patience=1 stops at the first epoch without a >1% improvement of any member: before a longer patience does,
    # on the same seed, and far before the cap; every epoch is max_epoch_steps steps
    epochs = {}
    for patience in (1, 5):
        th.manual_seed(0)
        model = _small()
        metrics = fit(
            model,
            data["obs"],
            data["act"],
            data["next_obs"],
            data["rew"],
            patience=patience,
            max_epochs=300,
            max_epoch_steps=2,
            learning_rate=1e-2,
        )
        assert metrics["steps"] == 2 * metrics["epochs"]
        epochs[patience] = metrics["epochs"]
    assert 1 < epochs[1] < epochs[5] < 300, epochs


def test_step_differentiable_after_freeze() -> None:
    th.manual_seed(0)
    model = _small(learn_termination=True)
    data = _synthetic(500, nonlinear=True)
    fit(model, data["obs"], data["act"], data["next_obs"], data["rew"], data["done"], max_epochs=2)
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
    fit(model, data["obs"], data["act"], data["next_obs"], data["rew"], max_epochs=2)
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
    fit(model, data["obs"], data["act"], data["next_obs"], data["rew"], data["done"], max_epochs=3)
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
    metrics = fit(
        model, data["obs"], data["act"], data["next_obs"], data["rew"], data["done"], max_epochs=10, learning_rate=1e-2
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
        fit(model, data["obs"], data["act"], data["next_obs"], data["rew"], max_epochs=1)


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
    fit(_small(), data["obs"], data["act"], data["next_obs"], data["rew"], max_epochs=2, logger=logger)
    assert len(logger.dumps) == 3  # two epochs + the final summary
    assert "dynamics/holdout_mse" in logger.dumps[0] and "dynamics/no_change_mse" in logger.dumps[0]
    assert "dynamics/fit_time" in logger.dumps[-1]


# ---------------------------------------------------------------- the trainer's pieces
def test_holdout_split_is_one_randperm_draw() -> None:
    th.manual_seed(3)
    split = holdout_split(1000, holdout_ratio=0.2, max_holdout=1000)
    th.manual_seed(3)
    perm = th.randperm(1000, dtype=th.int32)
    assert split.train.dtype == th.int32 and split.holdout.dtype == th.long
    assert th.equal(split.holdout, perm[:200].long()) and th.equal(split.train, perm[200:])
    assert sorted(th.cat((split.train.long(), split.holdout)).tolist()) == list(range(1000))  # disjoint, complete
    # the cap, then no room for a holdout: the first training rows stand in for it
    assert holdout_split(1000, holdout_ratio=0.5, max_holdout=100).holdout.shape == (100,)
    small = holdout_split(4, holdout_ratio=0.2, max_holdout=3)
    assert small.train.shape == (4,) and th.equal(small.holdout, small.train[:3].long())
    with pytest.raises(ValueError, match="not enough transitions"):
        holdout_split(1, holdout_ratio=1.0, max_holdout=10)


def test_bootstrap_batches_walk_each_members_resample_once_per_pass() -> None:
    th.manual_seed(0)
    train_rows = th.randperm(200, dtype=th.int32)[:50] + 1000  # rows of the data set, not positions
    batches = BootstrapBatches(train_rows, n_members=3, batch_size=16)
    assert batches.steps_per_pass == 4 and batches.bootstrap.shape == (3, 50)
    assert int(batches.bootstrap.min()) >= 0 and int(batches.bootstrap.max()) < 50
    assert any(len(set(row.tolist())) < 50 for row in batches.bootstrap)  # drawn with replacement
    resampled = train_rows[batches.bootstrap.long()].long()  # [3, 50] every member's resample as rows
    walks = []
    for seed in (10, 11):  # two passes, each a fresh permutation of the same resample
        th.manual_seed(seed)
        rows = [batches.next_rows() for _ in range(batches.steps_per_pass)]
        assert [r.shape for r in rows] == [(3, 16)] * 3 + [(3, 2)]
        walked = th.cat(rows, dim=1)  # [3, 50]
        th.manual_seed(seed)
        perm = th.randperm(50, dtype=th.int32).long()  # the pass's one draw, shared by the members
        assert th.equal(walked, resampled[:, perm])
        walks.append(walked)
    assert not th.equal(walks[0], walks[1])


def test_early_stopping_keeps_each_members_best_weights() -> None:
    th.manual_seed(0)
    model = _small()  # 4 members
    first = [p.detach().clone() for p in EarlyStopping(model, patience=2).member_params]
    stopping = EarlyStopping(model, patience=2)
    assert not stopping.update(th.full((4,), float("inf"))).any()  # no improvement on inf
    assert stopping.update(th.ones(4)).all() and stopping.epochs_since_improvement == 0
    with th.no_grad():
        for p in stopping.member_params:
            p.add_(1.0)  # every member moves
    improved = stopping.update(th.tensor([0.995, 0.9, 1.0, 2.0]))  # only member 1 improves by more than 1%
    assert improved.tolist() == [False, True, False, False]
    assert stopping.best.tolist() == pytest.approx([1.0, 0.9, 1.0, 1.0])
    assert stopping.epochs_since_improvement == 0 and not stopping.should_stop
    moved = [p.detach().clone() for p in stopping.member_params]
    with th.no_grad():
        for p in stopping.member_params:
            p.add_(1.0)
    stopping.update(th.tensor([0.995, 0.895, 0.991, 0.991]))
    assert stopping.epochs_since_improvement == 1 and not stopping.should_stop
    stopping.update(th.ones(4))
    assert stopping.epochs_since_improvement == 2 and stopping.should_stop
    stopping.restore_best()
    for p, old, new in zip(stopping.member_params, first, moved, strict=True):
        assert th.equal(p[1], new[1])  # member 1: the weights of its best epoch
        for member in (0, 2, 3):  # the others: the weights they had at their best (first) epoch
            assert th.equal(p[member], old[member])


def test_select_elites_takes_the_lowest_scores_in_index_order() -> None:
    elites = select_elites(th.tensor([0.3, 0.1, 0.5, 0.2, 0.4]), 3)
    assert elites.dtype == th.long and elites.tolist() == [0, 1, 3]
    assert select_elites(th.tensor([2.0, 1.0]), 1).tolist() == [1]


def test_holdout_scores_per_member() -> None:
    th.manual_seed(0)
    model = _small(learn_termination=True)
    data = _synthetic(300, nonlinear=True)
    transitions = Transitions.from_arrays(model, data["obs"], data["act"], data["next_obs"], data["rew"], data["done"])
    rows = th.arange(300)
    stats = split_statistics(transitions.observations, transitions.actions, transitions.next_observations,
                             transitions.rewards, rows)  # fmt: skip
    model.set_normalization(stats)
    assert not th.allclose(model.target_std, th.ones_like(model.target_std))
    x, y = transitions.standardized(rows, stats)
    th.testing.assert_close(x, model.normalize_inputs(data["obs"], data["act"]))
    done = transitions.done_rows(rows)
    assert done is not None
    mse, score, raw_state_mse = holdout_scores(model, x, y, done)
    with th.no_grad():
        mean, _, logit = model(data["obs"], data["act"])  # [E, H, D], [E, H]
    assert logit is not None
    raw_err = mean * model.target_std + model.target_mean - th.cat((data["next_obs"] - data["obs"], data["rew"][:, None]), -1)
    p = th.sigmoid(logit)
    bce = -(done * th.log(p) + (1 - done) * th.log(1 - p)).mean(dim=1)
    for m in range(model.n_members):
        th.testing.assert_close(mse[m], ((mean[m] - y) ** 2).mean())
        th.testing.assert_close(raw_state_mse[m], (raw_err[m, :, :OBS_DIM] ** 2).mean(), rtol=1e-4, atol=1e-6)
        th.testing.assert_close(score[m], mse[m] + bce[m], rtol=1e-4, atol=1e-6)
    _, score_without_head, _ = holdout_scores(model, x, y, None)
    assert th.equal(score_without_head, mse)


def test_transitions_use_the_callers_float32_tensors() -> None:
    model = _small()
    data = _synthetic(50, nonlinear=False)
    transitions = Transitions.from_arrays(model, data["obs"], data["act"], data["next_obs"], data["rew"], data["done"])
    assert transitions.observations.data_ptr() == data["obs"].data_ptr()  # no copy
    assert transitions.rewards.shape == (50, 1) and transitions.dones is None  # no head: dones dropped
    assert transitions.done_rows(th.arange(3)) is None and len(transitions) == 50
    as_numpy = Transitions.from_arrays(model, *(data[k].numpy().astype(np.float64) for k in ("obs", "act", "next_obs", "rew")))
    assert as_numpy.observations.dtype == th.float32
    th.testing.assert_close(as_numpy.next_observations, data["next_obs"])


def test_train_epoch_takes_its_steps() -> None:
    th.manual_seed(0)
    model = _small()
    data = _synthetic(400, nonlinear=True)
    transitions = Transitions.from_arrays(model, data["obs"], data["act"], data["next_obs"], data["rew"])
    split = holdout_split(len(transitions), 0.2, 1000)
    stats = split_statistics(data["obs"], data["act"], data["next_obs"], transitions.rewards, split.train)
    trainer = DynamicsTrainer(model, batch_size=32)
    before = [p.detach().clone() for p in model.parameters()]
    loss = trainer.train_epoch(transitions, stats, BootstrapBatches(split.train, model.n_members, 32), n_steps=3)
    assert math.isfinite(loss)
    assert all(int(state["step"]) == 3 for state in trainer.optimizer.state.values())
    assert all(not th.equal(p, b) for p, b in zip(model.parameters(), before, strict=True))
    assert trainer.train_epoch(transitions, stats, BootstrapBatches(split.train, model.n_members, 32), n_steps=0) == 0.0


def test_fit_elites_are_the_best_final_holdout_scores() -> None:
    data = _synthetic(600, nonlinear=True)
    model = EnsembleDynamics(OBS_DIM, ACT_DIM, n_members=6, n_elites=2, hidden_dim=32, n_layers=2)
    th.manual_seed(5)
    metrics = DynamicsTrainer(model, max_epochs=4, batch_size=64).fit(data["obs"], data["act"], data["next_obs"], data["rew"])
    th.manual_seed(5)
    split = holdout_split(600, 0.2, 1000)  # the fit's first draw: the same split
    transitions = Transitions.from_arrays(model, data["obs"], data["act"], data["next_obs"], data["rew"])
    stats = split_statistics(data["obs"], data["act"], data["next_obs"], transitions.rewards, split.train)
    th.testing.assert_close(stats.target_std, model.target_std, rtol=0, atol=0)
    mse, score, _ = holdout_scores(model, *transitions.standardized(split.holdout, stats), None)
    assert len(set(score.tolist())) == 6  # distinct scores: the elites are unambiguous
    assert model.elites.tolist() == th.argsort(score)[:2].sort().values.tolist()
    assert metrics["holdout_norm_mse"] == pytest.approx(float(mse[model.elites].mean()))
    assert not model.training and all(p.requires_grad for p in model.parameters())
