"""POLA: Policy Optimization by Looking Ahead (Liu & Hofert), in the Stable-Baselines3 mould."""

from __future__ import annotations

import contextlib
import functools
import os
import pathlib
import warnings
from collections.abc import Callable, Iterator
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, ReplayBufferSamples, Schedule
from stable_baselines3.common.utils import FloatSchedule, update_learning_rate
from torch.nn.utils import clip_grad_norm_

from sb3_pola.common.buffers import OfflineReplayBuffer
from sb3_pola.common.compile import CompiledLoss
from sb3_pola.common.datasets import DatasetError, DatasetLocation, OfflineDataset, make_env, resolve_dataset_path
from sb3_pola.common.dict_obs import key_slice
from sb3_pola.common.diffusion import BETA_SCHEDULES, PREDICTION_TYPES
from sb3_pola.common.dynamics import check_dynamics_kwargs
from sb3_pola.common.dynamics_cache import cache_key, data_fingerprint, fit_or_load
from sb3_pola.common.dynamics_trainer import DynamicsTrainer, auto_max_steps, check_fit_kwargs
from sb3_pola.common.errors import HyperparameterError
from sb3_pola.common.input_gradients import explicit_input_gradients, input_gradient_fn
from sb3_pola.common.offline_algorithm import OfflineAlgorithm
from sb3_pola.common.term_rates import check_term_rate_optimizer, term_rate_step
from sb3_pola.common.termination import TerminationFn, get_termination_fn
from sb3_pola.common.validation import check_choice, check_float, check_float_or_schedule, check_int
from sb3_pola.pola.export import export_policy
from sb3_pola.pola.fast_sampling import sample_chain, sample_no_grad
from sb3_pola.pola.losses import (
    advantage_weights,
    ensemble_similarity,
    lookahead_q_objective,
    lookahead_weights,
    pessimistic_q,
    value_expansion_objective,
    value_lower_bound,
)
from sb3_pola.pola.policies import DiffusionActor, EnsembleCritic, MlpPolicy, POLAPolicy, members_agree

SelfPOLA = TypeVar("SelfPOLA", bound="POLA")


def _lerp_params(params: Any, target_params: Any, tau: float) -> None:
    """Polyak update ``target <- (1 - tau) target + tau param`` of all tensors in one ``_foreach_lerp_`` call."""
    with th.no_grad():
        th._foreach_lerp_(list(target_params), list(params), tau)


LOOKAHEAD_NORMALIZATIONS = ("first", "weights")
LOOKAHEAD_TARGETS = ("q", "value_expansion")
LOOKAHEAD_TRUST_RULES = ("value", "bellman")
LOOKAHEAD_ACTIONS = ("actor", "ema")
ETA_GATES = (None, "critic_maturity")
GOAL_SWITCHES = (None, "terminal", "relabel")
CRITIC_DIVERSITY_INPUTS = ("actions", "states_and_actions")
DEFAULT_LEARNING_RATE = 1e-3  # constant, as SB3: a cosine decay to 0 over a short budget starved the Q term (#23)
GRADIENT_RATIO_FREQ = 100  # gradient steps between two measurements of train/q_bc_grad_ratio
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
}


def _goal_reward(compute_reward: Callable[..., Any], achieved: np.ndarray, desired: np.ndarray) -> np.ndarray:
    """A GoalEnv's ``compute_reward`` over a batch of goals (its ``info`` unused by the mazes' sparse reward)."""
    return np.asarray(compute_reward(achieved, desired, {}), dtype=np.float32)


def _dataset_source(dataset: Any) -> str | None:
    """The folder of a dataset given by id or path, for the dynamics cache's listing (``None`` if unknown)."""
    if not isinstance(dataset, str | os.PathLike):
        return None
    try:
        return str(resolve_dataset_path(dataset))
    except (DatasetError, TypeError):
        return None


# ------------------------------------------------------------------ argument checks (issue #25)
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
    q_term_confidence: float | None,
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
    check_float("q_term_confidence", q_term_confidence, optional=True)
    if q_term_confidence is not None and n_critics < 2:
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


