"""POLA's arguments: the values each may take, their checks (issue #25) and the paper's form."""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.type_aliases import Schedule

from sb3_pola.common.diffusion import BETA_SCHEDULES, PREDICTION_TYPES
from sb3_pola.common.dynamics import check_dynamics_kwargs
from sb3_pola.common.dynamics_trainer import check_fit_kwargs
from sb3_pola.common.errors import HyperparameterError
from sb3_pola.common.validation import check_choice, check_float, check_float_or_schedule, check_int

LOOKAHEAD_NORMALIZATIONS = ("first", "weights")
LOOKAHEAD_TARGETS = ("q", "value_expansion")
LOOKAHEAD_TRUST_RULES = ("value", "bellman")
LOOKAHEAD_ACTIONS = ("actor", "ema")
ETA_GATES = (None, "critic_maturity")
GOAL_SWITCHES = (None, "terminal", "relabel")
CRITIC_DIVERSITY_INPUTS = ("actions", "states_and_actions")
# the "auto" values of the options for dense rewards (#23 fortieth pass): on where the data have no desired_goal
DENSE_REWARD_OPTIONS: dict[str, float] = {"q_term_confidence": 1.0, "bc_top_fraction": 0.1}
# the paper's form (eq. 3/4 as written, Diffusion-QL's divisor, no ensemble-similarity term, the actor's gradient
# through the model, the DDPM noise target of eq. 6, Diffusion-QL's learning rate 3e-4, the actor on the state's
# pairwise products of section V, with the critics' Mish): POLA(..., **PAPER_FORM);
# the defaults depart from it (docstring)
PAPER_FORM: dict[str, Any] = {
    "eta": 1.0,
    "lookahead_weight": 1.0,
    "lookahead_normalization": "first",
    "q_scale_floor": None,
    "critic_diversity": 0.0,
    "backprop_through_model": True,
    "prediction_type": "epsilon",
    "learning_rate": 3e-4,
    "critic_layer_norm": False,
    "eta_gate": None,
    "target_q_floor": None,
    "critic_init_value": None,
    "lookahead_fixed_goal": False,
    "goal_switches": None,
    "hindsight_goals": False,
    "use_state_products": True,
    "q_term_confidence": None,
    "bc_top_fraction": None,
}


# ------------------------------------------------------------------ argument checks (issue #25)
def check_auto_float(name: str, value: Any, **bounds: Any) -> None:
    """An option of ``DENSE_REWARD_OPTIONS``: ``"auto"``, ``None`` or a number within ``bounds``."""
    if isinstance(value, str):
        check_choice(name, value, ("auto",))
    else:
        check_float(name, value, optional=True, **bounds)


