"""The policy of POLA: the diffusion actor (:mod:`~sb3_pola.pola.actor`), its EMA copy, the critic ensemble
(:mod:`~sb3_pola.pola.critic`) and their targets, the dynamics model, and ``predict``."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn
from torch.nn import functional as F

from sb3_pola.common.activations import fused_activation, twice_differentiable
from sb3_pola.common.dynamics import EnsembleDynamics
from sb3_pola.common.torch_layers import StateProductsExtractor
from sb3_pola.pola.actor import (
    DETERMINISTIC_RULES,
    DiffusionActor,
    noise_from_projection,
    observation_noise,
    observation_noise_projection,
)
from sb3_pola.pola.critic import EnsembleCritic
from sb3_pola.pola.fast_sampling import kernel_mode_fast, sample_no_grad


def _check_predict_arguments(
    n_action_samples: int,
    predict_actor: str,
    deterministic_rule: str,
    mode_samples: int,
    mode_bandwidth: float,
    fallback_confidence: float | None,
) -> None:
    """Raise ``ValueError`` for :class:`POLAPolicy`'s ``predict`` arguments out of their range."""
    if n_action_samples < 1:
        raise ValueError(f"n_action_samples must be >= 1, got {n_action_samples}")
    if predict_actor not in ("ema", "online"):
        raise ValueError(f"predict_actor must be 'ema' or 'online', got {predict_actor!r}")
    if deterministic_rule not in DETERMINISTIC_RULES:
        raise ValueError(f"deterministic_rule must be one of {DETERMINISTIC_RULES}, got {deterministic_rule!r}")
    if mode_samples < 1 or mode_bandwidth <= 0:
        raise ValueError(f"mode_samples must be >= 1 and mode_bandwidth > 0, got {mode_samples}, {mode_bandwidth}")
    if fallback_confidence is not None:
        if not np.isfinite(fallback_confidence):
            raise ValueError(f"fallback_confidence must be a finite number or None, got {fallback_confidence}")
        if n_action_samples > 1:
            raise ValueError("fallback_confidence chooses between two actions; it needs n_action_samples=1")


def members_agree(gain: th.Tensor, k: float) -> th.Tensor:
    """``[B]`` bool: where the critic's members agree on a gain, ``mean_j d_j > k std_j d_j`` over ``gain`` ``[N, B]``
    (``d_j = Q_j(s, a) - Q_j(s, a_other)``): the test of ``fallback_confidence`` and of ``q_term_confidence``."""
    return gain.mean(dim=0) > k * gain.std(dim=0)


def choose_confident(q: th.Tensor, action: th.Tensor, fallback: th.Tensor, k: float) -> th.Tensor:
    """``fallback_confidence``'s rule: ``action`` ``[B, A]`` where the critic's members agree it beats ``fallback``
    (:func:`members_agree`), else ``fallback``. ``q`` ``[N, 2B]``: the members' values at the ``B`` actions, then at
    the ``B`` fallbacks (``predict`` and the export graph)."""
    q = q.view(q.shape[0], 2, action.shape[0])  # [N, 2, B]
    take = members_agree(q[:, 0] - q[:, 1], k)  # [B]
    return th.where(take.unsqueeze(1), action, fallback)


