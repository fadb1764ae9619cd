"""Every constructor argument is checked at construction, before the dataset is loaded, with its public name and
its range (issue #25)."""

from __future__ import annotations

from typing import Any

import pytest

from sb3_pola.common.datasets import DatasetNotFoundError
from sb3_pola.common.dynamics_trainer import DynamicsTrainer
from sb3_pola.common.errors import HyperparameterError
from sb3_pola.common.validation import check_float, check_int
from sb3_pola.pola import POLA

# a dataset that does not exist: a check that runs after the dataset is loaded would raise DatasetNotFoundError
MISSING = "no/such-dataset-v0"

BAD_ARGUMENTS: list[tuple[dict[str, Any], str]] = [
    ({"batch_size": 0}, "batch_size must be an int >= 1, got 0"),
    ({"batch_size": -5}, "batch_size must be an int >= 1"),
    ({"batch_size": 2.5}, "batch_size must be an int"),
    ({"gamma": 1.5}, "gamma must be a number in (0.0, 1.0], got 1.5"),
    ({"gamma": 0.0}, "gamma must be a number in (0.0, 1.0]"),
    ({"gamma": 1.0, "q_scale_floor": "auto"}, "q_scale_floor='auto' needs gamma < 1"),
    ({"tau": 2}, "tau must be a number in (0.0, 1.0], got 2"),
    ({"tau": 0.0}, "tau must be"),
    ({"eta": -1}, "eta must be a number >= 0.0 or a schedule, got -1"),
    ({"eta": lambda progress: -1.0}, "eta must be a number >= 0.0 or a schedule of such numbers"),
    ({"learning_rate": 0.0}, "learning_rate must be a number > 0.0"),
    ({"learning_rate": lambda progress: -1e-3}, "learning_rate must be"),
    ({"n_critics": 0}, "n_critics must be an int >= 1, got 0"),
    ({"top_k": 0}, "top_k must be an int in [1, 10], got 0"),
    ({"n_critics": 4, "top_k": 5}, "top_k must be an int in [1, 4], got 5"),
    ({"rollout_length": -1}, "rollout_length must be an int >= 0"),
    ({"n_diffusion_steps": 0}, "n_diffusion_steps must be an int >= 1, got 0"),
    ({"beta_schedule": "sigmoid"}, "beta_schedule must be one of"),
    ({"prediction_type": "v"}, "prediction_type must be one of"),
    ({"lookahead_normalization": "sum"}, "lookahead_normalization must be one of"),
    ({"q_scale_floor": "max"}, "q_scale_floor must be one of"),
    ({"q_scale_floor": -1.0}, "q_scale_floor must be a number >= 0.0"),
    ({"critic_diversity": -1.0}, "critic_diversity must be a number >= 0.0"),
    ({"n_critics": 1, "top_k": 1}, "critic_diversity > 0 needs n_critics >= 2"),
    ({"critic_diversity_inputs": "states"}, "critic_diversity_inputs must be one of"),
    ({"lookahead_uncertainty_penalty": -0.5}, "lookahead_uncertainty_penalty must be"),
    ({"lookahead_uncertainty_cutoff": 0.0}, "lookahead_uncertainty_cutoff must be None or a number > 0.0"),
    ({"lookahead_trust_margin": 0.1, "lookahead_target": "value_expansion"}, "lookahead_trust_margin judges Q"),
    ({"lookahead_trust_rule": "q"}, "lookahead_trust_rule must be one of"),
    ({"lcb_coef": -1.0}, "lcb_coef must be None or a number >= 0.0"),
    ({"critic_bc_coef": -0.1}, "critic_bc_coef must be a number >= 0.0"),
    ({"q_term_confidence": float("nan")}, "q_term_confidence must be"),
    ({"q_term_confidence": "always"}, "q_term_confidence must be one of 'auto'"),
    (
        {"q_term_confidence": 1.0, "n_critics": 1, "top_k": 1, "critic_diversity": 0.0},
        "q_term_confidence needs n_critics >= 2",
    ),
    ({"critic_layer_norm": "yes"}, "critic_layer_norm must be one of False, True"),
    ({"bc_top_fraction": 0.0}, "bc_top_fraction must be None or a number in"),
    ({"bc_top_fraction": "best"}, "bc_top_fraction must be one of 'auto'"),
    ({"max_grad_norm": 0.0}, "max_grad_norm must be None or a number > 0.0"),
    ({"ema_decay": 1.5}, "ema_decay must be a number in [0.0, 1.0]"),
    ({"ema_update_freq": 0}, "ema_update_freq must be an int >= 1"),
    ({"ema_start": -1}, "ema_start must be an int >= 0"),
    ({"check_finite_freq": -1}, "check_finite_freq must be an int >= 0"),
    ({"dynamics_kwargs": {"n_members": 0}}, "dynamics_kwargs['n_members'] must be an int >= 1"),
    ({"dynamics_kwargs": {"n_members": 3}}, "dynamics_kwargs['n_elites'] must be an int in [1, 3], got 5"),
    ({"dynamics_kwargs": {"hidden": 64}}, "dynamics_kwargs has unknown key(s) 'hidden'"),
    ({"dynamics_kwargs": {"mean_loss": "l1"}}, "dynamics_kwargs['mean_loss'] must be one of"),
    ({"dynamics_fit_kwargs": {"patience": 0}}, "dynamics_fit_kwargs['patience'] must be an int >= 1"),
    ({"dynamics_fit_kwargs": {"max_epochs": 0}}, "dynamics_fit_kwargs['max_epochs'] must be None or an int >= 1"),
    ({"dynamics_fit_kwargs": {"holdout_ratio": 1.0}}, "dynamics_fit_kwargs['holdout_ratio'] must be a number in [0.0, 1.0)"),
    ({"dynamics_fit_kwargs": {"epochs": 3}}, "dynamics_fit_kwargs has unknown key(s) 'epochs'"),
]


@pytest.mark.parametrize(("kwargs", "message"), BAD_ARGUMENTS, ids=[str(sorted(k)) + "-" + m[:20] for k, m in BAD_ARGUMENTS])
def test_bad_argument_raises_naming_it(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(HyperparameterError) as info:
        POLA("MlpPolicy", dataset=MISSING, **kwargs)
    assert isinstance(info.value, ValueError)
    assert str(info.value).startswith(message), str(info.value)


def test_good_arguments_reach_the_dataset() -> None:
    """The defaults, schedules and edge values pass the checks: the dataset lookup is what fails."""
    for kwargs in (
        {},
        {"eta": lambda progress: progress, "gamma": 1.0, "q_scale_floor": None, "tau": 1.0},
        {"n_critics": 1, "top_k": 1, "critic_diversity": 0.0, "rollout_length": 0},
    ):
        with pytest.raises(DatasetNotFoundError):
            POLA("MlpPolicy", dataset=MISSING, **kwargs)


def test_trainer_checks_its_own_arguments() -> None:
    with pytest.raises(HyperparameterError, match=r"^patience must be an int >= 1, got 0"):
        DynamicsTrainer(None, patience=0)  # type: ignore[arg-type]


def test_checkers() -> None:
    assert check_int("n", 3, low=1) == 3 and check_int("n", None, optional=True) is None
    with pytest.raises(HyperparameterError, match=r"^n must be an int >= 1, got True"):
        check_int("n", True, low=1)  # a bool is not an int here
    with pytest.raises(HyperparameterError, match=r"^x must be a number in \[0, 1\), got nan"):
        check_float("x", float("nan"), low=0, high=1, high_open=True)
