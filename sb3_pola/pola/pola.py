"""POLA: Policy Optimization by Looking Ahead (Liu & Hofert), in the Stable-Baselines3 mould."""

from __future__ import annotations

import inspect
import os
import pathlib
from typing import Any, ClassVar

import torch as th
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, ReplayBufferSamples, Schedule
from stable_baselines3.common.utils import FloatSchedule, update_learning_rate
from torch.nn.utils import clip_grad_norm_

from sb3_pola.common.buffers import OfflineReplayBuffer
from sb3_pola.common.datasets import DatasetLocation, OfflineDataset
from sb3_pola.common.term_rates import check_term_rate_optimizer, term_rate_step
from sb3_pola.common.termination import TerminationFn, get_termination_fn
from sb3_pola.pola.arguments import PAPER_FORM, check_pola_arguments
from sb3_pola.pola.export import export_policy
from sb3_pola.pola.losses import ensemble_similarity, lookahead_q_objective, lookahead_weights
from sb3_pola.pola.objectives import POLAObjectives
from sb3_pola.pola.policies import DiffusionActor, EnsembleCritic, MlpPolicy, POLAPolicy
from sb3_pola.pola.preparation import POLAData


def _lerp_params(params: Any, target_params: Any, tau: float) -> None:
    """Polyak update ``target <- (1 - tau) target + tau param`` of all tensors in one ``_foreach_lerp_`` call."""
    with th.no_grad():
        th._foreach_lerp_(list(target_params), list(params), tau)


DEFAULT_LEARNING_RATE = 1e-3  # constant, as SB3: a cosine decay to 0 over a short budget starved the Q term (#23)
GRADIENT_RATIO_FREQ = 100  # gradient steps between two measurements of train/q_bc_grad_ratio