class POLAPolicy(BasePolicy):
    """Policy of POLA: diffusion actor on ``s_new`` (state + products), its EMA copy, critic ensemble and targets.

    ``predict`` uses the EMA actor (as Diffusion-QL evaluates). ``deterministic=False`` draws one sample of the
    reverse chain. ``deterministic=True`` must give the same action for the same observation; with one sample
    (``n_action_samples=1``) it follows ``deterministic_rule``: ``"mode"`` (default) draws ``mode_samples`` chains
    with noise that is a fixed function of the observation (:func:`observation_noise`) and returns their kernel
    mode (:func:`~sb3_pola.pola.actor.kernel_mode`), the policy's most likely action, as SB3's Gaussian policies
    return their mean: on unimodal data about the conditional mean, on mixed data a point in the densest mode;
    ``"observation_noise"`` is one such sample (reproducible, but it keeps the chain's noise); ``"noise_free"``
    starts from ``a_T = 0`` and follows the posterior means, which returns about the conditional mean, and so stands
    still between the modes of a symmetric mixture (measurements in docs/results.md, #23's twenty-ninth pass).
    With ``n_action_samples > 1`` it draws that many candidates (candidate 0 noise-free, the others with noise from
    ``predict_seed``, the same for every state) and keeps the one with the highest pessimistic (min over the
    ensemble) Q-value; ``deterministic=False`` then samples one with probabilities ``softmax(Q)`` as Diffusion-QL
    does.

    :param observation_space: a flat ``Box``
    :param action_space: a ``Box``
    :param lr_schedule: learning-rate schedule (actor and critic)
    :param net_arch: hidden sizes, a list for both or ``dict(pi=[...], qf=[...])`` (default 3 x 256 each)
    :param activation_fn: activation of the critics, and of an actor on the state products (Mish, as Diffusion-QL)
    :param actor_activation_fn: the actor's own activation. ``None``: ReLU for an actor on the raw state (the
        default, ``use_state_products=False``), ``activation_fn`` for one on the state products (the paper's form).
        ReLU without the products is d3rlpy BC's piecewise-linear network: it imitates no better offline but acts
        better where the data never go; either piece alone gains little (docs/results.md, #23's twenty-seventh and
        twenty-eighth passes). The policy's own ``save`` names the resolved class
    :param n_critics: critic ensemble size ``N`` (paper: 10)
    :param n_diffusion_steps: denoising steps of the actor (paper and Diffusion-QL: 5)
    :param beta_schedule: noise schedule, ``"vp"``, ``"linear"`` or ``"cosine"``
    :param prediction_type: the actor network's target, ``"epsilon"`` (the noise) or ``"sample"`` (the clean
        action; :class:`DiffusionActor`)
    :param use_state_products: feed the actor ``s_new`` = state + all ``X_i X_j, i < j`` (paper section V; the
        package default is the raw state, #23)
    :param critic_state_products: also give the critics the products (the paper reports this hurts)
    :param critic_layer_norm: LayerNorm in the critics' hidden layers, which bounds Q off the data (ReBRAC, RLPD)
    :param time_embedding_dim: size of the diffusion-step embedding
    :param n_action_samples: candidate actions per state in ``predict``
    :param predict_seed: seed of the candidates' noise in deterministic ``predict`` with ``n_action_samples > 1``
    :param deterministic_rule: the action of a deterministic ``predict`` with one sample: ``"mode"``,
        ``"observation_noise"`` or ``"noise_free"`` (see above)
    :param mode_samples: chain samples per state of the ``"mode"`` rule
    :param mode_bandwidth: its kernel's standard deviation in the actions' ``[-1, 1]`` units (0.4 merged
        halfcheetah/medium-replay's modes and stood still; 0.1 and 0.2 did not)
    :param predict_actor: the actor ``predict`` samples from: ``"ema"`` (Diffusion-QL's evaluation) or
        ``"online"`` (the trained actor itself; the EMA lags it by about ``1 / (1 - ema_decay)`` updates)
    :param fallback_confidence: ``k`` of the confident choice; ``None`` (default) builds none. A second, imitation-only
        diffusion actor (``fallback_actor``, with its own EMA copy) is trained beside POLA's on ``L_d`` alone, and
        ``predict`` runs both and takes POLA's action only where the critic's members agree it is better than the
        imitation actor's: ``mean_j d_j > k std_j d_j``, ``d_j = Q_j(s, a) - Q_j(s, a_bc)`` over the ensemble; the
        imitation actor's elsewhere. ``k = 0`` is the ensemble mean's choice of the two; a larger ``k`` falls back
        more often. Where the critic's gain at its own actions is within its members' spread (the narrow hopper file)
        the Q term's move is noise to the critic itself (docs/results.md, #23's thirty-fifth and thirty-sixth
        passes). Not with ``n_action_samples > 1``
    :param dynamics_kwargs: arguments of :class:`~sb3_pola.common.dynamics.EnsembleDynamics`; ``None`` builds no model
    :param compile_activations: run Mish through a kernel fused by ``torch.compile``
        (:mod:`sb3_pola.common.activations`; same function, float rounding aside, eager fallback)
    :param optimizer_class: optimizer of actor and critic
    :param optimizer_kwargs: extra optimizer arguments
    """

    actor: DiffusionActor
    actor_ema: DiffusionActor
    fallback_actor: DiffusionActor | None
    fallback_actor_ema: DiffusionActor | None
    dynamics_fitted: th.Tensor
    critic: EnsembleCritic
    critic_target: EnsembleCritic

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        net_arch: list[int] | dict[str, list[int]] | None = None,
        activation_fn: type[nn.Module] = nn.Mish,
        actor_activation_fn: type[nn.Module] | None = None,
        n_critics: int = 10,
        n_diffusion_steps: int = 5,
        beta_schedule: str = "vp",
        prediction_type: str = "epsilon",
        use_state_products: bool = False,
        critic_state_products: bool = False,
        critic_layer_norm: bool = False,
        time_embedding_dim: int = 16,
        n_action_samples: int = 1,
        predict_seed: int = 0,
        predict_actor: str = "ema",
        deterministic_rule: str = "mode",
        mode_samples: int = 16,
        mode_bandwidth: float = 0.2,
        fallback_confidence: float | None = None,
        dynamics_kwargs: dict[str, Any] | None = None,
        compile_activations: bool = False,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
    ) -> None:
        if not isinstance(observation_space, spaces.Box) or len(observation_space.shape) != 1:
            raise ValueError(f"POLA needs a flat Box observation space, got {observation_space}")
        if not isinstance(action_space, spaces.Box):
            raise ValueError(f"POLA needs a continuous (Box) action space, got {action_space}")
        super().__init__(
            observation_space,
            action_space,
            features_extractor_class=StateProductsExtractor,
            features_extractor_kwargs={"use_state_products": use_state_products},
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
            normalize_images=False,
            squash_output=True,  # actions live in [-1, 1]; predict() rescales them to the env's bounds
        )
        if net_arch is None:
            net_arch = [256, 256, 256]
        if isinstance(net_arch, dict):
            actor_arch, critic_arch = net_arch["pi"], net_arch["qf"]
        else:
            actor_arch, critic_arch = net_arch, net_arch
        _check_predict_arguments(
            n_action_samples, predict_actor, deterministic_rule, mode_samples, mode_bandwidth, fallback_confidence
        )
        self.predict_actor = predict_actor
        self.deterministic_rule = deterministic_rule
        self.mode_samples = mode_samples
        self.mode_bandwidth = mode_bandwidth
        self.fallback_confidence = fallback_confidence
        self.net_arch = net_arch
        self.activation_fn = activation_fn
        if actor_activation_fn is None:
            actor_activation_fn = activation_fn if use_state_products else nn.ReLU
        self.actor_activation_fn = actor_activation_fn
        self.n_critics = n_critics
        self.n_diffusion_steps = n_diffusion_steps
        self.beta_schedule = beta_schedule
        self.prediction_type = prediction_type
        self.use_state_products = use_state_products
        self.critic_state_products = critic_state_products
        self.critic_layer_norm = critic_layer_norm
        self.time_embedding_dim = time_embedding_dim
        self.n_action_samples = n_action_samples
        self.predict_seed = predict_seed
        self.dynamics_kwargs = dynamics_kwargs
        self.compile_activations = compile_activations
        net_activation = fused_activation(activation_fn) if compile_activations else activation_fn
        action_dim = int(np.prod(action_space.shape))
        obs_dim = int(np.prod(observation_space.shape))

        self.features_extractor = self.make_features_extractor()  # actor's s_new

        def make_actor() -> DiffusionActor:
            return DiffusionActor(
                self.features_extractor.features_dim,
                action_dim,
                actor_arch,
                n_diffusion_steps=n_diffusion_steps,
                beta_schedule=beta_schedule,
                time_embedding_dim=time_embedding_dim,
                activation_fn=fused_activation(actor_activation_fn) if compile_activations else actor_activation_fn,
                prediction_type=prediction_type,
            )

        self.actor = make_actor()
        self.actor_ema = copy.deepcopy(self.actor).requires_grad_(False)
        critic_features = StateProductsExtractor(observation_space, use_state_products=critic_state_products)
        # the critic's similarity term differentiates it twice: Mish in a form whose second derivative is finite
        critic_activation = net_activation if compile_activations else twice_differentiable(activation_fn)
        self.critic = EnsembleCritic(critic_features, action_dim, critic_arch, n_critics, critic_activation, critic_layer_norm)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.critic_target.train(False)
        self.actor_ema.train(False)

        self.dynamics: EnsembleDynamics | None = None
        if dynamics_kwargs is not None:
            self.dynamics = EnsembleDynamics(obs_dim, action_dim, **dynamics_kwargs)
        # whether the dynamics model has been fitted; a buffer so it travels with the weights
        self.register_buffer("dynamics_fitted", th.zeros((), dtype=th.bool))
        # built last, so that the other modules' initial weights do not depend on the option
        self.fallback_actor = None
        self.fallback_actor_ema = None
        if fallback_confidence is not None:
            self.fallback_actor = make_actor()
            self.fallback_actor_ema = copy.deepcopy(self.fallback_actor).requires_grad_(False).train(False)

        self.actor.optimizer = self.optimizer_class(self.actor.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)  # type: ignore[call-arg]
        self.critic.optimizer = self.optimizer_class(self.critic.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)  # type: ignore[call-arg]
        if self.fallback_actor is not None:
            self.fallback_actor.optimizer = self.optimizer_class(  # type: ignore[call-arg]
                self.fallback_actor.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs
            )

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            net_arch=self.net_arch,
            activation_fn=self.activation_fn,
            actor_activation_fn=self.actor_activation_fn,
            n_critics=self.n_critics,
            n_diffusion_steps=self.n_diffusion_steps,
            beta_schedule=self.beta_schedule,
            prediction_type=self.prediction_type,
            use_state_products=self.use_state_products,
            critic_state_products=self.critic_state_products,
            critic_layer_norm=self.critic_layer_norm,
            time_embedding_dim=self.time_embedding_dim,
            n_action_samples=self.n_action_samples,
            predict_seed=self.predict_seed,
            predict_actor=self.predict_actor,
            deterministic_rule=self.deterministic_rule,
            mode_samples=self.mode_samples,
            mode_bandwidth=self.mode_bandwidth,
            fallback_confidence=self.fallback_confidence,
            dynamics_kwargs=self.dynamics_kwargs,
            compile_activations=self.compile_activations,
            lr_schedule=self._dummy_schedule,
            optimizer_class=self.optimizer_class,
            optimizer_kwargs=self.optimizer_kwargs,
        )
        return data

    def set_normalization(self, mean: np.ndarray | th.Tensor, std: np.ndarray | th.Tensor) -> None:
        """Set the state normalisation (dataset mean and std) of the actor and critic inputs."""
        assert isinstance(self.features_extractor, StateProductsExtractor)
        for extractor in (self.features_extractor, self.critic.features_extractor, self.critic_target.features_extractor):
            extractor.set_normalization(th.as_tensor(mean), th.as_tensor(std))

    def actor_features(self, obs: th.Tensor) -> th.Tensor:
        """``s_new``: normalised state with the pairwise products (section V)."""
        return self.features_extractor(obs)

    def forward(self, obs: th.Tensor, deterministic: bool = False) -> th.Tensor:
        return self._predict(obs, deterministic=deterministic)

    def _predict(self, observation: PyTorchObs, deterministic: bool = False) -> th.Tensor:
        assert isinstance(observation, th.Tensor)
        obs = observation.float()
        action = self._actor_action(self.actor_ema if self.predict_actor == "ema" else self.actor, obs, deterministic)
        if self.fallback_actor is None:
            return action
        assert self.fallback_actor_ema is not None and self.fallback_confidence is not None
        fallback_actor = self.fallback_actor_ema if self.predict_actor == "ema" else self.fallback_actor
        fallback = self._actor_action(fallback_actor, obs, deterministic)
        return self.confident_choice(obs, action, fallback, self.fallback_confidence)

    def confident_choice(self, obs: th.Tensor, action: th.Tensor, fallback: th.Tensor, k: float) -> th.Tensor:
        """:func:`choose_confident` between ``action`` and ``fallback`` ``[B, A]`` by this policy's critics."""
        with th.no_grad():
            q = self.critic(th.cat([obs, obs]), th.cat([action, fallback]))  # [N, 2B]
        return choose_confident(q, action, fallback, k)

    def _actor_action(self, actor: DiffusionActor, obs: th.Tensor, deterministic: bool) -> th.Tensor:
        """One actor's action by the policy's rule (``deterministic_rule``, or the best of ``n_action_samples``)."""
        n = self.n_action_samples
        # the fast form of actor.sample (same function, float rounding aside): predict needs no gradient
        if n == 1:
            if deterministic and self.deterministic_rule == "mode":
                return self._mode_action(actor, obs)
            noise = None
            if deterministic and self.deterministic_rule == "observation_noise":
                projection, offset = self._noise_projection(obs.device)
                noise = noise_from_projection(obs, projection, offset, actor.n_diffusion_steps)
            return sample_no_grad(actor, self.actor_features(obs), deterministic=deterministic, noise=noise)
        batch_size = obs.shape[0]
        obs_rep = obs.repeat_interleave(n, dim=0)  # [B * n, obs]
        features = self.actor_features(obs_rep)
        if deterministic:
            noise = self.candidate_noise(actor).repeat(1, batch_size, 1)  # [steps + 1, B * n, A]
            actions = sample_no_grad(actor, features, noise=noise)
        else:
            actions = sample_no_grad(actor, features)  # [B * n, A]
        q = self.critic_target(obs_rep, actions).min(dim=0).values.view(batch_size, n)  # [B, n]
        if deterministic:
            idx = q.argmax(dim=1)
        else:
            idx = th.multinomial(F.softmax(q, dim=1), 1).squeeze(1)
        return actions.view(batch_size, n, -1)[th.arange(batch_size, device=obs.device), idx]

    def _mode_action(self, actor: DiffusionActor, obs: th.Tensor) -> th.Tensor:
        """``deterministic_rule="mode"``: ``mode_samples`` chain samples, each with the observation's own noise,
        and their densest point (:func:`~sb3_pola.pola.actor.kernel_mode`, in its fast form)."""
        k, steps = self.mode_samples, actor.n_diffusion_steps
        projection, offset = self._noise_projection(obs.device, k)
        # [steps + 1, B, k * A] -> [steps + 1, B * k, A]: row b * k + j is sample j of observation b
        noise = noise_from_projection(obs, projection, offset, steps).reshape(steps + 1, obs.shape[0] * k, -1)
        features = self.actor_features(obs).repeat_interleave(k, dim=0)  # [B * k, F]
        samples = sample_no_grad(actor, features, noise=noise).view(obs.shape[0], k, -1)  # [B, k, A]
        return kernel_mode_fast(samples, self.mode_bandwidth)

    def _noise_projection(self, device: th.device, n_samples: int = 1) -> tuple[th.Tensor, th.Tensor]:
        """:func:`~sb3_pola.pola.actor.observation_noise_projection` of this policy for ``n_samples`` chains a
        state, drawn once per seed, size and device (predict is a hot path; the projection depends only on the sizes
        and ``predict_seed``)."""
        key = (self.predict_seed, device, n_samples)
        if getattr(self, "_projection_cache", (None,))[0] != key:
            obs_dim = int(np.prod(self.observation_space.shape))  # type: ignore[arg-type]
            projection, offset = observation_noise_projection(
                obs_dim, self.actor.n_diffusion_steps, self.actor.action_dim * n_samples, self.predict_seed
            )
            self._projection_cache = (key, projection.to(device), offset.to(device))
        return self._projection_cache[1], self._projection_cache[2]

    def candidate_noise(self, actor: DiffusionActor) -> th.Tensor:
        """``[steps + 1, n, A]``: the chain noise of the ``n`` candidates of a deterministic ``predict``, the same for
        every state and batch size: candidate 0 is the noise-free chain (zeros), the others drawn with
        ``predict_seed``. The best of them by the pessimistic critic is the action, so on unimodal data the choice
        can stay at the noise-free action, and on mixed data it moves to a mode instead of the modes' mean."""
        device = self.device
        generator = th.Generator(device="cpu").manual_seed(self.predict_seed)
        shape = (actor.n_diffusion_steps + 1, self.n_action_samples, actor.action_dim)
        noise = th.randn(shape, generator=generator)
        noise[:, 0] = 0.0
        return noise.to(device)

    def set_training_mode(self, mode: bool) -> None:
        # targets and the EMA copy stay in eval mode; they have no dropout/batch-norm, so this is for clarity only.
        # predict() calls this every time: walking every submodule would cost a large part of a single predict
        for module in (self.actor, self.critic, self.fallback_actor):
            if module is not None and module.training != mode:
                module.train(mode)
        self.training = mode


MlpPolicy = POLAPolicy

__all__ = ["DETERMINISTIC_RULES", "DiffusionActor", "EnsembleCritic", "MlpPolicy", "POLAPolicy", "observation_noise"]
