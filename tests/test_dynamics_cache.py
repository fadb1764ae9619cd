"""The fitted dynamics model is kept and reused, sized to the data, and reported quietly (issue #25)."""

from __future__ import annotations

import hashlib
import os
import pathlib

import pytest
import torch as th
from helpers import light_kwargs
from stable_baselines3.common.logger import Logger, configure

from sb3_pola.common.datasets import make_env
from sb3_pola.common.dynamics_cache import dynamics_cache_dir, dynamics_entries
from sb3_pola.common.dynamics_trainer import AUTO_PASSES, MIN_AUTO_STEPS, DynamicsTrainer, auto_max_steps
from sb3_pola.pola import POLA

FIT = {"max_epochs": 3}


def digest(module: th.nn.Module) -> str:
    h = hashlib.sha256()
    for key, value in sorted(module.state_dict().items()):
        h.update(key.encode() + value.detach().cpu().contiguous().view(-1).view(th.uint8).numpy().tobytes())
    return h.hexdigest()


def count_fits(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """A list that grows by one at every DynamicsTrainer.fit."""
    calls: list[int] = []
    fit = DynamicsTrainer.fit

    def counted(self, *args, **kwargs):
        calls.append(1)
        return fit(self, *args, **kwargs)

    monkeypatch.setattr(DynamicsTrainer, "fit", counted)
    return calls


def test_second_learn_skips_the_fit_and_trains_identically(pendulum_path: str, monkeypatch, capsys) -> None:
    calls = count_fits(monkeypatch)
    first = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(dynamics_fit_kwargs=FIT, verbose=1)).learn(30)
    assert calls == [1] and "cached" not in first.dynamics_fit_info
    # in the user's cache folder ($SB3_POLA_CACHE_DIR, a temporary one in the tests)
    assert len(dynamics_entries()) == 1 and dynamics_cache_dir() == pathlib.Path(os.environ["SB3_POLA_CACHE_DIR"]) / "dynamics"
    capsys.readouterr()
    second = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(dynamics_fit_kwargs=FIT, verbose=1)).learn(30)
    assert calls == [1], "the second learn fitted again"
    assert second.dynamics_fit_info["cached"] == 1.0
    assert "dynamics model loaded from the cache" in capsys.readouterr().out
    # the same model, and the same training after it: the random state the fit left is restored
    assert digest(second.policy.dynamics) == digest(first.policy.dynamics)
    assert digest(second.policy) == digest(first.policy)
    # without the cache: a fit, the same result, nothing more kept
    third = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(dynamics_fit_kwargs=FIT, dynamics_cache=False)).learn(30)
    assert calls == [1, 1] and digest(third.policy) == digest(first.policy)
    assert len(dynamics_entries()) == 1


@pytest.mark.parametrize(
    "change",
    [
        {"seed": 1},
        {"dynamics_fit_kwargs": {"max_epochs": 2}},
        {"dynamics_kwargs": {"n_members": 2, "n_elites": 1, "hidden_dim": 16, "n_layers": 2}},
    ],
)
def test_another_seed_or_configuration_fits_again(pendulum_path: str, change: dict, monkeypatch) -> None:
    calls = count_fits(monkeypatch)
    POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(dynamics_fit_kwargs=FIT)).learn(1)
    POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(**{"dynamics_fit_kwargs": FIT, **change})).learn(1)
    assert calls == [1, 1] and len(dynamics_entries()) == 2


def test_fit_budget_sized_to_the_data(pendulum_path: str, monkeypatch) -> None:
    """No budget given: ``auto_max_steps`` of the data; a budget given (the main job's, the grid's) is kept as it is."""
    seen: list[dict] = []
    init = DynamicsTrainer.__init__

    def spy(self, model, **kwargs):
        seen.append(kwargs)
        init(self, model, **kwargs)

    monkeypatch.setattr(DynamicsTrainer, "__init__", spy)
    POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(dynamics_fit_kwargs={})).learn(1)
    POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(dynamics_fit_kwargs={"max_epochs": 20})).learn(1)
    assert seen[0]["max_steps"] == auto_max_steps(600) == MIN_AUTO_STEPS
    assert seen[1]["max_epochs"] == 20 and "max_steps" not in seen[1]
    assert auto_max_steps(30_000) == AUTO_PASSES * 114  # the shipped pendulum data: 29,000 training rows, batch 256
    assert auto_max_steps(1_000_000) == AUTO_PASSES * 3903


def test_verbose_1_fit_prints_no_table_and_short_learn_logs_train_stats(pendulum_path: str, capsys) -> None:
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(dynamics_fit_kwargs=FIT, verbose=1))
    model.learn(7, log_interval=1000)
    out = capsys.readouterr().out
    assert "| dynamics/" not in out  # the per-epoch tables: verbose=2 only
    assert out.count("dynamics fit: 3 epochs") == 1  # the summary line
    assert "| train/" in out and "critic_loss" in out  # a learn shorter than log_interval dumps at its end
    verbose2 = POLA(
        "MlpPolicy", dataset=pendulum_path, **light_kwargs(dynamics_fit_kwargs=FIT, dynamics_cache=False, verbose=2)
    )
    verbose2.learn(1)
    assert capsys.readouterr().out.count("| dynamics/") == 3 + 1  # a table per epoch, and the fit's


def test_fit_values_still_reach_the_other_log_formats(pendulum_path: str, tmp_path: pathlib.Path) -> None:
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(dynamics_fit_kwargs=FIT))
    logger: Logger = configure(str(tmp_path), ["csv"])
    model.set_logger(logger)
    model.learn(2)
    header = (tmp_path / "progress.csv").read_text().splitlines()[0]
    assert "dynamics/holdout_norm_mse" in header and "train/critic_loss" in header


def test_make_env_is_monitor_wrapped(tiny_dataset: str) -> None:
    from stable_baselines3.common.monitor import Monitor

    env = make_env("invertedpendulum/medium-v0")
    assert isinstance(env, Monitor)
    assert not isinstance(make_env("invertedpendulum/medium-v0", monitor=False), Monitor)


def test_progress_bars_write_nothing_without_a_terminal(pendulum_path: str, capsys) -> None:
    """stderr is not a terminal under pytest: neither the fit's bar nor the training bar writes (no cursor codes)."""
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(dynamics_fit_kwargs=FIT, verbose=1))
    model.learn(5, progress_bar=True)
    err = capsys.readouterr().err
    assert "\r" not in err and "\x1b[" not in err, repr(err[:200])


def test_unseeded_models_reuse_any_fit_of_the_data(pendulum_path: str, monkeypatch) -> None:
    """seed=None (torch starts each process from another random state): the fit is reused all the same."""
    calls = count_fits(monkeypatch)
    kwargs = light_kwargs(dynamics_fit_kwargs=FIT, seed=None)
    first = POLA("MlpPolicy", dataset=pendulum_path, **kwargs)
    first.learn(1)
    th.manual_seed(1234)  # as another process would start
    second = POLA("MlpPolicy", dataset=pendulum_path, **kwargs)
    second.learn(1)
    assert calls == [1] and second.dynamics_fit_info["cached"] == 1.0
    assert digest(second.policy.dynamics) == digest(first.policy.dynamics)