def check_pola_arguments(
    *,
    n_critics: int,
    top_k: int,
    rollout_length: int,
    eta: float | Schedule,
    gamma: float,
    lookahead_normalization: str,
    lookahead_weight: float,
    q_scale_floor: float | str | None,
    target_q_floor: float | str | None,
    reward_scale: float,
    critic_init_value: float | str | None,
    goal_switches: str | None,
    critic_diversity: float,
    critic_diversity_inputs: str,
    lookahead_uncertainty_penalty: float,
    lookahead_uncertainty_cutoff: float | None,
    lookahead_trust_margin: float | None,
    lookahead_trust_rule: str,
    lcb_coef: float | None,
    critic_bc_coef: float,
    q_term_confidence: float | str | None,
    critic_layer_norm: bool,
    eta_gate: str | None,
    eta_gate_fraction: float,
    lookahead_fixed_goal: bool,
    lookahead_target: str,
    lookahead_actions: str,
    critic_learning_rate: float | Schedule | None,
    bc_learning_rate: float | Schedule | None,
    bc_weight_temp: float | None,
    bc_max_weight: float,
    bc_top_fraction: float | str | None,
    backprop_through_model: bool,
    model_td_weight: float,
    model_conservatism: float,
    n_diffusion_steps: int,
    beta_schedule: str,
    prediction_type: str,
    max_grad_norm: float | None,
    ema_decay: float,
    ema_update_freq: int,
    ema_start: int,
    dynamics_kwargs: dict[str, Any] | None,
    dynamics_fit_kwargs: dict[str, Any] | None,
) -> None:
    """Check POLA's own arguments before anything is loaded or built (the base class checks ``learning_rate``,
    ``batch_size``, ``tau``, ``gamma``); each message names the public argument and its range.

    :raises ~sb3_pola.common.errors.HyperparameterError: (a ``ValueError``) an argument out of its range
    """
    n_critics = check_int("n_critics", n_critics, low=1)  # type: ignore[assignment]
    check_int("top_k", top_k, low=1, high=n_critics)
    check_int("rollout_length", rollout_length, low=0)
    check_float_or_schedule("eta", eta, low=0.0)
    check_choice("lookahead_normalization", lookahead_normalization, LOOKAHEAD_NORMALIZATIONS)
    if q_scale_floor is None or isinstance(q_scale_floor, str):
        check_choice("q_scale_floor", q_scale_floor, (None, "auto"))
    else:
        check_float("q_scale_floor", q_scale_floor, low=0.0)
    if q_scale_floor == "auto" and isinstance(gamma, float | int) and gamma == 1:
        raise HyperparameterError(
            "q_scale_floor='auto' needs gamma < 1 (the data's value scale is mean |r| / (1 - gamma)); "
            "give q_scale_floor a number or None"
        )
    if target_q_floor is None or isinstance(target_q_floor, str):
        check_choice("target_q_floor", target_q_floor, (None, "auto", "returns"))
    else:
        check_float("target_q_floor", target_q_floor)
    check_float("reward_scale", reward_scale, low=0.0, low_open=True)
    if critic_init_value is None or isinstance(critic_init_value, str):
        check_choice("critic_init_value", critic_init_value, (None, "returns"))
    else:
        check_float("critic_init_value", critic_init_value)
    check_choice("goal_switches", goal_switches, GOAL_SWITCHES)
    check_float("critic_diversity", critic_diversity, low=0.0)
    check_choice("critic_diversity_inputs", critic_diversity_inputs, CRITIC_DIVERSITY_INPUTS)
    if critic_diversity > 0 and n_critics < 2:
        raise HyperparameterError(f"critic_diversity > 0 needs n_critics >= 2, got n_critics={n_critics}")
    check_float("lookahead_uncertainty_penalty", lookahead_uncertainty_penalty, low=0.0)
    check_float("lookahead_uncertainty_cutoff", lookahead_uncertainty_cutoff, low=0.0, low_open=True, optional=True)
    check_float("lookahead_trust_margin", lookahead_trust_margin, optional=True)
    check_choice("lookahead_trust_rule", lookahead_trust_rule, LOOKAHEAD_TRUST_RULES)
    check_float("lcb_coef", lcb_coef, low=0.0, optional=True)
    if lcb_coef is not None and n_critics < 2:
        raise HyperparameterError(f"lcb_coef needs n_critics >= 2, got n_critics={n_critics}")
    check_float("critic_bc_coef", critic_bc_coef, low=0.0)
    check_auto_float("q_term_confidence", q_term_confidence)  # "auto": on with two or more critics
    if q_term_confidence not in (None, "auto") and n_critics < 2:
        raise HyperparameterError(f"q_term_confidence needs n_critics >= 2, got n_critics={n_critics}")
    check_choice("critic_layer_norm", critic_layer_norm, (False, True))
    check_choice("eta_gate", eta_gate, ETA_GATES)
    check_float("eta_gate_fraction", eta_gate_fraction, low=0.0, low_open=True)
    check_choice("lookahead_fixed_goal", lookahead_fixed_goal, (False, True))
    check_choice("lookahead_target", lookahead_target, LOOKAHEAD_TARGETS)
    check_float("lookahead_weight", lookahead_weight, low=0.0)
    check_choice("lookahead_actions", lookahead_actions, LOOKAHEAD_ACTIONS)
    if critic_learning_rate is not None:
        check_float_or_schedule("critic_learning_rate", critic_learning_rate, low=0.0, low_open=True)
    if bc_learning_rate is not None:
        check_float_or_schedule("bc_learning_rate", bc_learning_rate, low=0.0, low_open=True)
    check_float("bc_weight_temp", bc_weight_temp, low=0.0, optional=True)
    check_float("bc_max_weight", bc_max_weight, low=0.0, low_open=True)
    check_auto_float("bc_top_fraction", bc_top_fraction, low=0.0, high=1.0, low_open=True)
    if lookahead_trust_margin is not None and lookahead_target != "q":
        raise HyperparameterError("lookahead_trust_margin judges Q at the predicted states; it needs lookahead_target='q'")
    if lookahead_actions == "ema" and not backprop_through_model:
        raise HyperparameterError(
            "lookahead_actions='ema' trains the actor through the model only; it needs backprop_through_model=True"
        )
    check_float("model_td_weight", model_td_weight, low=0.0)
    check_float("model_conservatism", model_conservatism, low=0.0)
    check_int("n_diffusion_steps", n_diffusion_steps, low=1)
    check_choice("beta_schedule", beta_schedule, tuple(BETA_SCHEDULES))
    check_choice("prediction_type", prediction_type, PREDICTION_TYPES)
    check_float("max_grad_norm", max_grad_norm, low=0.0, low_open=True, optional=True)
    check_float("ema_decay", ema_decay, low=0.0, high=1.0)
    check_int("ema_update_freq", ema_update_freq, low=1)
    check_int("ema_start", ema_start, low=0)
    check_dynamics_kwargs(dynamics_kwargs or {})
    check_fit_kwargs(dynamics_fit_kwargs or {})
