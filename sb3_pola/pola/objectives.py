"""POLA's loss terms over the algorithm's networks: the critic's TD loss (section IV), the actor's imitation ``L_d``
(eq. 6) and its look-ahead Q term ``L_q`` (eq. 3/4), one step of the dynamics model as the look-ahead takes it.
The pure functions they call are :mod:`sb3_pola.pola.losses`; ``POLA._update`` puts them together."""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable, Iterator

import torch as th
from stable_baselines3.common.type_aliases import Schedule

from sb3_pola.common.compile import CompiledLoss
from sb3_pola.common.input_gradients import explicit_input_gradients, input_gradient_fn
from sb3_pola.common.offline_algorithm import OfflineAlgorithm
from sb3_pola.common.termination import TerminationFn
from sb3_pola.pola.fast_sampling import sample_chain, sample_no_grad
from sb3_pola.pola.losses import (
    advantage_weights,
    ensemble_similarity,
    lookahead_q_objective,
    lookahead_weights,
    pessimistic_q,
    value_expansion_objective,
)
from sb3_pola.pola.policies import DiffusionActor, EnsembleCritic, POLAPolicy, members_agree


class POLAObjectives(OfflineAlgorithm):
    """:class:`~sb3_pola.pola.pola.POLA`'s loss terms (a base of POLA; its arguments are POLA's)."""

    policy: POLAPolicy
    actor: DiffusionActor
    critic: EnsembleCritic
    critic_target: EnsembleCritic
    gamma: float
    eta: float | Schedule
    top_k: int
    lcb_coef: float | None
    rollout_length: int
    reward_scale: float
    target_q_floor_value: float | None
    critic_bc_coef: float
    critic_diversity: float
    critic_diversity_inputs: str
    model_td_weight: float
    model_conservatism: float
    bc_weight_temp: float | None
    bc_max_weight: float
    backprop_through_model: bool
    lookahead_target: str
    lookahead_actions: str
    compile_update: bool
    lookahead_weight: float
    lookahead_normalization: str
    lookahead_uncertainty_penalty: float
    lookahead_uncertainty_cutoff: float | None
    lookahead_trust_margin: float | None
    lookahead_trust_rule: str
    q_term_confidence: float | str | None
    _dense_option: Callable[[str], float | None]  # POLAData's: an option's value as it applies ("auto")
    q_scale_floor_value: float | None
    _goal_mask: th.Tensor | None
    _termination_fn: TerminationFn | None

    def _setup_objectives(self) -> None:
        """The terms' constants and their fast forms, chosen once (``compile_update``); by ``_setup_model``."""
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

    @property
    def _cudagraphs(self) -> bool:
        return self.compile_update and self.device.type == "cuda"

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
        q = self.critic(th.cat(states), th.cat(actions_)).view(-1, horizon + 1, batch_size)  # [N, T+1, B]
        alive_mask = th.stack(alive)  # [T+1, B]
        counted, trusted = alive_mask, None  # counted: the terms eq. 3 sums, [T+1, B]
        margin = self.lookahead_trust_margin
        if margin is not None and horizon > 0:
            with th.no_grad():  # a predicted state valued above the current one by more than the margin is left out
                q_pess = pessimistic_q(q, self.top_k, self.lcb_coef)  # [T+1, B]
                bound = q_pess[0] + margin * q_pess[0].abs().mean()  # [B]
                judged = q_pess[1:]  # [T, B]
                if self.lookahead_trust_rule == "bellman":
                    # the rollout read as the critic's own chain: sum_{j<i} gamma^j r_j + gamma^i Q(s_i, a_i)
                    discounts = self._gamma_powers[:, None]  # [T+1, 1]: gamma^i
                    paid = th.cumsum(discounts[:-1] * alive_mask[:-1] * th.stack(rewards), dim=0)  # [T, B]
                    judged = paid + discounts[1:] * judged
                trusted = (judged <= bound).float()  # [T, B]
                q_all = (alive_mask * q_pess).mean(dim=1)  # [T+1]: the diagnostics keep every alive term
            counted = alive_mask * th.cat([th.ones_like(trusted[:1]), trusted])  # [T+1, B]
        confidence = self._dense_option("q_term_confidence")
        confident = None
        if confidence is not None and data_actions is not None:
            with th.no_grad():  # d_j = Q_j(s_t, a_t) - Q_j(s_t, a_data): the state's terms count where mean > k std
                gain = q[:, 0] - self.critic(obs, data_actions)  # [N, B]
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
            q,
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
        stats["policy_q_ensemble_std"] = q.detach()[:, 0].std(dim=0).mean()
        stats["lookahead_alive"] = alive_mask[-1].mean()
        if horizon > 0:
            doubt = th.stack(disagreements).mean(dim=1)  # [T]
            if self.lookahead_uncertainty_penalty > 0:
                weights = lookahead_weights(powers, self.lookahead_normalization)[1:]
                q_loss = q_loss + self.lookahead_uncertainty_penalty * (weights * doubt).sum()
            stats.update({f"lookahead_uncertainty_{i + 1}": doubt[i].detach() for i in range(horizon)})
        return q_loss, stats

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