class POLA(OfflineAlgorithm):
    """Policy Optimization by Looking Ahead: model-based offline RL with a diffusion policy.

    Paper: Y. Liu and M. Hofert, "Policy Optimization by Looking Ahead for Model-based Offline
    Reinforcement Learning". Each gradient step (``train``) does, on a batch from the dataset:

    1. critic: TD regression of every member of the ``n_critics`` ensemble on the pessimistic
       target ``r + gamma (1 - done) min_j Q'_j(s', a')``, ``a'`` from the EMA actor (section IV), plus
       ``critic_diversity`` times EDAC's ensemble similarity of the members' action gradients;
    2. actor: ``L_d + eta * L_q`` where ``L_d`` is the DDPM loss on dataset actions (eq. 6) and
       ``L_q`` the look-ahead loss (eq. 3, 4): the mean of the ``top_k`` smallest ensemble
       Q-values at the current state and at ``rollout_length`` states predicted by the dynamics
       model, weighted by ``gamma^i`` (times ``lookahead_weight`` at the predicted states); the actor sees
       ``s_new``, the state with all pairwise
       products (section V);
    3. EMA actor and Polyak target critics.

    The dynamics model (an ensemble of Gaussian MLPs, MOPO-style) is fitted on the dataset with
    holdout early stopping when ``learn`` first starts, then frozen. ``rollout_length=0`` is
    Diffusion-QL with an ensemble critic; ``eta=0`` is behaviour cloning with the diffusion actor.

    Choices the paper leaves open, taken from Diffusion-QL (the code POLA builds on): the Q term
    is divided by the detached mean ``|Q|`` of the current-state term (scale invariance); the
    critic loss sums the members' MSEs; targets use the EMA actor's action; gradients of both
    losses are clipped to ``max_grad_norm``. Look-ahead states that a termination rule (the known
    MuJoCo rule for the env, or the model's learned termination head when the env is unknown)
    marks terminal contribute no Q term, and neither do any states after them.

    Eleven defaults depart from the paper, each chosen by measurements in ``docs/results.md`` (issues #12 and #23):
    ``eta=3.94`` with ``lookahead_weight=1/16`` (the Q weight the paper gives all ``T + 1`` states at ``T = 3`` goes
    to the current state; each predicted state, where the critic never trained and the actor learned to exploit it,
    weighs a sixteenth of the paper's: level with the paper's weights at 10,000 steps, above them over 100,000 on
    halfcheetah/medium-replay; hopper/medium still falls with either),
    ``critic_layer_norm=True`` (LayerNorm critics, as ReBRAC: they bound Q off the data, so the Q term keeps the
    paper's full strength, ``lookahead_normalization="first"`` and no floor, without the actor climbing the critic's
    extrapolation; without them that strength collapsed the locomotion actors within a CPU budget),
    ``critic_diversity=1`` (EDAC's term: without it the ensemble agreed so closely that its minimum was no
    pessimism), ``backprop_through_model=False`` (the actor steered the model into states the critic overvalued),
    ``prediction_type="sample"`` (the actor regresses the clean action: it imitates as well as a plain MSE
    regressor, the noise target did not), a constant learning rate of 1e-3 (a cosine decay to 0 over ``learn``
    halved the steps within a CPU budget, and the Q term's gain with them; it imitated the U-maze better),
    ``target_q_floor="returns"`` (the critic's target floored at the data's return-to-go: within a CPU budget the
    bootstrapped critic sees only a few dozen steps ahead, too few for the pendulum's drift or Hopper's falls),
    ``critic_init_value="returns"`` (the critics' output starts at the data's mean return-to-go: with the floor and Q
    starting at 0, HalfCheetah's critic spent most of the budget climbing to its targets while the actor followed it),
    ``eta_gate="critic_maturity"`` (the Q term is held while the critic's Q at the data is below the data's lowest
    value: with plain targets on sparse mazes that was thousands of steps of noise; with the two ``"returns"``
    defaults Q starts at the data's values, so the gate is open from the first step and only closes should Q
    collapse), ``lookahead_fixed_goal=True`` (on goal-conditioned data the look-ahead keeps the goal: the model
    had learned the collectors' goal switches and moved the goal near it) and ``goal_switches="relabel"`` (those
    switches keep their goal and its reward, so the critic sees what staying at a goal is worth). The dynamics model
    fits with beta-NLL and ``predict(deterministic=True)`` returns the mode of 16 chain samples drawn with the
    observation's own noise (:class:`~sb3_pola.pola.policies.POLAPolicy`). The paper's form is
    ``POLA(..., **PAPER_FORM)``; the shipped InvertedPendulum main job (``make train``) runs the defaults.

    :param policy: policy class or alias (``"MlpPolicy"``)
    :param env: env (or id) for evaluation callbacks; made from the dataset's metadata if ``None``
    :param dataset: Minari dataset id, path to a Minari dataset folder, or ``minari.MinariDataset``
    :param learning_rate: learning rate of actor and critic (Adam), a float or a schedule (default: 1e-3, constant;
        :func:`~sb3_pola.common.schedules.cosine_schedule` gives Diffusion-QL's cosine decay)
    :param batch_size: minibatch size
    :param tau: Polyak coefficient of the target critics
    :param gamma: discount factor, also the weight ``gamma^i`` of the ``i``-th look-ahead term (eq. 3)
    :param n_critics: size ``N`` of the critic ensemble (paper: 10)
    :param top_k: number ``K`` of smallest ensemble Q-values averaged in the policy loss (eq. 4)
    :param rollout_length: look-ahead horizon ``T`` (paper ablates 0, 1, 3, 5; 0 disables the model)
    :param eta: weight of the Q term in the actor loss (``0`` = behaviour cloning): a float, or an SB3
        ``Schedule`` of the remaining progress (1 at the start of ``learn``, 0 at the end), e.g.
        :func:`~sb3_pola.common.schedules.warmup_schedule` for a behaviour-cloning warm-up. Default 3.94
        (``sum_{i<=3} 0.99^i``, the Q weight the paper's ``eta = 1`` gives at ``T = 3`` under ``"first"``), now on the
        current state, the predicted states at ``lookahead_weight``; the paper: 1
    :param lookahead_normalization: ``"first"`` (the paper, eq. 3/4 as written; default): the ``T + 1`` weighted
        Q terms are summed and divided by ``mean |Q|`` of the first, so the Q term's weight grows with
        ``T`` (``sum_i gamma^i``, 3.94 at ``T = 3``); ``"weights"``: also divided by
        ``sum_i gamma^i``, so ``eta`` weighs the Q term the same for every ``T``
    :param lookahead_weight: factor ``lambda`` on eq. 3's terms at the predicted states, whose weights become
        ``lambda gamma^i`` for ``i >= 1`` (before ``lookahead_normalization``): the current state keeps its weight while
        the predicted states, where the critic never trained, pull less. On hopper/medium the actor learns to exploit
        the critic at the predicted states (docs/results.md, eleventh and twelfth passes). Default ``1/16``: with
        ``eta = 3.94`` each predicted state weighs about 0.24 against the current state's 3.94 (it does not stop the
        fall on hopper/medium); ``1``: the paper; ``0``: the states are rolled out but pull nothing. With
        ``lookahead_target="value_expansion"`` it weighs each expansion ``V_h``, ``h >= 1``
    :param q_scale_floor: lower bound of the detached ``mean |Q|`` that divides the Q term. ``None``:
        Diffusion-QL's batch mean alone (the paper; default). ``"auto"``: the dataset's value scale
        ``mean |r| / (1 - gamma)``,
        so while the critic is immature (``|Q|`` far below the returns it will reach) its gradient pulls
        the actor in proportion to how far it has learned, instead of at full strength from the first step.
        A float: that floor
    :param target_q_floor: lower bound of the critic's bootstrapped ``min_j Q_j(s', a')``. ``"auto"``: the lowest
        value any policy can have on rewards no lower than the data's (:func:`value_lower_bound`: ``r_min`` for
        ``r_min >= 0``, ``r_min / (1 - gamma)`` below): with sparse rewards (``r_min = 0``) the minimum over the
        ensemble otherwise drags Q below 0, a value no policy has. ``"returns"``: the whole target
        ``r + gamma min_j Q_j(s', a')`` floored at the data's discounted return-to-go from the transition
        (:meth:`~sb3_pola.common.datasets.OfflineDataset.returns_to_go`; Monte-Carlo augmented targets, MCAC,
        Wilcox et al. 2022): the data's own return from ``(s, a)`` is a value the optimal policy at least reaches, so Q
        at the data starts at the data's values instead of climbing to them one target update at a time, and on sparse
        rewards the value of reaching a goal is there from the first step (default). A float: that floor. ``None``: no
        floor (the paper)
    :param reward_scale: factor on the data's rewards as the critic learns them (as d3rlpy's reward scaler; the
        dynamics model keeps the raw rewards). The Q term is divided by ``mean |Q|``, so the scale only changes how
        fast the critic can fit: Adam moves its weights by about the learning rate a step, so an output of a few
        hundred (HalfCheetah's returns-to-go) takes thousands of steps to reach, while Q's dependence on the action is
        a small part of it. Q, its targets and the floors are in the scaled units. Default ``1``
    :param critic_init_value: where the critics' output starts: their last layer's bias is shifted by this value
        before the first gradient step (members and target critics alike). ``"returns"``: the data's mean discounted
        return-to-go (in the critic's units), so Q starts at the data's value scale and the critic only has to learn
        how Q varies around it, instead of climbing to it at Adam's pace (a few hundred on HalfCheetah) while the actor
        follows an action gradient that is not yet shaped (default). A float: that value. ``None``: the layer's own
        initialisation (the paper)
    :param goal_switches: what to do where a goal-conditioned dataset's ``desired_goal`` changes between a
        transition's observations (:meth:`~sb3_pola.common.datasets.OfflineDataset.goal_switches`): the mazes'
        collectors draw a new goal the step the old one is reached, so the critic bootstraps the step after reaching a
        goal from a state whose goal is elsewhere, and no transition shows staying at a goal, which is what the
        maze's evaluation pays for. ``"terminal"``: those transitions end their goal's episode; ``"relabel"``: they
        keep their own goal and the env's reward of it (hindsight relabelling, the env's ``compute_reward``;
        default since #23's fourteenth pass, which it lifted on both mazes: docs/results.md);
        ``None``: the data as recorded (the paper). No effect on data without a ``desired_goal``
    :param hindsight_goals: also train the critic on a copy of every goal segment relabelled with a goal it passes
        through (:meth:`~sb3_pola.common.datasets.OfflineDataset.with_hindsight_goals`, HER): each relabelled segment
        is rewarded where it passes its goal and not after, so the critic learns what leaving a goal costs. The actor
        draws its batches from the data alone: imitating the copies would teach it to pass its goal by (on the
        medium maze the actor that imitated them too scored 1.5). Default ``True`` (#23's sixteenth pass, which it
        lifted on the medium maze: docs/results.md); ``False``: the data alone (the paper). No effect on data without
        a ``desired_goal``
    :param critic_diversity: weight ``eta_ES`` of EDAC's ensemble-similarity term added to the critic loss
        (:func:`ensemble_similarity`): it decorrelates the members' action gradients at the data, so that they
        disagree off it and the minimum over the ensemble (targets) and its top-K (eq. 4) are pessimistic where the
        actor leaves the data. Default ``1`` (EDAC's value for HalfCheetah); ``0``: off (the paper). The term's
        input gradients are written out layer by layer (:mod:`sb3_pola.common.input_gradients`), so the critic
        loss is differentiated once, compiles under ``compile_update`` and costs a fraction of autograd's double
        backward (Mish or ReLU critics; other activations take autograd's path and stay eager)
    :param critic_diversity_inputs: the gradients the similarity term compares: ``"actions"`` (EDAC:
        ``grad_a Q_i``), or ``"states_and_actions"`` (the gradient over the critic's whole input, state features
        and action): the look-ahead's gradient through the model reaches the actor by ``grad_s Q``, so this makes
        the members disagree on where the predicted states should go as well
    :param lookahead_uncertainty_penalty: weight ``lambda`` of a MOPO-style penalty added to ``L_q``:
        ``lambda sum_{i>=1} w_i mean(alive * u_i)``, ``u_i`` the disagreement of the dynamics model's elites
        on the step into ``s_{t+i}`` (RMS over state dimensions of the elites' standard deviation, in
        standardised units), ``w_i`` the look-ahead weights; it pushes the actor away from actions whose
        predicted consequences the model is unsure of. ``0``: off (the paper)
    :param lookahead_uncertainty_cutoff: look-ahead states reached through a step with disagreement above
        this value contribute no Q term, and neither do later ones (as a terminal state). ``None``: off
    :param lookahead_trust_margin: ``m``: a predicted state's term of eq. 3 counts, sample by sample, only where its
        pessimistic Q is at most the current state's plus ``m`` times the batch's mean ``|Q(s_t, a_t)|``: the critic
        never trained at a model state, and a predicted state it values above the state the actor starts from is
        more likely its extrapolation than a better future. At ``m = 0`` over 30,000 steps on hopper/medium it
        recovered half of the look-ahead's cost from 20k; at 10,000 steps it moved no dataset's score; where the
        predicted states run forward (halfcheetah) or to the goal (the mazes) it drops most of them, which the critic
        rightly values higher (docs/results.md, thirty-second pass). The share of predicted terms kept is logged as
        ``train/lookahead_trusted``. ``None``: every term counts (the paper; default). Needs ``lookahead_target="q"``
    :param lookahead_trust_rule: what ``lookahead_trust_margin`` holds against the current state's pessimistic Q.
        ``"value"`` (default): the predicted state's own. ``"bellman"``: the value the rollout implies for the current
        state, the model's discounted rewards on the way (while alive) plus ``gamma^i Q(s_{t+i}, a_{t+i})``: a better
        future that the critic already counts at ``s_t`` passes, a value that appears only at the predicted state does
        not. It keeps as many of hopper/medium's terms as ``"value"`` but other ones, and more where the future is
        better (halfcheetah/medium-replay, the mazes); over 30,000 steps on hopper/medium it recovered what ``"value"``
        recovers, half of the look-ahead's cost (docs/results.md, thirty-third pass)
    :param lcb_coef: ``k`` of a lower confidence bound ``mean - k std`` over the ensemble used in the policy loss
        in place of the mean of the ``top_k`` smallest members (:func:`lookahead_q_objective`). ``None``: top-K
    :param critic_bc_coef: ReBRAC's critic penalty ``beta``: the bootstrapped ``min_j Q'_j(s', a')`` pays
        ``beta ||a' - a'_data||^2`` (summed over the action's dimensions, actions in [-1, 1]), ``a'_data`` the
        data's own next action in the episode (no penalty at an episode's last step), in the critic's units, before
        ``target_q_floor``. The target then values a policy that stays near the data's actions in the future, so the
        Q term judges ``a`` by what follows it when the data's behaviour follows. ``0``: no penalty (the paper;
        default). ReBRAC uses 0.01 on hopper-medium, 0.5 on hopper-medium-replay
    :param q_term_confidence: ``k``: each state's terms of eq. 3/4 (the current state and its predicted states) count
        only where the critic's members agree the actor's action beats the data's, ``mean_j d_j > k std_j d_j`` with
        ``d_j = Q_j(s, a_t) - Q_j(s, a_data)`` (no gradient); elsewhere the actor only imitates. The test of the
        policy option ``fallback_confidence`` made while training one actor, so ``predict`` costs nothing more. At
        ``k = 1`` it lifted hopper/medium's narrow file from 34.0 to 40.9 and broke the sparse medium maze, where
        the members rarely agree (docs/results.md, thirty-seventh pass): for dense rewards only. The share of the
        batch whose terms count is logged as ``train/q_term_share``. ``None``: every state counts (the paper;
        default). Needs ``n_critics >= 2``
    :param critic_layer_norm: LayerNorm in the critics' hidden layers (ReBRAC): it bounds Q off the data, so the Q term
        can pull at the paper's strength without the actor climbing the critic's extrapolation. Passed to the policy
        (a ``critic_layer_norm`` in ``policy_kwargs`` takes precedence). Default ``True``; ``False``: plain MLP
        critics (the paper)
    :param eta_gate: ``"critic_maturity"`` (default): each step's ``eta`` is multiplied by
        ``clip((Q - G_min) / (f (G - G_min)), 0, 1)``, ``Q`` the ensemble's mean at the batch's data, ``G`` and ``G_min``
        the mean and the lowest discounted return-to-go of the dataset
        (:meth:`~sb3_pola.common.datasets.OfflineDataset.returns_to_go`), ``f`` = ``eta_gate_fraction``: the Q term
        opens as the critic's Q rises from the data's lowest value towards its mean (logged as
        ``train/critic_maturity``). With dense rewards it is open within the first hundred steps (HalfCheetah:
        ``G_min`` is below 0); with sparse rewards the ensemble minimum's pessimism bias holds Q below the data's
        floor ``G_min = 0`` for thousands of steps, and meanwhile the actor imitates instead of following the critic's
        noise (docs/results.md, issue #23's fifth pass). ``None``: ``eta`` as given (the paper)
    :param eta_gate_fraction: ``f`` of the ``"critic_maturity"`` gate: the Q term is fully open once ``Q`` has covered
        this fraction of the way from ``G_min`` to ``G``. Default ``0.1``
    :param lookahead_fixed_goal: on goal-conditioned data (a ``desired_goal`` key), the look-ahead's predicted states
        keep the state's own ``desired_goal``: the task does not change in imagination, as it does not in the
        evaluation. The dynamics model fitted on the mazes' data has learned that a goal jumps once it is reached (the
        collector's switches), so near a goal it moves the predicted goal (U-maze: by 0.2 a step, 0.58 after three,
        beyond the goal's 0.45 radius) and the actor was trained to follow a drifting goal. Default ``True``;
        ``False``: the model's prediction (the paper). No effect without a ``desired_goal``
    :param lookahead_target: how the look-ahead judges the predicted states. ``"q"`` (the paper, eq. 3; default): the
        critic's Q at each of them. ``"value_expansion"``: the model's predicted rewards up to each of them and the
        critic's Q there, ``V_h = sum_{i<h} gamma^i r_i + gamma^h Q(s_{t+h}, a_{t+h})`` for ``h = 0..T``
        (MVE; :func:`~sb3_pola.pola.losses.value_expansion_objective`), each an estimate of ``Q(s_t, a_t)``: the
        critic never trains at a model state, so its Q there is extrapolation, and the expansion discounts it by
        ``gamma^h`` behind rewards the model was fitted on. ``lookahead_normalization`` sums or averages the expansions
    :param lookahead_actions: who acts at the predicted states. ``"actor"`` (the paper; default): the actor, so eq. 3's
        terms at ``s_{t+i}`` train its action there by Q alone, at states without a dataset action for ``L_d`` to
        anchor it (on hopper/medium the T = 3 actor learned to exploit the critic there; docs/results.md, twelfth
        pass). ``"ema"``: the EMA actor, as a fixed function of the state, so the look-ahead trains only ``a_t``, at the
        data's state where ``L_d`` anchors it, through where the model says it leads; needs
        ``backprop_through_model=True``
    :param model_td_weight: weight of a second TD loss in the critic's, on the transitions of ``T``-step model rollouts
        of the EMA actor from the batch's next states (as MBPO and MOPO train their critics on model data): the
        look-ahead judges the actor by Q at model-predicted states of its own actions, where a critic trained only
        on the data extrapolates, and an actor trained there learns to exploit it (on hopper/medium the T = 3 policy's
        Q overstates its own return by 50-100% after 100,000 steps, T = 0's by 1-2%; docs/results.md, eleventh pass).
        With it the critic also fits ``r + gamma (1 - done) min_j Q'_j(s', a')`` there, with the model's reward and
        termination. The loss is the mean over the rollouts' rows that have not ended. It did not stop that
        overstatement (the rollouts' targets bootstrap from the same Q three steps on); an option, not a default.
        ``0``: off (the paper; default). No effect at ``T = 0``
    :param model_conservatism: weight ``beta`` of COMBO's conservative term in the critic's loss (Yu et al., 2021):
        ``beta (mean Q at the model rollouts' states and the EMA actor's actions - mean Q at the data's (s, a))`` per
        member, the rollouts as for ``model_td_weight``: it lowers Q where the look-ahead asks the critic and the data
        cannot answer, and raises it at the data. ``0``: off (the paper; default). No effect at ``T = 0``
    :param backprop_through_model: ``True`` (paper eq. 3): the actor's gradient flows through the
        dynamics model into earlier actions, since ``s_{t+i}`` depends on ``a_{t+i-1}``. ``False`` (default):
        look-ahead states are detached, so each Q term only trains the action taken at its state: the actor
        still learns at the states its own actions lead to, but cannot move them to please the critic.
    :param n_diffusion_steps: denoising steps of the diffusion actor
    :param beta_schedule: noise schedule: ``"vp"`` (default), ``"linear"`` or ``"cosine"``
    :param prediction_type: the actor network's target: ``"epsilon"``, the noise (eq. 6 as written), or
        ``"sample"``, the clean action (:class:`~sb3_pola.pola.policies.DiffusionActor`)
    :param use_state_products: give the actor the pairwise state products (section V; default ``False``: the raw
        state, with a ReLU actor unless ``policy_kwargs`` names its ``actor_activation_fn``. On the mazes this actor
        lifts POLA well above the paper's, on the locomotion datasets it is level, except a hopper file rich in good
        episodes, where the products gave more; docs/results.md, #23's twenty-eighth pass)
    :param critic_learning_rate: the critics' own learning rate, a float or a schedule, as d3rlpy's
        ``critic_learning_rate`` (``None``, the default: ``learning_rate``, as SB3)
    :param bc_learning_rate: the behaviour-cloning term's own rate in the actor's step, a float or a schedule
        (``None``, the default: ``learning_rate``). The actor's Adam keeps one second moment for the summed gradient
        of ``L_d + eta L_q`` (eq. 6) and moves ``L_d``'s part at this rate, ``eta L_q``'s at ``learning_rate``
        (:mod:`~sb3_pola.common.term_rates`), so a decaying imitation step can leave the Q term's step alone; with
        ``eta = 0`` it is the actor's rate. It needs the actor's optimizer to be Adam or AdamW
    :param bc_weight_temp: temperature ``beta`` of advantage-weighted imitation (AWR, as IQL's and AWAC's actors):
        each row of ``L_d`` (eq. 6) is weighted by ``exp(beta A)``, ``A = Q(s, a) - Q(s, a_ema)`` the pessimistic
        critic's advantage of the data's action over the EMA actor's (top-K as in eq. 4), in units of the batch's
        standard deviation, the weights normalised to mean 1 over the batch
        (:func:`~sb3_pola.pola.losses.advantage_weights`). The imitation target moves towards the data's better
        actions without querying the critic off the data, which ``L_q`` does. With ``eta_gate`` the temperature opens
        with ``eta`` (``beta`` times the critic's maturity). ``None`` (default): the plain mean (the paper); ``0``: the
        same weights, all 1. Costs one more chain of the EMA actor and one critic call a step
    :param bc_max_weight: upper clip of the advantage weights (relative to their mean of 1). Default ``20``
    :param max_grad_norm: gradient-norm clipping of actor and critic (``None`` disables it)
    :param ema_decay: decay of the EMA actor used for targets and ``predict``
    :param ema_update_freq: gradient steps between EMA updates
    :param ema_start: gradient step from which the EMA averages (before it copies the actor)
    :param dynamics_kwargs: arguments of :class:`~sb3_pola.common.dynamics.EnsembleDynamics`
    :param dynamics_fit_kwargs: arguments of :class:`~sb3_pola.common.dynamics_trainer.DynamicsTrainer`. With neither
        ``max_epochs`` nor ``max_steps`` in it, the fit's budget is sized to the data
        (:func:`~sb3_pola.common.dynamics_trainer.auto_max_steps`: 10 passes over the data, at least 1,000 gradient
        steps; early stopping may end it sooner); ``{"max_steps": None}`` fits until early stopping alone ends it
    :param dynamics_cache: keep the fitted dynamics model in the user's cache (``$SB3_POLA_CACHE_DIR/dynamics``, else
        ``~/.cache/sb3_pola/dynamics``) and reuse it: a later ``learn`` on the same dataset content, dynamics
        configuration, fit arguments and seed loads it instead of fitting again, and trains exactly as after the fit
        (the random state the fit leaves is restored; :mod:`~sb3_pola.common.dynamics_cache`); without a seed, any
        kept fit of the same data and configuration is loaded. ``False``: always fit, keep nothing
    :param compile_update: compile the critic and actor losses (forward and backward) with ``torch.compile``
        for the static shapes of training, and on CUDA capture them as CUDA graphs (the GPU speed path).
        The first gradient step compiles (one to three minutes on a small CPU); random draws match eager
        PyTorch (``fallback_random``), so results are the eager update's up to float rounding. It turns on
        the policy's ``compile_activations`` unless ``policy_kwargs`` says otherwise. ``False``: eager.
    :param download: let Minari download a dataset id that is not found locally
    :param policy_kwargs: extra arguments of :class:`~sb3_pola.pola.policies.POLAPolicy`
        (``net_arch``, ``activation_fn``, ``n_action_samples``, ``critic_state_products``, ...)
    :param tensorboard_log: tensorboard log folder
    :param verbose: 0 silent, 1 info, 2 debug
    :param seed: random seed
    :param device: ``"cpu"``, ``"cuda"`` or ``"auto"``
    :param check_finite_freq: gradient steps between two NaN/inf checks of losses and parameters (``1``: every step)
    :param _init_setup_model: build the networks at construction
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": MlpPolicy}
    policy: POLAPolicy
    actor: DiffusionActor
    critic: EnsembleCritic
    critic_target: EnsembleCritic

    def __init__(
        self,
        policy: str | type[POLAPolicy],
        env: GymEnv | str | None = None,
        dataset: DatasetLocation | OfflineDataset | None = None,
        learning_rate: float | Schedule = DEFAULT_LEARNING_RATE,
        batch_size: int = 256,
        tau: float = 0.005,
        gamma: float = 0.99,
        n_critics: int = 10,
        top_k: int = 2,
        rollout_length: int = 3,
        eta: float | Schedule = 3.94,
        lookahead_normalization: str = "first",
        lookahead_weight: float = 0.0625,
        q_scale_floor: float | str | None = None,
        target_q_floor: float | str | None = "returns",
        reward_scale: float = 1.0,
        critic_init_value: float | str | None = "returns",
        goal_switches: str | None = "relabel",
        hindsight_goals: bool = True,
        critic_diversity: float = 1.0,
        critic_diversity_inputs: str = "actions",
        lookahead_uncertainty_penalty: float = 0.0,
        lookahead_uncertainty_cutoff: float | None = None,
        lookahead_trust_margin: float | None = None,
        lookahead_trust_rule: str = "value",
        lcb_coef: float | None = None,
        critic_bc_coef: float = 0.0,
        q_term_confidence: float | None = None,
        critic_layer_norm: bool = True,
        eta_gate: str | None = "critic_maturity",
        eta_gate_fraction: float = 0.1,
        lookahead_fixed_goal: bool = True,
        lookahead_target: str = "q",
        lookahead_actions: str = "actor",
        model_td_weight: float = 0.0,
        model_conservatism: float = 0.0,
        backprop_through_model: bool = False,
        n_diffusion_steps: int = 5,
        beta_schedule: str = "vp",
        prediction_type: str = "sample",
        use_state_products: bool = False,
        critic_learning_rate: float | Schedule | None = None,
        bc_learning_rate: float | Schedule | None = None,
        bc_weight_temp: float | None = None,
        bc_max_weight: float = 20.0,
        max_grad_norm: float | None = 1.0,
        ema_decay: float = 0.995,
        ema_update_freq: int = 5,
        ema_start: int = 1000,
        dynamics_kwargs: dict[str, Any] | None = None,
        dynamics_fit_kwargs: dict[str, Any] | None = None,
        dynamics_cache: bool = True,
        compile_update: bool = False,
        download: bool = False,
        policy_kwargs: dict[str, Any] | None = None,
        tensorboard_log: str | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: str = "auto",
        check_finite_freq: int = 100,
        _init_setup_model: bool = True,
    ) -> None:
        check_pola_arguments(
            n_critics=n_critics,
            top_k=top_k,
            rollout_length=rollout_length,
            eta=eta,
            gamma=gamma,
            lookahead_normalization=lookahead_normalization,
            lookahead_weight=lookahead_weight,
            q_scale_floor=q_scale_floor,
            target_q_floor=target_q_floor,
            reward_scale=reward_scale,
            critic_init_value=critic_init_value,
            goal_switches=goal_switches,
            critic_diversity=critic_diversity,
            critic_diversity_inputs=critic_diversity_inputs,
            lookahead_uncertainty_penalty=lookahead_uncertainty_penalty,
            lookahead_uncertainty_cutoff=lookahead_uncertainty_cutoff,
            lookahead_trust_margin=lookahead_trust_margin,
            lookahead_trust_rule=lookahead_trust_rule,
            lcb_coef=lcb_coef,
            critic_bc_coef=critic_bc_coef,
            q_term_confidence=q_term_confidence,
            critic_layer_norm=critic_layer_norm,
            eta_gate=eta_gate,
            eta_gate_fraction=eta_gate_fraction,
            lookahead_fixed_goal=lookahead_fixed_goal,
            lookahead_target=lookahead_target,
            lookahead_actions=lookahead_actions,
            critic_learning_rate=critic_learning_rate,
            bc_learning_rate=bc_learning_rate,
            bc_weight_temp=bc_weight_temp,
            bc_max_weight=bc_max_weight,
            backprop_through_model=backprop_through_model,
            model_td_weight=model_td_weight,
            model_conservatism=model_conservatism,
            n_diffusion_steps=n_diffusion_steps,
            beta_schedule=beta_schedule,
            prediction_type=prediction_type,
            max_grad_norm=max_grad_norm,
            ema_decay=ema_decay,
            ema_update_freq=ema_update_freq,
            ema_start=ema_start,
            dynamics_kwargs=dynamics_kwargs,
            dynamics_fit_kwargs=dynamics_fit_kwargs,
        )
        # read while the base class loads the dataset (_prepare_offline_data), so set before it
        self.goal_switches = goal_switches
        self.hindsight_goals = hindsight_goals
        self._n_imitation_rows: int | None = None  # hindsight_goals: the actor's batches come from the first rows
        super().__init__(
            policy,
            env,
            dataset,
            learning_rate,
            batch_size=batch_size,
            tau=tau,
            gamma=gamma,
            download=download,
            policy_kwargs=policy_kwargs,
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            seed=seed,
            device=device,
            check_finite_freq=check_finite_freq,
        )
        self.n_critics = n_critics
        self.top_k = top_k
        self.rollout_length = rollout_length
        self.eta = eta
        self.lookahead_normalization = lookahead_normalization
        self.lookahead_weight = lookahead_weight
        self.q_scale_floor = q_scale_floor
        # the floor's value: q_scale_floor, or the dataset's value scale once the data are loaded ("auto")
        self.q_scale_floor_value: float | None = None if q_scale_floor == "auto" else float(q_scale_floor or 0.0)
        self.target_q_floor = target_q_floor
        # the floor's value: target_q_floor, or the lowest value any policy can have on the data's rewards ("auto")
        self.target_q_floor_value: float | None = (
            None if target_q_floor in (None, "auto", "returns") else float(target_q_floor)
        )
        self.reward_scale = reward_scale
        self.critic_init_value = critic_init_value
        # "returns": the dataset's discounted return-to-go of every transition, [N], set once the data are loaded
        self._data_returns: th.Tensor | None = None
        self._critic_init_done = False  # critic_init_value applied (once, before the first update)
        self.critic_diversity = critic_diversity
        self.critic_diversity_inputs = critic_diversity_inputs
        self.lookahead_uncertainty_penalty = lookahead_uncertainty_penalty
        self.lookahead_uncertainty_cutoff = lookahead_uncertainty_cutoff
        self.lookahead_trust_margin = lookahead_trust_margin
        self.lookahead_trust_rule = lookahead_trust_rule
        self.lcb_coef = lcb_coef
        self.critic_bc_coef = critic_bc_coef
        self.q_term_confidence = q_term_confidence
        # critic_bc_coef: 1 where a row's episode goes on (its next action is the next row's), [N]
        self._next_data_mask: th.Tensor | None = None
        self.eta_gate = eta_gate
        self.eta_gate_fraction = eta_gate_fraction
        # "critic_maturity": the dataset's mean and lowest discounted return-to-go, set once the data are loaded
        self.data_value: float | None = None
        self.data_value_floor = 0.0
        self.lookahead_fixed_goal = lookahead_fixed_goal
        self.lookahead_target = lookahead_target
        self.lookahead_actions = lookahead_actions
        self.model_td_weight = model_td_weight
        self.model_conservatism = model_conservatism
        # [obs_dim] bool, the desired_goal's columns of goal-conditioned data (lookahead_fixed_goal), set by learn
        self._goal_mask: th.Tensor | None = None
        self.backprop_through_model = backprop_through_model
        self.n_diffusion_steps = n_diffusion_steps
        self.beta_schedule = beta_schedule
        self.prediction_type = prediction_type
        self.use_state_products = use_state_products
        self.max_grad_norm = max_grad_norm
        self.critic_learning_rate = critic_learning_rate
        self.bc_learning_rate = bc_learning_rate
        self.bc_weight_temp = bc_weight_temp
        self.bc_max_weight = bc_max_weight
        self.ema_decay = ema_decay
        self.ema_update_freq = ema_update_freq
        self.ema_start = ema_start
        self.dynamics_kwargs = dynamics_kwargs or {}
        self.dynamics_fit_kwargs = dynamics_fit_kwargs or {}
        self.dynamics_fit_info: dict[str, float] = {}
        self.dynamics_cache = dynamics_cache
        self.compile_update = compile_update
        # the critics' LayerNorm is the policy's; policy_kwargs["critic_layer_norm"], if given, takes precedence, and
        # a saved model keeps it in its policy_kwargs (a file from before this argument loads without it: False)
        self.policy_kwargs = {"critic_layer_norm": critic_layer_norm, **self.policy_kwargs}
        if compile_update:  # Mish as one exp inside the compiled graph: inductor fuses it into a single kernel
            self.policy_kwargs = {"compile_activations": True, **self.policy_kwargs}
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        self._setup_lr_schedule()
        self.critic_lr_schedule: Schedule | None = None
        if self.critic_learning_rate is not None:  # the critics' own rate (the actor keeps learning_rate)
            self.critic_lr_schedule = FloatSchedule(self.critic_learning_rate)
        # models saved before the argument have none: the actor's one rate
        bc_learning_rate = getattr(self, "bc_learning_rate", None)
        self.bc_lr_schedule = None if bc_learning_rate is None else FloatSchedule(bc_learning_rate)
        self._bc_lr: float | None = None if self.bc_lr_schedule is None else float(self.bc_lr_schedule(1.0))
        self.eta_schedule = FloatSchedule(self.eta)
        self.set_random_seed(self.seed)
        self._termination_fn: TerminationFn | None = get_termination_fn(self.env_id)
        dynamics_kwargs = None
        if self.rollout_length > 0:
            # a learned termination head stands in for the env's rule where none is known
            dynamics_kwargs = {"learn_termination": self._termination_fn is None, **self.dynamics_kwargs}
        self.policy = self.policy_class(  # type: ignore[assignment]
            self.observation_space,
            self.action_space,
            self.lr_schedule,
            n_critics=self.n_critics,
            n_diffusion_steps=self.n_diffusion_steps,
            beta_schedule=self.beta_schedule,
            prediction_type=self.prediction_type,
            use_state_products=self.use_state_products,
            dynamics_kwargs=dynamics_kwargs,
            **self.policy_kwargs,
        )
        self.policy = self.policy.to(self.device)
        if self._offline_data is not None:
            mean, std = self._offline_data.obs_stats()
            self.policy.set_normalization(mean, std)
        self._create_aliases()
        self._gamma_powers = th.tensor([self.gamma**i for i in range(self.rollout_length + 1)], device=self.device)
        # eq. 3's weights: gamma^i, times lookahead_weight at the predicted states
        self._lookahead_powers = self._gamma_powers * th.tensor(
            [1.0] + [float(self.lookahead_weight)] * self.rollout_length, device=self.device
        )
        self._eta_value = th.zeros((), device=self.device)  # this step's eta, a tensor so a compiled graph reads it
        self._bc_temp_value = th.zeros((), device=self.device)  # this step's bc_weight_temp, likewise
        # eq. 5's chain in its fast forms (sb3_pola.pola.fast_sampling, tested equal to DiffusionActor.sample): the
        # actor's samples need gradients; the target's do not, but a compiled graph traces the differentiable
        # form (the no-grad one rebuilds its weights in Python each call)
        self._sample_actor: Callable[[th.Tensor], th.Tensor] = functools.partial(sample_chain, self.policy.actor)
        # lookahead_actions="ema": the EMA actor acts at the predicted states, differentiable in the state only
        self._sample_lookahead = (
            functools.partial(sample_chain, self.policy.actor_ema) if self.lookahead_actions == "ema" else self._sample_actor
        )
        if self.compile_update:
            self._sample_target: Callable[[th.Tensor], th.Tensor] = functools.partial(sample_chain, self.policy.actor_ema)
        else:
            self._sample_target = functools.partial(sample_no_grad, self.policy.actor_ema, copy_weights=True)
        # EDAC's similarity term: autograd's double backward, or the same graph written out (differentiated once)
        self._input_gradients = input_gradient_fn(self.critic.q_net)
        # torch.compile differentiates once: the similarity term compiles in its written-out form only
        compile_critic = self.compile_update and (
            self.critic_diversity == 0 or self._input_gradients is explicit_input_gradients
        )
        self._critic_loss_fn = CompiledLoss(self._critic_loss, compile_critic, self._cudagraphs, starts_step=True)
        # eq. 6's two terms, each its own graph and backward pass: the BC term's gradient on its own is what
        # bc_learning_rate moves at its rate
        self._bc_loss_fn = CompiledLoss(self._bc_loss, self.compile_update, self._cudagraphs)
        self._q_term_fn = CompiledLoss(self._q_term, self.compile_update, self._cudagraphs)
        self._fallback_loss_fn = CompiledLoss(self._fallback_loss, self.compile_update, self._cudagraphs)
        if self.bc_lr_schedule is not None:
            check_term_rate_optimizer(self.actor.optimizer)

    @property
    def _cudagraphs(self) -> bool:
        return self.compile_update and self.device.type == "cuda"

    def _create_aliases(self) -> None:
        self.actor = self.policy.actor
        self.critic = self.policy.critic
        self.critic_target = self.policy.critic_target

    @property
    def critic_layer_norm(self) -> bool:
        """Whether the critics have LayerNorm (the policy's setting; ``False`` in a file saved before the argument)."""
        return bool(self.policy_kwargs.get("critic_layer_norm", False))

    def _excluded_save_params(self) -> list[str]:
        return [
            *super()._excluded_save_params(),
            "actor",
            "critic",
            "critic_target",
            "_termination_fn",
            "_gamma_powers",
            "_lookahead_powers",
            "_eta_value",
            "_sample_actor",
            "_sample_target",
            "_critic_loss_fn",
            "_data_returns",
            "_next_data_mask",
            "_goal_mask",
            "_n_imitation_rows",
            "_bc_loss_fn",
            "_q_term_fn",
            "_fallback_loss_fn",
            "_bc_lr",
            "eta_schedule",
            "critic_lr_schedule",
            "bc_lr_schedule",
        ]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        fallback = ["policy.fallback_actor.optimizer"] if self.policy.fallback_actor is not None else []
        return ["policy", "actor.optimizer", "critic.optimizer", *fallback], []

    def _prepare_offline_data(self, data: OfflineDataset) -> OfflineDataset:
        space = data.dict_observation_space
        hindsight = self.hindsight_goals and space is not None and "desired_goal" in space.spaces
        switches = self.goal_switches is not None and data.goal_switches().any()
        if not switches and not hindsight:
            return data
        reward_fn = None
        if hindsight or self.goal_switches == "relabel":
            env = make_env(data)
            compute_reward = getattr(env.unwrapped, "compute_reward", None)
            env.close()
            if compute_reward is not None:
                reward_fn = functools.partial(_goal_reward, compute_reward)
        if switches:
            if self.goal_switches == "relabel" and reward_fn is None:
                raise ValueError(f"goal_switches='relabel' needs an env with compute_reward (GoalEnv); {data.env_id} has none")
            data = data.with_goal_switches(self.goal_switches, reward_fn)  # type: ignore[arg-type]
        if hindsight:
            if reward_fn is None:
                warnings.warn(f"hindsight_goals needs an env with compute_reward (GoalEnv); {data.env_id} has none: no copies")
                return data
            self._n_imitation_rows = len(data)  # the copies come after: the critic's rows, not the actor's
            data = data.with_hindsight_goals(reward_fn, seed=0 if self.seed is None else self.seed)
        return data

    # ------------------------------------------------------------------ dynamics model
    def _before_training(self, progress_bar: bool = False) -> None:
        rewards = self._setup_offline_data().rewards * self.reward_scale  # in the critic's units
        if self.q_scale_floor_value is None:  # "auto": the value scale of the dataset's rewards
            self.q_scale_floor_value = float(rewards.abs().mean()) / (1.0 - self.gamma)
        if self.target_q_floor == "auto" and self.target_q_floor_value is None:
            self.target_q_floor_value = value_lower_bound(rewards, self.gamma)
        floor_needs = self.target_q_floor == "returns" and self._data_returns is None
        gate_needs = self.eta_gate == "critic_maturity" and self.data_value is None
        init_needs = self.critic_init_value == "returns" and self._n_updates == 0 and not self._critic_init_done
        if floor_needs or gate_needs or init_needs:  # the data's returns-to-go, computed once for all
            self._setup_offline_data()
            assert self._offline_data is not None
            returns = self._offline_data.returns_to_go(self.gamma) * self.reward_scale  # in the critic's units
            if floor_needs:
                self._data_returns = th.as_tensor(returns, dtype=th.float32, device=self.device)  # [N]
            if gate_needs:
                self.data_value, self.data_value_floor = float(returns.mean()), float(returns.min())
            if init_needs:
                self._shift_critic_output(float(returns.mean()))
        if self.critic_bc_coef > 0 and self._next_data_mask is None:
            self._next_data_mask = self._episode_goes_on()
        if isinstance(self.critic_init_value, float | int) and self._n_updates == 0:
            self._shift_critic_output(float(self.critic_init_value))
        if self.lookahead_fixed_goal and self._goal_mask is None:
            self._goal_mask = self._desired_goal_mask()
        dynamics = self.policy.dynamics
        if dynamics is None:
            return
        if bool(self.policy.dynamics_fitted):
            dynamics.freeze()  # a loaded model (resume) rebuilt the model with trainable parameters
            return
        arrays = self._dynamics_arrays()
        fit_kwargs = {"progress_bar": progress_bar, "logger": self.logger, "verbose": self.verbose, **self.dynamics_fit_kwargs}
        fit_kwargs = self._sized_fit_kwargs(fit_kwargs, len(arrays[0]))

        def fit() -> dict[str, float]:
            return DynamicsTrainer(dynamics, **fit_kwargs).fit(*arrays)

        self.dynamics_fit_info = self._fit_or_load_dynamics(fit, fit_kwargs, arrays)
        dynamics.freeze()
        self.policy.dynamics_fitted.fill_(True)

    def _episode_goes_on(self) -> th.Tensor:
        """``[N]`` 1 where a row's episode goes on, so its next action is the next row's; 0 at an episode's last row
        (a terminal's target has no ``Q'``; a truncation's next action is not in the data). The hindsight copies are
        episodes of their own (``episode_ends``)."""
        self._setup_offline_data()
        assert self._offline_data is not None
        return th.as_tensor(~self._offline_data.episode_ends(), dtype=th.float32, device=self.device)

    def _next_data(self, indices: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """``critic_bc_coef``'s batch: the data's next action of each row, ``[B, A]`` (the next row's; any action at an
        episode's last row), and ``[B]`` 1 where it is one (:meth:`_episode_goes_on`)."""
        assert self._next_data_mask is not None
        actions = self._setup_offline_data().actions
        return actions[(indices + 1).clamp_max(len(actions) - 1)], self._next_data_mask[indices]

    def _dynamics_arrays(self) -> list[th.Tensor]:
        """The transitions the dynamics model fits: ``s, a, s', r, done`` of the data's rows (the hindsight copies of
        ``hindsight_goals`` show the same motion under other goals)."""
        buffer = self._setup_offline_data()
        n = self._n_imitation_rows or len(buffer.observations)
        return [x[:n] for x in (buffer.observations, buffer.actions, buffer.next_observations, buffer.rewards, buffer.dones)]

    def _desired_goal_mask(self) -> th.Tensor | None:
        """``[obs_dim]`` bool, True at the ``desired_goal`` columns of a goal-conditioned dataset's flattened
        observations; ``None`` without a ``desired_goal``."""
        self._setup_offline_data()
        space = None if self._offline_data is None else self._offline_data.dict_observation_space
        if space is None or "desired_goal" not in space.spaces:
            return None
        mask = th.zeros(self.observation_space.shape[0], dtype=th.bool, device=self.device)  # type: ignore[index]
        mask[key_slice(space, "desired_goal")] = True
        return mask

    def _shift_critic_output(self, value: float) -> None:
        """Shift the output bias of every critic member and target member by ``value`` (``critic_init_value``), once:
        a second ``learn`` or a resumed model (``_n_updates > 0``) keeps its trained critics."""
        if self._critic_init_done:
            return
        with th.no_grad():
            for critic in (self.policy.critic, self.policy.critic_target):
                critic.output_layer.bias.add_(value)  # [N, 1, 1]
        self._critic_init_done = True

    # ------------------------------------------------------------------ the dynamics fit: its size, its cache (issue #25)
    def _sized_fit_kwargs(self, fit_kwargs: dict[str, Any], n_transitions: int) -> dict[str, Any]:
        """The fit's arguments: a bar at ``verbose >= 1`` too, and, when no budget is given, one sized to the data
        (:func:`~sb3_pola.common.dynamics_trainer.auto_max_steps`)."""
        fit_kwargs = {**fit_kwargs, "progress_bar": fit_kwargs["progress_bar"] or self.verbose >= 1}
        if "max_epochs" not in fit_kwargs and "max_steps" not in fit_kwargs:
            sizes = {k: fit_kwargs[k] for k in ("batch_size", "holdout_ratio", "max_holdout") if k in fit_kwargs}
            fit_kwargs["max_steps"] = auto_max_steps(n_transitions, **sizes)
        return fit_kwargs

    def _fit_or_load_dynamics(
        self, fit: Callable[[], dict[str, float]], fit_kwargs: dict[str, Any], arrays: list[th.Tensor]
    ) -> dict[str, float]:
        """``fit()`` on ``arrays`` (:meth:`_dynamics_arrays`), or its result from the cache of fitted dynamics models
        (``dynamics_cache``)."""
        dynamics, data = self.policy.dynamics, self._offline_data
        assert dynamics is not None
        if not getattr(self, "dynamics_cache", True):  # models saved before #25 have no such attribute
            return fit()
        data_key = data_fingerprint(data.fingerprint if data is not None else None, arrays)
        result_kwargs = {k: v for k, v in fit_kwargs.items() if k not in ("progress_bar", "logger", "verbose")}
        exact = self.seed is not None  # seed=None: any fit of this data and configuration will do
        key = cache_key(dynamics, data_key, result_kwargs, self.device, exact=exact)
        source = data.metadata.get("source") if data is not None else None
        about = {
            "dataset_id": data.dataset_id if data is not None else None,
            "source": source or _dataset_source(self.dataset),
        }
        return fit_or_load(dynamics, fit, key, about, verbose=self.verbose, restore_rng=exact)

    # ------------------------------------------------------------------ one gradient step
    def train(self, gradient_steps: int, batch_size: int = 256) -> None:
        self.policy.set_training_mode(True)
        # the imitation-only fallback actor (fallback_confidence) learns at the actor's rate
        actor_optimizers = [self.actor.optimizer]
        if self.policy.fallback_actor is not None:
            actor_optimizers.append(self.policy.fallback_actor.optimizer)
        if self.critic_lr_schedule is None:
            self._update_learning_rate([*actor_optimizers, self.critic.optimizer])
        else:
            self._update_learning_rate(actor_optimizers)
            critic_lr = self.critic_lr_schedule(self._current_progress_remaining)
            self.logger.record("train/critic_learning_rate", critic_lr)
            update_learning_rate(self.critic.optimizer, critic_lr)
        if self.bc_lr_schedule is not None:
            self._bc_lr = float(self.bc_lr_schedule(self._current_progress_remaining))
            self.logger.record("train/bc_learning_rate", self._bc_lr)
        buffer = self._setup_offline_data()
        for _ in range(gradient_steps):
            indices = buffer.sample_indices(batch_size)
            returns = None if self._data_returns is None else self._data_returns[indices]
            next_data = None if self._next_data_mask is None else self._next_data(indices)
            actor_batch = None
            if self._n_imitation_rows is not None:  # the hindsight copies train the critic, not the actor
                actor_indices = buffer.sample_indices(batch_size, self._n_imitation_rows)
                actor_batch = (buffer.observations[actor_indices], buffer.actions[actor_indices])
            self._accumulate_train_stats(self._update(buffer._get_samples(indices), returns, actor_batch, next_data))
            self._n_updates += 1

    def _update(
        self,
        batch: ReplayBufferSamples,
        returns: th.Tensor | None = None,
        actor_batch: tuple[th.Tensor, th.Tensor] | None = None,
        next_data: tuple[th.Tensor, th.Tensor] | None = None,
    ) -> dict[str, th.Tensor]:
        """One POLA update on a batch: critic, actor with look-ahead, EMA, targets. Returns detached statistics.

        ``returns``: ``[B]`` the data's discounted returns-to-go of the batch's transitions (``target_q_floor="returns"``)
        ``actor_batch``: the actor's own ``(observations, actions)`` (``hindsight_goals``: rows of the data, not of its
        relabelled copies); the critic's by default
        ``next_data``: ``critic_bc_coef``'s ``([B, A], [B])``, the data's next actions and where they exist
        """
        obs, actions, next_obs = batch.observations, batch.actions, batch.next_observations
        actor_obs, actor_actions = (obs, actions) if actor_batch is None else actor_batch
        rewards, dones = batch.rewards.flatten() * self.reward_scale, batch.dones.flatten()

        # critic: TD regression on the pessimistic target (section IV)
        next_data_actions, next_data_mask = (None, None) if next_data is None else next_data
        critic_loss, critic_stats = self._critic_loss_fn(
            obs, actions, next_obs, rewards, dones, returns, next_data_actions, next_data_mask
        )
        self.critic.optimizer.zero_grad(set_to_none=True)
        critic_loss.backward()
        critic_grad_norm = self._clip(self.critic.parameters())
        self.critic.optimizer.step()

        # fallback_confidence's actor: L_d of eq. 6 alone, unweighted; before the actor's step, so its random draws
        # are the same whatever the Q term does
        fallback_actor = self.policy.fallback_actor
        if fallback_actor is not None:
            fallback_actor.optimizer.zero_grad(set_to_none=True)
            fallback_loss, fallback_stats = self._fallback_loss_fn(actor_obs, actor_actions)
            fallback_loss.backward()
            self._clip(fallback_actor.parameters())
            fallback_actor.optimizer.step()
            critic_stats.update(fallback_stats)

        # actor: L_d + eta L_q (eq. 6, eq. 4), the critic fixed
        self._eta_value.fill_(float(self.eta_schedule(self._current_progress_remaining)))
        span = (self.data_value or 0.0) - self.data_value_floor  # the data's values from the lowest to the mean
        maturity: th.Tensor | None = None
        if self.eta_gate == "critic_maturity" and span > 0:
            # the Q term opens as the critic's Q at the data rises from the data's lowest return-to-go towards the mean:
            # below that floor Q is the ensemble minimum's pessimism bias, not a value (sparse rewards, early training)
            maturity = ((critic_stats["q_mean"] - self.data_value_floor) / (self.eta_gate_fraction * span)).clamp(0, 1)
            self._eta_value.mul_(maturity)
            critic_stats["critic_maturity"] = maturity
        if self.bc_weight_temp is not None:  # the advantage weights sharpen as the Q term opens
            self._bc_temp_value.fill_(float(self.bc_weight_temp))
            if maturity is not None:
                self._bc_temp_value.mul_(maturity)
        self.actor.optimizer.zero_grad(set_to_none=True)
        bc_loss, actor_stats = self._bc_loss_fn(actor_obs, actor_actions, self._bc_temp_value)
        bc_loss.backward()
        bc_grads = None
        if self._bc_lr is not None:  # L_d's gradient alone, before eta L_q's is added to it
            params = [p for group in self.actor.optimizer.param_groups for p in group["params"]]
            bc_grads = [None if p.grad is None else p.grad.clone() for p in params]
        actor_loss = bc_loss.detach()
        if self._behaviour_cloning:
            actor_stats["q_loss"] = th.zeros_like(actor_loss)
        else:
            with self._critic_frozen():
                q_term, q_stats = self._q_term_fn(actor_obs, self._eta_value, actor_actions)
            q_term.backward()
            actor_loss = actor_loss + q_term.detach()
            actor_stats.update(q_stats)
        actor_grad_norm = self._clip(self.actor.parameters())
        self.actor.optimizer.step()
        if bc_grads is not None:
            assert self._bc_lr is not None
            if self.max_grad_norm is not None:  # the summed gradient's clipping, on its L_d part too
                scale = (self.max_grad_norm / (actor_grad_norm + 1e-6)).clamp(max=1.0)
                th._foreach_mul_([g for g in bc_grads if g is not None], scale)
            term_rate_step(self.actor.optimizer, bc_grads, self._bc_lr)
        actor_stats.update(actor_loss=actor_loss, eta=self._eta_value.clone())

        # EMA actor (Diffusion-QL: copies the actor until ema_start, then averages every ema_update_freq steps)
        step = self._n_updates + 1
        if step % self.ema_update_freq == 0:
            decay = self.ema_decay if step >= self.ema_start else 0.0
            _lerp_params(self.actor.parameters(), self.policy.actor_ema.parameters(), 1.0 - decay)
            if fallback_actor is not None:
                assert self.policy.fallback_actor_ema is not None
                _lerp_params(fallback_actor.parameters(), self.policy.fallback_actor_ema.parameters(), 1.0 - decay)
        _lerp_params(self.critic.parameters(), self.critic_target.parameters(), self.tau)
        if step % GRADIENT_RATIO_FREQ == 0 and not self._behaviour_cloning:
            self.logger.record_mean("train/q_bc_grad_ratio", self.q_bc_gradient_ratio(actor_obs, actor_actions))

        # losses first: a divergence message names the first few non-finite statistics
        return {
            "critic_loss": critic_stats["critic_loss"],
            "actor_loss": actor_stats["actor_loss"],
            **actor_stats,
            **critic_stats,
            "critic_grad_norm": critic_grad_norm,
            "actor_grad_norm": actor_grad_norm,
        }

    def q_bc_gradient_ratio(self, obs: th.Tensor, actions: th.Tensor) -> float:
        """``|grad eta L_q| / |grad L_d|`` over the actor's parameters at this step's ``eta``: how hard the Q term
        pulls against imitation. Eager, on its own draws (the training's random stream is left untouched)."""
        params = [p for p in self.actor.parameters() if p.requires_grad]
        with th.random.fork_rng(devices=[self.device] if self.device.type == "cuda" else []), self._critic_frozen():
            features = self.policy.actor_features(obs)
            bc_loss, _ = self._bc_loss(obs, actions, self._bc_temp_value)  # L_d as trained (weighted if bc_weight_temp)
            bc_grads = th.autograd.grad(bc_loss, params, allow_unused=True)
            q_loss, _ = self._lookahead_q_loss(obs, features, actions)
            q_grads = th.autograd.grad(self._eta_value * q_loss, params, allow_unused=True)

        def norm(grads: tuple[th.Tensor | None, ...]) -> th.Tensor:
            return th.linalg.vector_norm(th.stack([th.linalg.vector_norm(g) for g in grads if g is not None]))

        return float(norm(q_grads) / norm(bc_grads).clamp_min(1e-12))

    @contextlib.contextmanager
    def _critic_frozen(self) -> Iterator[None]:
        """The actor's Q term must not train the critic: its weights take no gradient while the loss is built."""
        self.critic.requires_grad_(False)
        try:
            yield
        finally:
            self.critic.requires_grad_(True)

    def _critic_loss(
        self,
        obs: th.Tensor,
        actions: th.Tensor,
        next_obs: th.Tensor,
        rewards: th.Tensor,
        dones: th.Tensor,
        returns: th.Tensor | None = None,
        next_data_actions: th.Tensor | None = None,
        next_data_mask: th.Tensor | None = None,
    ) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        """TD loss of every ensemble member on the pessimistic target, min over the target ensemble (section IV)."""
        with th.no_grad():
            next_actions = self._sample_target(self.policy.actor_features(next_obs))  # a' from the EMA actor
            next_q = self.critic_target(next_obs, next_actions).min(dim=0).values  # [B]
            if next_data_actions is not None and next_data_mask is not None:  # ReBRAC: a' pays for leaving the data
                distance = (next_actions - next_data_actions).pow(2).sum(dim=-1)  # [B]
                next_q = next_q - self.critic_bc_coef * next_data_mask * distance
            if self.target_q_floor_value is not None:  # no policy's value lies below it: the rest is pessimism bias
                next_q = next_q.clamp_min(self.target_q_floor_value)
            target_q = rewards + self.gamma * (1.0 - dones) * next_q  # [B]
            if returns is not None:  # the data's own return from (s, a) is a value the greedy policy can at least reach
                target_q = th.maximum(target_q, returns)
        input_grads = None
        if self.critic_diversity == 0:
            current_q = self.critic(obs, actions)  # [N, B]
        else:  # each member's gradient at its input, itself differentiable (sb3_pola.common.input_gradients)
            inputs = self.critic.inputs(obs, actions)  # [B, in]
            n_grad = actions.shape[-1] if self.critic_diversity_inputs == "actions" else inputs.shape[-1]  # EDAC: a
            current_q, input_grads = self._input_gradients(self.critic.q_net, inputs, n_grad)  # [N, B], [N, B, n_grad]
        critic_loss = (current_q - target_q).pow(2).mean(dim=1).sum()
        q = current_q.detach()
        stats = {"q_mean": q.mean(), "q_ensemble_std": q.std(dim=0).mean(), "target_q": target_q.mean()}
        if (self.model_td_weight > 0 or self.model_conservatism > 0) and self.rollout_length > 0:
            model_loss, model_stats = self._model_rollout_loss(next_obs, next_actions, dones, current_q)
            critic_loss = critic_loss + model_loss
            stats.update(model_stats)
        if input_grads is not None:
            similarity = ensemble_similarity(input_grads)
            critic_loss = critic_loss + self.critic_diversity * similarity
            stats["critic_similarity"] = similarity.detach()
        return critic_loss, {"critic_loss": critic_loss.detach(), **stats}

    def _model_rollout_loss(
        self, start: th.Tensor, start_actions: th.Tensor, dones: th.Tensor, data_q: th.Tensor
    ) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        """The critic's terms at ``T``-step model rollouts of the EMA actor: ``model_td_weight`` times their TD loss,
        plus ``model_conservatism`` times COMBO's gap between Q there and Q at the data (``data_q``, ``[N, B]``).

        ``start``: the batch's next states, ``start_actions`` the EMA actor's actions there (the data's TD target drew
        them), ``dones``: whether they are terminal (no rollout from those).
        """
        states, actions, rewards, not_done, alive = [], [], [], [], [1.0 - dones]  # per step: [B, obs], [B, A], [B]...
        with th.no_grad():
            state, action = start, start_actions
            for _ in range(self.rollout_length):
                next_state, reward, terminal, _ = self._model_step(state, action)
                states.append(state)
                actions.append(action)
                rewards.append(reward)
                not_done.append(1.0 - terminal)
                alive.append(alive[-1] * not_done[-1])
                state = next_state
                action = self._sample_target(self.policy.actor_features(next_state))
            weights = th.cat(alive[:-1])  # [T B] the row's state is reached
            n_rows = weights.sum().clamp_min(1.0)
        current_q = self.critic(th.cat(states), th.cat(actions))  # [N, T B]
        loss = current_q.new_zeros(())
        stats = {"model_q_mean": (current_q.detach().mean(dim=0) * weights).sum() / n_rows}
        if self.model_td_weight > 0:
            with th.no_grad():  # the targets' next states are the rollout's states 1..T, with the EMA actor's actions
                next_q = self.critic_target(th.cat([*states[1:], state]), th.cat([*actions[1:], action]))  # [N, T B]
                next_q = next_q.min(dim=0).values
                if self.target_q_floor_value is not None:
                    next_q = next_q.clamp_min(self.target_q_floor_value)
                target_q = th.cat(rewards) + self.gamma * th.cat(not_done) * next_q  # [T B]
            loss = loss + self.model_td_weight * ((current_q - target_q).pow(2) * weights).sum(dim=1).sum() / n_rows
        if self.model_conservatism > 0:
            gap = (current_q * weights).sum(dim=1) / n_rows - data_q.mean(dim=1)  # [N]
            loss = loss + self.model_conservatism * gap.sum()
            stats["model_q_gap"] = gap.detach().mean()
        return loss, stats

    @property
    def _behaviour_cloning(self) -> bool:
        """``eta`` is the constant 0: no Q term to build."""
        return not callable(self.eta) and float(self.eta) == 0.0

    def _bc_loss(self, obs: th.Tensor, actions: th.Tensor, weight_temp: th.Tensor) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        """``L_d`` of eq. 6: the diffusion actor's imitation loss at the data's actions (advantage-weighted under
        ``bc_weight_temp``; ``weight_temp`` is this step's temperature, a 0-d tensor)."""
        features = self.policy.actor_features(obs)
        if self.bc_weight_temp is None:
            bc_loss = self.actor.loss(actions, features)
            return bc_loss, {"bc_loss": bc_loss.detach()}
        with th.no_grad():  # A = Q(s, a) - Q(s, a_ema), both the pessimistic value of eq. 4 at the current state
            q = self.critic(th.cat([obs, obs]), th.cat([actions, self._sample_target(features)]))  # [N, 2B]
            q_data, q_ema = pessimistic_q(q.view(q.shape[0], 2, -1), self.top_k, self.lcb_coef)  # [B] each
            weights = advantage_weights(q_data - q_ema, weight_temp, self.bc_max_weight)  # [B]
        bc_loss = self.actor.loss(actions, features, weights)
        # the weights' effective sample size as a fraction of the batch: 1 is plain imitation
        ess = weights.sum().pow(2) / (weights.shape[0] * weights.pow(2).sum())
        return bc_loss, {"bc_loss": bc_loss.detach(), "imitation_ess": ess, "imitation_weight_max": weights.max()}

    def _fallback_loss(self, obs: th.Tensor, actions: th.Tensor) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        """The fallback actor's ``L_d`` (``fallback_confidence``): plain imitation of the data's actions."""
        assert self.policy.fallback_actor is not None
        loss = self.policy.fallback_actor.loss(actions, self.policy.actor_features(obs))
        return loss, {"fallback_bc_loss": loss.detach()}

    def _q_term(
        self, obs: th.Tensor, eta: th.Tensor, actions: th.Tensor | None = None
    ) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        """``eta * L_q`` (eq. 6 and eq. 3/4); ``eta`` is this step's value of the schedule (a 0-d tensor), ``actions``
        the batch's data actions (``q_term_confidence``)."""
        q_loss, stats = self._lookahead_q_loss(obs, self.policy.actor_features(obs), actions)
        return eta * q_loss, {"q_loss": q_loss.detach(), **stats}

    def _model_step(self, state: th.Tensor, action: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
        """One step of the dynamics model as the look-ahead takes it: ``s'``, the reward in the critic's units, whether
        ``s'`` ends the rollout (the env's rule, else the model's termination head; a too uncertain prediction ends it
        too, ``lookahead_uncertainty_cutoff``) and the elites' disagreement, all ``[B]`` but ``s'``."""
        assert self.policy.dynamics is not None
        next_state, reward, terminal_prob, disagreement = self.policy.dynamics.step(state, action)
        if self._goal_mask is not None:  # the task does not change in imagination (lookahead_fixed_goal)
            next_state = th.where(self._goal_mask, state, next_state)
        if self._termination_fn is not None:
            terminal = self._termination_fn(state, action, next_state).float()
        else:
            terminal = terminal_prob.detach()
        if self.lookahead_uncertainty_cutoff is not None:  # too uncertain a prediction ends the look-ahead
            terminal = th.maximum(terminal, (disagreement.detach() > self.lookahead_uncertainty_cutoff).float())
        return next_state, reward * self.reward_scale, terminal, disagreement

    def _lookahead_q_loss(
        self, obs: th.Tensor, features: th.Tensor, data_actions: th.Tensor | None = None
    ) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        """``L_q`` of eq. 4: top-K pessimistic Q at ``s_t`` and at ``T`` model-predicted states, weighted by ``gamma^i``
        (under ``q_term_confidence``, only at the states where the critic's members agree ``a_t`` beats
        ``data_actions``, ``[B, A]``)."""
        policy, horizon = self.policy, self.rollout_length
        batch_size = obs.shape[0]
        action = self._sample_actor(features)  # a_t = pi(s_t), differentiable through the reverse chain
        saturation = (action.detach().abs() > 0.99).float().mean()
        states, actions_, alive = [obs], [action], [th.ones(batch_size, device=obs.device)]
        disagreements: list[th.Tensor] = []  # [B] per look-ahead step, the model's doubt about s_{t+i}
        rewards: list[th.Tensor] = []  # [B] per look-ahead step, the model's r(s_{t+i}, a_{t+i})
        state = obs
        for _ in range(horizon):
            next_state, reward, terminal, disagreement = self._model_step(state, action)
            rewards.append(reward)
            # the penalty of the step into s_{t+i} counts while s_{t+i-1} is alive
            disagreements.append(alive[-1] * disagreement)
            alive.append(alive[-1] * (1.0 - terminal))
            state = next_state if self.backprop_through_model else next_state.detach()
            action = self._sample_lookahead(policy.actor_features(state))  # a_{t+i} = pi(s_{t+i}) (or the EMA's)
            states.append(state)
            actions_.append(action)

        # all T + 1 critic evaluations in one ensemble call (the caller has switched off the critic's gradients)
        q = self.critic(th.cat(states), th.cat(actions_))  # [N, (T+1) B]
        alive_mask = th.stack(alive)  # [T+1, B]
        counted, trusted = alive_mask, None  # counted: the terms eq. 3 sums, [T+1, B]
        margin = getattr(self, "lookahead_trust_margin", None)  # models saved before the option have none
        if margin is not None and horizon > 0:
            with th.no_grad():  # a predicted state valued above the current one by more than the margin is left out
                q_pess = pessimistic_q(q.view(-1, horizon + 1, batch_size), self.top_k, self.lcb_coef)  # [T+1, B]
                bound = q_pess[0] + margin * q_pess[0].abs().mean()  # [B]
                judged = q_pess[1:]  # [T, B]
                if getattr(self, "lookahead_trust_rule", "value") == "bellman":  # old models: "value"
                    # the rollout read as the critic's own chain: sum_{j<i} gamma^j r_j + gamma^i Q(s_i, a_i)
                    discounts = self._gamma_powers[:, None]  # [T+1, 1]: gamma^i
                    paid = th.cumsum(discounts[:-1] * alive_mask[:-1] * th.stack(rewards), dim=0)  # [T, B]
                    judged = paid + discounts[1:] * judged
                trusted = (judged <= bound).float()  # [T, B]
                q_all = (alive_mask * q_pess).mean(dim=1)  # [T+1]: the diagnostics keep every alive term
            counted = alive_mask * th.cat([th.ones_like(trusted[:1]), trusted])  # [T+1, B]
        confidence = getattr(self, "q_term_confidence", None)  # models saved before the option have none
        confident = None
        if confidence is not None and data_actions is not None:
            with th.no_grad():  # d_j = Q_j(s_t, a_t) - Q_j(s_t, a_data): the state's terms count where mean > k std
                gain = q.view(-1, horizon + 1, batch_size)[:, 0] - self.critic(obs, data_actions)  # [N, B]
                confident = members_agree(gain, confidence).to(counted.dtype)  # [B]
            counted = counted * confident
        objective: Callable[..., tuple[th.Tensor, th.Tensor]] = lookahead_q_objective  # eq. 3/4
        powers = self._lookahead_powers
        if self.lookahead_target == "value_expansion" and horizon > 0:
            objective = functools.partial(  # rewards [T, B]
                value_expansion_objective, rewards=th.stack(rewards), expansion_weight=float(self.lookahead_weight)
            )
            powers = self._gamma_powers
        q_loss, per_step = objective(
            q.view(-1, horizon + 1, batch_size),  # [N, T+1, B]
            alive=counted,
            gamma_powers=powers,
            top_k=self.top_k,
            normalization=self.lookahead_normalization,
            q_scale_floor=self.q_scale_floor_value or 0.0,
            lcb_coef=self.lcb_coef,
        )
        stats = {f"lookahead_q_{i}": per_step[i].detach() for i in range(horizon + 1)}
        if trusted is not None:
            stats.update({f"lookahead_q_{i}": q_all[i] for i in range(horizon + 1)})
            stats["lookahead_trusted"] = trusted.mean()
        stats["action_saturation"] = saturation
        if confident is not None:
            stats["q_term_share"] = confident.mean()
        # the ensemble's spread at the actor's own actions (next to q_ensemble_std at the data's): pessimism
        # protects the actor only where the members disagree more off the data than on it
        stats["policy_q_ensemble_std"] = q.detach().view(-1, horizon + 1, batch_size)[:, 0].std(dim=0).mean()
        stats["lookahead_alive"] = alive_mask[-1].mean()
        if horizon > 0:
            doubt = th.stack(disagreements).mean(dim=1)  # [T]
            if self.lookahead_uncertainty_penalty > 0:
                weights = lookahead_weights(powers, self.lookahead_normalization)[1:]
                q_loss = q_loss + self.lookahead_uncertainty_penalty * (weights * doubt).sum()
            stats.update({f"lookahead_uncertainty_{i + 1}": doubt[i].detach() for i in range(horizon)})
        return q_loss, stats

    def export_policy(self, path: str | os.PathLike[str], format: str = "onnx", **kwargs: Any) -> pathlib.Path:
        """Write the deterministic policy as one static graph that runs without sb3_pola (``sb3-pola export``).

        The graph maps raw observations ``obs`` ``[batch, obs_dim]`` (float32) to the actions
        ``predict(obs, deterministic=True)`` returns, ``action`` ``[batch, action_dim]``: normalisation, state
        products, the noise-free reverse chain of the predict actor unrolled, the clip and the rescaling to
        the action bounds (:mod:`sb3_pola.pola.export`).

        :param path: output file
        :param format: ``"onnx"`` (for ONNX Runtime; needs ``pip install sb3_pola[export]``) or
            ``"torchscript"`` (for ``torch.jit.load``)
        :param kwargs: arguments of :func:`~sb3_pola.pola.export.export_policy` (``opset_version``, ``atol``)
        :raises ~sb3_pola.pola.export.PolicyExportError: the policy cannot be exported, e.g. ``n_action_samples > 1``
        :return: the written file
        """
        return export_policy(self.policy, path, format=format, **kwargs)

    def _clip(self, parameters: Any) -> th.Tensor:
        if self.max_grad_norm is None:
            return th.zeros((), device=self.device)
        return clip_grad_norm_(parameters, self.max_grad_norm)


__all__ = ["POLA", "OfflineReplayBuffer", "ensemble_similarity", "lookahead_q_objective", "lookahead_weights"]