class POLA(POLAObjectives, POLAData):
    """Policy Optimization by Looking Ahead: model-based offline RL with a diffusion policy.

    Paper: Y. Liu and M. Hofert, "Policy Optimization by Looking Ahead for Model-based Offline
    Reinforcement Learning". Each gradient step (``train``) does, on a batch from the dataset:

    1. critic: TD regression of every member of the ``n_critics`` ensemble on the pessimistic
       target ``r + gamma (1 - done) min_j Q'_j(s', a')``, ``a'`` from the EMA actor (section IV), plus
       ``critic_diversity`` times EDAC's ensemble similarity of the members' action gradients;
    2. actor: ``L_d + eta * L_q`` where ``L_d`` is the DDPM loss on dataset actions (eq. 6) and
       ``L_q`` the look-ahead loss (eq. 3, 4): the mean of the ``top_k`` smallest ensemble
       Q-values at the current state and at ``rollout_length`` states predicted by the dynamics
       model, weighted by ``gamma^i`` (times ``lookahead_weight`` at the predicted states);
    3. EMA actor and Polyak target critics.

    The loss terms are :class:`~sb3_pola.pola.objectives.POLAObjectives`', the data's preparation and the dynamics
    model's fit :class:`~sb3_pola.pola.preparation.POLAData`'s. The dynamics model (an ensemble of Gaussian MLPs,
    MOPO-style) is fitted on the dataset with holdout early stopping when ``learn`` first starts, then frozen.
    ``rollout_length=0`` is Diffusion-QL with an ensemble critic; ``eta=0`` is behaviour cloning with the diffusion
    actor.

    Choices the paper leaves open, taken from Diffusion-QL (the code POLA builds on): the Q term
    is divided by the detached mean ``|Q|`` of the current-state term (scale invariance); the
    critic loss sums the members' MSEs; targets use the EMA actor's action; gradients of both
    losses are clipped to ``max_grad_norm``. Look-ahead states that a termination rule (the known
    MuJoCo rule for the env, or the model's learned termination head when the env is unknown)
    marks terminal contribute no Q term, and neither do any states after them.

    Defaults that depart from the paper, each chosen by measurements (docs/hyperparameters.md says why, with the
    figures; docs/results.md, issues #12 and #23): ``eta=3.94`` with ``lookahead_weight=1/16``,
    ``critic_layer_norm=True``, ``critic_diversity=1``, ``backprop_through_model=False``, ``prediction_type="sample"``,
    ``use_state_products=False``, a constant ``learning_rate`` of 1e-3, ``target_q_floor="returns"``,
    ``critic_init_value="returns"``, ``eta_gate="critic_maturity"``, ``lookahead_fixed_goal=True``,
    ``goal_switches="relabel"``, ``hindsight_goals=True``, ``q_term_confidence="auto"`` and
    ``bc_top_fraction="auto"`` (on without a ``desired_goal``); the dynamics model fits with beta-NLL and
    ``predict(deterministic=True)`` returns the mode of 16 chain samples drawn with the observation's own noise
    (:class:`~sb3_pola.pola.policies.POLAPolicy`). The paper's form is ``POLA(..., **PAPER_FORM)``.

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
        (``sum_{i<=3} 0.99^i``, the Q weight the paper's ``eta = 1`` gives at ``T = 3`` under ``"first"``), on the
        current state, the predicted states at ``lookahead_weight``; the paper: 1
    :param lookahead_normalization: ``"first"`` (the paper, eq. 3/4 as written; default): the ``T + 1`` weighted
        Q terms are summed and divided by ``mean |Q|`` of the first, so the Q term's weight grows with ``T``;
        ``"weights"``: also divided by ``sum_i gamma^i``, so ``eta`` weighs the Q term the same for every ``T``
    :param lookahead_weight: factor ``lambda`` on eq. 3's terms at the predicted states (weights ``lambda gamma^i``
        for ``i >= 1``, before ``lookahead_normalization``): the predicted states, where the critic never trained,
        pull less than the current state. Default ``1/16``; ``1``: the paper; ``0``: rolled out but pulling nothing.
        With ``lookahead_target="value_expansion"`` it weighs each expansion ``V_h``, ``h >= 1``
    :param q_scale_floor: lower bound of the detached ``mean |Q|`` that divides the Q term. ``None``: Diffusion-QL's
        batch mean alone (the paper; default). ``"auto"``: the dataset's value scale ``mean |r| / (1 - gamma)``, so an
        immature critic pulls in proportion to how far it has learned. A float: that floor
    :param target_q_floor: lower bound of the critic's target. ``"returns"`` (default): the whole target
        ``r + gamma min_j Q_j(s', a')`` floored at the data's discounted return-to-go from the transition
        (:meth:`~sb3_pola.common.datasets.OfflineDataset.returns_to_go`; MCAC, Wilcox et al. 2022), so Q at the data
        starts at the data's values. ``"auto"``: the bootstrapped ``min_j Q_j(s', a')`` floored at the lowest value
        any policy can have on the data's rewards (:func:`~sb3_pola.pola.losses.value_lower_bound`). A float: that
        floor. ``None``: no floor (the paper)
    :param reward_scale: factor on the data's rewards as the critic learns them (as d3rlpy's reward scaler; the
        dynamics model keeps the raw rewards); Q, its targets and the floors are in the scaled units. Default ``1``
    :param critic_init_value: where the critics' output starts: their last layer's bias (members and targets) is
        shifted by this value before the first gradient step. ``"returns"`` (default): the data's mean discounted
        return-to-go, so the critic learns how Q varies around the data's value scale instead of climbing to it. A
        float: that value. ``None``: the layer's own initialisation (the paper)
    :param goal_switches: where a goal-conditioned dataset's ``desired_goal`` changes between a transition's
        observations (:meth:`~sb3_pola.common.datasets.OfflineDataset.goal_switches`; the mazes' collectors draw a
        new goal the step the old one is reached): ``"relabel"`` (default) keeps the old goal and the env's reward of
        it (``compute_reward``, as HER), so the data show what staying at a goal is worth; ``"terminal"`` ends that
        goal's episode; ``None``: the data as recorded (the paper). No effect without a ``desired_goal``
    :param hindsight_goals: also train the critic on a copy of every goal segment relabelled with a goal it passes
        through (:meth:`~sb3_pola.common.datasets.OfflineDataset.with_hindsight_goals`, HER), so it learns what
        leaving a goal costs; the actor imitates the data alone. Default ``True``; ``False``: the data alone (the
        paper). No effect without a ``desired_goal``
    :param critic_diversity: weight ``eta_ES`` of EDAC's ensemble-similarity term in the critic loss
        (:func:`~sb3_pola.pola.losses.ensemble_similarity`): the members' action gradients at the data are pushed
        apart, so the ensemble disagrees, and its minimum is pessimistic, off the data. Default ``1``; ``0``: off (the
        paper). Its input gradients are written out (:mod:`sb3_pola.common.input_gradients`), so the critic loss is
        differentiated once and compiles under ``compile_update`` (Mish or ReLU critics)
    :param critic_diversity_inputs: the gradients the similarity term compares: ``"actions"`` (EDAC,
        ``grad_a Q_i``; default) or ``"states_and_actions"`` (the critic's whole input)
    :param lookahead_uncertainty_penalty: weight ``lambda`` of a MOPO-style penalty added to ``L_q``,
        ``lambda sum_{i>=1} w_i mean(alive * u_i)``, ``u_i`` the disagreement of the dynamics model's elites on the
        step into ``s_{t+i}`` (RMS over state dimensions of their standard deviation, standardised units), ``w_i`` the
        look-ahead weights. ``0``: off (the paper)
    :param lookahead_uncertainty_cutoff: look-ahead states reached through a step with disagreement above
        this value contribute no Q term, and neither do later ones (as a terminal state). ``None``: off
    :param lookahead_trust_margin: ``m``: a predicted state's term of eq. 3 counts, sample by sample, only where its
        pessimistic Q is at most the current state's plus ``m`` times the batch's mean ``|Q(s_t, a_t)|``: a predicted
        state the critic values above the current one is more likely its extrapolation than a better future. Logged
        as ``train/lookahead_trusted``. ``None``: every term counts (the paper; default). Needs
        ``lookahead_target="q"``
    :param lookahead_trust_rule: what ``lookahead_trust_margin`` holds against the current state's pessimistic Q:
        ``"value"`` (default), the predicted state's own; ``"bellman"``, the value the rollout implies for the current
        state, the model's discounted rewards on the way (while alive) plus ``gamma^i Q(s_{t+i}, a_{t+i})``
    :param lcb_coef: ``k`` of a lower confidence bound ``mean - k std`` over the ensemble used in the policy loss
        in place of the mean of the ``top_k`` smallest members (:func:`~sb3_pola.pola.losses.lookahead_q_objective`).
        ``None``: top-K
    :param critic_bc_coef: ReBRAC's critic penalty ``beta``: the bootstrapped ``min_j Q'_j(s', a')`` pays
        ``beta ||a' - a'_data||^2`` (summed over the action's dimensions), ``a'_data`` the data's next action in the
        episode (none at an episode's last step), in the critic's units, before ``target_q_floor``. ``0``: no penalty
        (the paper; default). ReBRAC uses 0.01 on hopper-medium, 0.5 on hopper-medium-replay
    :param q_term_confidence: ``k``: each state's terms of eq. 3/4 (the current state and its predicted states) count
        only where the critic's members agree the actor's action beats the data's, ``mean_j d_j > k std_j d_j`` with
        ``d_j = Q_j(s, a_t) - Q_j(s, a_data)`` (no gradient); elsewhere the actor only imitates (the policy option
        ``fallback_confidence``'s test, made while training one actor). For dense rewards: on sparse ones the members
        rarely agree. Logged as ``train/q_term_share``. ``"auto"`` (default): ``1.0`` where the data have no
        ``desired_goal`` and ``n_critics >= 2``, else ``None``. ``None``: every state counts (the paper). A number
        needs ``n_critics >= 2``
    :param critic_layer_norm: LayerNorm in the critics' hidden layers (ReBRAC): it bounds Q off the data, so the Q term
        can pull at the paper's strength without the actor climbing the critic's extrapolation. Passed to the policy
        (a ``critic_layer_norm`` in ``policy_kwargs`` takes precedence). Default ``True``; ``False``: the paper
    :param eta_gate: ``"critic_maturity"`` (default): each step's ``eta`` is multiplied by
        ``clip((Q - G_min) / (f (G - G_min)), 0, 1)``, ``Q`` the ensemble's mean at the batch's data, ``G`` and
        ``G_min`` the mean and the lowest discounted return-to-go of the dataset, ``f`` = ``eta_gate_fraction``: the
        Q term waits while the critic's Q at the data is below the data's lowest value (sparse rewards, early
        training). Logged as ``train/critic_maturity``. ``None``: ``eta`` as given (the paper)
    :param eta_gate_fraction: ``f`` of the ``"critic_maturity"`` gate: the Q term is fully open once ``Q`` has covered
        this fraction of the way from ``G_min`` to ``G``. Default ``0.1``
    :param lookahead_fixed_goal: on goal-conditioned data (a ``desired_goal`` key), the look-ahead's predicted states
        keep the state's own ``desired_goal``: the task does not change in imagination, as it does not in the
        evaluation (the model fitted on the mazes learned the collectors' goal jumps). Default ``True``; ``False``:
        the model's prediction (the paper). No effect without a ``desired_goal``
    :param lookahead_target: how the look-ahead judges the predicted states. ``"q"`` (the paper, eq. 3; default): the
        critic's Q at each. ``"value_expansion"``: the model's predicted rewards up to each and the critic's Q there,
        ``V_h = sum_{i<h} gamma^i r_i + gamma^h Q(s_{t+h}, a_{t+h})`` for ``h = 0..T`` (MVE;
        :func:`~sb3_pola.pola.losses.value_expansion_objective`), each an estimate of ``Q(s_t, a_t)``;
        ``lookahead_normalization`` sums or averages them
    :param lookahead_actions: who acts at the predicted states: ``"actor"`` (the paper; default), so eq. 3's terms
        there train its action by Q alone; ``"ema"``, the EMA actor as a fixed function of the state, so the
        look-ahead trains only ``a_t`` through where the model says it leads; needs ``backprop_through_model=True``
    :param model_td_weight: weight of a second TD loss in the critic's, on the transitions of ``T``-step model rollouts
        of the EMA actor from the batch's next states (as MBPO and MOPO), with the model's reward and termination;
        the mean over the rollouts' rows that have not ended. ``0``: off (the paper; default). No effect at ``T = 0``
    :param model_conservatism: weight ``beta`` of COMBO's conservative term in the critic's loss (Yu et al., 2021):
        ``beta (mean Q at the model rollouts' states and the EMA actor's actions - mean Q at the data's (s, a))`` per
        member, the rollouts as for ``model_td_weight``. ``0``: off (the paper; default). No effect at ``T = 0``
    :param backprop_through_model: ``True`` (paper eq. 3): the actor's gradient flows through the dynamics model into
        earlier actions, since ``s_{t+i}`` depends on ``a_{t+i-1}``. ``False`` (default): look-ahead states are
        detached, so each Q term only trains the action taken at its state
    :param n_diffusion_steps: denoising steps of the diffusion actor
    :param beta_schedule: noise schedule: ``"vp"`` (default), ``"linear"`` or ``"cosine"``
    :param prediction_type: the actor network's target: ``"epsilon"``, the noise (eq. 6 as written), or
        ``"sample"``, the clean action (default; :class:`~sb3_pola.pola.policies.DiffusionActor`)
    :param use_state_products: give the actor the pairwise state products (section V). Default ``False``: the raw
        state, with a ReLU actor unless ``policy_kwargs`` names its ``actor_activation_fn``
    :param critic_learning_rate: the critics' own learning rate, a float or a schedule, as d3rlpy's
        ``critic_learning_rate`` (``None``, the default: ``learning_rate``, as SB3)
    :param bc_learning_rate: the behaviour-cloning term's own rate in the actor's step, a float or a schedule
        (``None``, the default: ``learning_rate``): the actor's Adam keeps one second moment for the summed gradient
        of ``L_d + eta L_q`` (eq. 6) and moves ``L_d``'s part at this rate, ``eta L_q``'s at ``learning_rate``
        (:mod:`~sb3_pola.common.term_rates`); with ``eta = 0`` it is the actor's rate. Needs Adam or AdamW
    :param bc_weight_temp: temperature ``beta`` of advantage-weighted imitation (AWR, as IQL's and AWAC's actors):
        each row of ``L_d`` (eq. 6) is weighted by ``exp(beta A)``, ``A = Q(s, a) - Q(s, a_ema)`` the pessimistic
        critic's advantage of the data's action over the EMA actor's, in units of the batch's standard deviation,
        normalised to mean 1 (:func:`~sb3_pola.pola.losses.advantage_weights`); with ``eta_gate`` it opens with
        ``eta``. ``None`` (default): the plain mean (the paper); ``0``: the same weights, all 1. Costs one more chain
        of the EMA actor and one critic call a step
    :param bc_max_weight: upper clip of the advantage weights (relative to their mean of 1). Default ``20``
    :param bc_top_fraction: the actor's batches (its ``L_d`` and its Q term's states) come from this fraction of the
        episodes, the best by return (filtered BC, the Decision Transformer paper's %BC), the critics' from every
        transition. For dense rewards: a maze's collector switches goals, so its episodes' returns do not rank how a
        policy holds one. ``"auto"`` (default): ``0.1`` where the data have no ``desired_goal``, else ``None``.
        ``None``: every episode (the paper)
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
        configuration, fit arguments and seed loads it and trains exactly as after the fit
        (:mod:`~sb3_pola.common.dynamics_cache`); without a seed, any kept fit of the same data and configuration is
        loaded. ``False``: always fit, keep nothing
    :param compile_update: compile the critic and actor losses (forward and backward) with ``torch.compile`` for the
        static shapes of training, and on CUDA capture them as CUDA graphs. The first gradient step compiles; random
        draws match eager PyTorch (``fallback_random``), so results are the eager update's up to float rounding. It
        turns on the policy's ``compile_activations`` unless ``policy_kwargs`` says otherwise. ``False``: eager
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
        q_term_confidence: float | str | None = "auto",
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
        bc_top_fraction: float | str | None = "auto",
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
        arguments = locals()  # POLA's own arguments, checked before anything is loaded or built
        check_pola_arguments(**{name: arguments[name] for name in inspect.signature(check_pola_arguments).parameters})
        # read while the base class loads the dataset (_prepare_offline_data), so set before it
        self.goal_switches = goal_switches
        self.hindsight_goals, self.bc_top_fraction = hindsight_goals, bc_top_fraction
        self._init_data_state()
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
        self.n_critics, self.top_k, self.rollout_length = n_critics, top_k, rollout_length
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
        self.critic_diversity, self.critic_diversity_inputs = critic_diversity, critic_diversity_inputs
        self.lookahead_uncertainty_penalty = lookahead_uncertainty_penalty
        self.lookahead_uncertainty_cutoff = lookahead_uncertainty_cutoff
        self.lookahead_trust_margin, self.lookahead_trust_rule = lookahead_trust_margin, lookahead_trust_rule
        self.lcb_coef = lcb_coef
        self.critic_bc_coef = critic_bc_coef
        self.q_term_confidence = q_term_confidence
        self.eta_gate, self.eta_gate_fraction = eta_gate, eta_gate_fraction
        self.lookahead_fixed_goal = lookahead_fixed_goal
        self.lookahead_target = lookahead_target
        self.lookahead_actions = lookahead_actions
        self.model_td_weight, self.model_conservatism = model_td_weight, model_conservatism
        self.backprop_through_model = backprop_through_model
        self.n_diffusion_steps = n_diffusion_steps
        self.beta_schedule, self.prediction_type = beta_schedule, prediction_type
        self.use_state_products = use_state_products
        self.max_grad_norm = max_grad_norm
        self.critic_learning_rate, self.bc_learning_rate = critic_learning_rate, bc_learning_rate
        self.bc_weight_temp, self.bc_max_weight = bc_weight_temp, bc_max_weight
        self.ema_decay, self.ema_update_freq, self.ema_start = ema_decay, ema_update_freq, ema_start
        self.dynamics_kwargs = dynamics_kwargs or {}
        self.dynamics_fit_kwargs = dynamics_fit_kwargs or {}
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
        self.bc_lr_schedule = None if self.bc_learning_rate is None else FloatSchedule(self.bc_learning_rate)
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
        self._setup_objectives()
        if self.bc_lr_schedule is not None:
            check_term_rate_optimizer(self.actor.optimizer)

    def _create_aliases(self) -> None:
        self.actor = self.policy.actor
        self.critic = self.policy.critic
        self.critic_target = self.policy.critic_target

    @property
    def critic_layer_norm(self) -> bool:
        """Whether the critics have LayerNorm (the policy's setting; ``False`` in a file saved before the argument)."""
        return bool(self.policy_kwargs.get("critic_layer_norm", False))

    def _excluded_save_params(self) -> list[str]:
        # rebuilt by _setup_model and before training, or read from the data again
        rebuilt = """actor critic critic_target _termination_fn _gamma_powers _lookahead_powers _eta_value _bc_temp_value
            _sample_actor _sample_lookahead _sample_target _input_gradients _critic_loss_fn _data_returns
            _next_data_mask _goal_mask _n_imitation_rows _imitation_rows _bc_loss_fn _q_term_fn _fallback_loss_fn _bc_lr
            eta_schedule critic_lr_schedule bc_lr_schedule"""
        return [*super()._excluded_save_params(), *rebuilt.split()]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        fallback = ["policy.fallback_actor.optimizer"] if self.policy.fallback_actor is not None else []
        return ["policy", "actor.optimizer", "critic.optimizer", *fallback], []

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
            rows = self._actor_indices(buffer, batch_size)  # the actor's own rows: hindsight copies, bc_top_fraction
            actor_batch = None if rows is None else (buffer.observations[rows], buffer.actions[rows])
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


__all__ = [
    "PAPER_FORM",
    "POLA",
    "OfflineReplayBuffer",
    "check_pola_arguments",
    "ensemble_similarity",
    "lookahead_q_objective",
    "lookahead_weights",
]
