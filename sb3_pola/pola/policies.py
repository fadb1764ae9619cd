"""Networks of POLA: the diffusion actor (paper section V), the critic ensemble (section IV) and the policy that holds them."""

from __future__ import annotations

import copy
import itertools
import math
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn
from torch.nn import functional as F

from sb3_pola.common.activations import fused_activation, twice_differentiable
from sb3_pola.common.diffusion import NoiseSchedule
from sb3_pola.common.dynamics import EnsembleDynamics
from sb3_pola.common.torch_layers import SinusoidalPosEmb, StateProductsExtractor, vectorized_mlp
from sb3_pola.pola.fast_sampling import sample_no_grad


class DiffusionActor(nn.Module):
    """Conditional DDPM over actions in ``[-1, 1]``: the noise predictor ``eps_theta(a_t, s_new, t)`` of eq. 5 / 6.

    The MLP sees ``[a_t, time_embedding(t), state_features]`` (Diffusion-QL's layout). :meth:`sample` and
    :meth:`loss` are the paper's equations as written; :mod:`sb3_pola.pola.fast_sampling` holds the same
    chain in fewer operations, which training and ``predict`` run.

    :param features_dim: size of the state features (``s_new`` with the products)
    :param action_dim: action size
    :param net_arch: hidden layer sizes of the noise predictor
    :param n_diffusion_steps: number of denoising steps
    :param beta_schedule: ``"vp"``, ``"linear"`` or ``"cosine"``
    :param time_embedding_dim: size of the sinusoidal time embedding
    :param activation_fn: activation (Mish in Diffusion-QL)
    :param prediction_type: the network's target: ``"epsilon"``, the noise (eq. 6 as written), or ``"sample"``,
        the clean action (Diffuser's ``predict_epsilon=False``). Under epsilon-prediction the clean-action
        estimate at the noisiest steps divides the network's error by ``sqrt(abar_t)``, small there, while the
        loss weighs those steps least; predicting ``a_0`` makes the noisiest step a plain regressor of the action
    """

    optimizer: th.optim.Optimizer
    step_indices: th.Tensor

    def __init__(
        self,
        features_dim: int,
        action_dim: int,
        net_arch: list[int],
        n_diffusion_steps: int = 5,
        beta_schedule: str = "vp",
        time_embedding_dim: int = 16,
        activation_fn: type[nn.Module] = nn.Mish,
        prediction_type: str = "epsilon",
    ) -> None:
        super().__init__()
        self.features_dim = features_dim
        self.action_dim = action_dim
        self.time_embedding_dim = time_embedding_dim
        self.schedule = NoiseSchedule(n_diffusion_steps, beta_schedule, prediction_type)
        self.time_mlp = nn.Sequential(
            SinusoidalPosEmb(time_embedding_dim),
            nn.Linear(time_embedding_dim, 2 * time_embedding_dim),
            activation_fn(),
            nn.Linear(2 * time_embedding_dim, time_embedding_dim),
        )
        self.input_layer = nn.Linear(action_dim + time_embedding_dim + features_dim, net_arch[0])
        layers: list[nn.Module] = [activation_fn()]
        for in_size, out_size in itertools.pairwise(net_arch):
            layers += [nn.Linear(in_size, out_size), activation_fn()]
        layers.append(nn.Linear(net_arch[-1], action_dim))
        self.trunk = nn.Sequential(*layers)
        self.register_buffer("step_indices", th.arange(n_diffusion_steps), persistent=False)

    @property
    def n_diffusion_steps(self) -> int:
        return self.schedule.n_steps

    @property
    def prediction_type(self) -> str:
        return self.schedule.prediction_type

    def predict_noise(self, x_t: th.Tensor, t: th.Tensor, features: th.Tensor) -> th.Tensor:
        """The network's output for a batch with per-sample steps ``t`` [B]: ``eps_theta(x_t, s_new, t)``, or the
        clean action under ``prediction_type="sample"``."""
        # [B, A + time + F] -> [B, A]
        return self.trunk(self.input_layer(th.cat((x_t, self.time_mlp(t), features), dim=-1)))

    def loss(self, actions: th.Tensor, features: th.Tensor) -> th.Tensor:
        """Behaviour-cloning loss ``L_d`` (eq. 6): noise-prediction MSE at a uniformly drawn step (or the clean
        action's MSE under ``prediction_type="sample"``)."""
        t = th.randint(0, self.n_diffusion_steps, (actions.shape[0],), device=actions.device)
        noise = th.randn_like(actions)
        x_t = self.schedule.add_noise(actions, noise, t)
        # eq. 6: || eps - eps_theta(sqrt(abar_t) a + sqrt(1 - abar_t) eps, s_new, t) ||^2 (a in place of eps for x0)
        target = actions if self.prediction_type == "sample" else noise
        return F.mse_loss(self.predict_noise(x_t, t, features), target)

    def sample(
        self,
        features: th.Tensor,
        generator: th.Generator | None = None,
        deterministic: bool = False,
        noise: th.Tensor | None = None,
    ) -> th.Tensor:
        """Draw actions with the reverse chain (eq. 5), differentiable w.r.t. the parameters and ``features``.

        :param features: ``[B, F]`` state features
        :param generator: draws the chain's noise from this generator (a fixed seed gives reproducible samples)
        :param deterministic: the noise-free chain: start from ``a_T = 0`` and follow the posterior means.
            A fixed noise draw would be deterministic too, but it biases every action the same way
            (on InvertedPendulum it dropped a policy's return from 1000 to 58); the mean path does not.
        :param noise: ``[n + 1, B, A]`` the chain's noise (``a_T`` last), given instead of drawn
        :return: ``[B, A]`` actions in ``[-1, 1]``
        """
        batch_size = features.shape[0]
        shape = (self.n_diffusion_steps + 1, batch_size, self.action_dim)
        if noise is None and not deterministic:
            noise = th.randn(shape, device=features.device, dtype=features.dtype, generator=generator)
        # a_T ~ N(0, I) (0 for the deterministic chain)
        x = th.zeros(shape[1:], device=features.device, dtype=features.dtype) if noise is None else noise[-1]
        for t in reversed(range(self.n_diffusion_steps)):
            out = self.predict_noise(x, self.step_indices[t].expand(batch_size), features)
            # eq. 5: a_{t-1} = mean(a_t, eps_theta(a_t, s_new, t)) + sigma_t z, the mean formed from the predicted a_0
            # clipped to [-1, 1] (Diffusion-QL; the paper's mean without the clip); no noise at the last step
            x = self.schedule.step(out, t, x, None if noise is None else noise[t])
        return x.clamp(-1.0, 1.0)


DETERMINISTIC_RULES = ("observation_noise", "noise_free")


def observation_noise_projection(obs_dim: int, n_steps: int, action_dim: int, seed: int = 0) -> tuple[th.Tensor, th.Tensor]:
    """The fixed float64 projection ``[obs_dim, 2 D]`` and offset ``[2 D]`` of :func:`observation_noise`
    (``D = (n_steps + 1) action_dim``), drawn from ``seed``."""
    n_draws = (n_steps + 1) * action_dim
    generator = th.Generator(device="cpu").manual_seed(seed)
    projection = th.randn(obs_dim, 2 * n_draws, generator=generator, dtype=th.float64)
    offset = th.rand(2 * n_draws, generator=generator, dtype=th.float64) * 1000.0
    return projection, offset


def noise_from_projection(obs: th.Tensor, projection: th.Tensor, offset: th.Tensor, n_steps: int) -> th.Tensor:
    """:func:`observation_noise` from a given projection: uniforms from a sine hash, then Box-Muller."""
    key = obs.to(th.float64) @ projection + offset  # [B, 2D]
    # the classic sine hash; its constant is exact in float32, as an exporter may store a scalar in float32 and
    # the hash magnifies any difference
    hashed = th.sin(key).abs() * 43758.5
    uniform = (hashed - th.floor(hashed)).clamp(1e-12, 1.0 - 1e-12)  # [B, 2D] in (0, 1)
    n_draws = uniform.shape[-1] // 2
    u1, u2 = uniform[:, :n_draws], uniform[:, n_draws:]
    normal = th.sqrt(-2.0 * th.log(u1)) * th.cos(2.0 * math.pi * u2)  # [B, D]
    return normal.to(obs.dtype).reshape(obs.shape[0], n_steps + 1, -1).transpose(0, 1)  # [n_steps + 1, B, A]


def observation_noise(obs: th.Tensor, n_steps: int, action_dim: int, seed: int = 0) -> th.Tensor:
    """``[n_steps + 1, B, A]`` standard normal noise that is a fixed function of each observation (row of ``obs``).

    A deterministic ``predict`` that still draws a sample of the policy: the same observation always gets the same
    chain noise, different observations get independent-looking draws (so no common noise vector shifts every
    action the same way, as one fixed draw for all states does). Uniforms from a sine hash of fixed random
    projections of the observation, in float64, then Box-Muller: plain tensor operations, so the exported graph
    computes the same noise.

    :param obs: ``[B, obs_dim]`` raw observations
    :param n_steps: diffusion steps (the chain uses ``n_steps + 1`` noise vectors)
    :param action_dim: action size
    :param seed: seed of the projections
    """
    projection, offset = observation_noise_projection(obs.shape[-1], n_steps, action_dim, seed)
    return noise_from_projection(obs, projection.to(obs.device), offset.to(obs.device), n_steps)


class EnsembleCritic(nn.Module):
    """``N`` Q-networks as one vectorised module: ``[N, B, in]`` through batched matmuls (paper section IV).

    :param features_extractor: state normalisation (and optional products) shared by all members
    :param action_dim: action size
    :param net_arch: hidden layer sizes of every member
    :param n_critics: ensemble size ``N``
    :param activation_fn: activation
    :param layer_norm: LayerNorm before every hidden activation (bounds Q off the data)
    """

    optimizer: th.optim.Optimizer

    def __init__(
        self,
        features_extractor: StateProductsExtractor,
        action_dim: int,
        net_arch: list[int],
        n_critics: int = 10,
        activation_fn: type[nn.Module] = nn.Mish,
        layer_norm: bool = False,
    ) -> None:
        super().__init__()
        self.features_extractor = features_extractor
        self.n_critics = n_critics
        in_dim = features_extractor.features_dim + action_dim
        self.q_net = vectorized_mlp(in_dim, 1, net_arch, n_critics, activation_fn, layer_norm=layer_norm)

    def forward(self, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """Q-values of every member: ``[B, obs], [B, A] -> [N, B]``."""
        return self.q_values(self.inputs(obs, actions))

    def inputs(self, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """The members' shared input ``[B, in]``: state features, then the action."""
        return th.cat((self.features_extractor(obs), actions), dim=-1)

    def q_values(self, inputs: th.Tensor) -> th.Tensor:
        """``[B, in]`` (one input for all members) or ``[N, B, in]`` (one per member) ``-> [N, B]``."""
        if inputs.dim() == 2:
            inputs = inputs.unsqueeze(0).expand(self.n_critics, -1, -1)  # [N, B, in], no copy
        return self.q_net(inputs).squeeze(-1)


class POLAPolicy(BasePolicy):
    """Policy of POLA: diffusion actor on ``s_new`` (state + products), its EMA copy, critic ensemble and targets.

    ``predict`` uses the EMA actor (as Diffusion-QL evaluates). ``deterministic=False`` draws one sample of the
    reverse chain. ``deterministic=True`` must give the same action for the same observation; with one sample
    (``n_action_samples=1``) it follows ``deterministic_rule``: ``"observation_noise"`` (default) draws the chain
    with noise that is a fixed function of the observation (:func:`observation_noise`), so it is a sample of the
    policy, reproducible, and moves to a mode on mixed data; ``"noise_free"`` starts from ``a_T = 0`` and follows
    the posterior means, which returns about the conditional mean, and so stands still between the modes of a
    symmetric mixture (measurements in docs/results.md). With ``n_action_samples > 1`` it draws that many
    candidates (candidate 0 noise-free, the others with noise from ``predict_seed``, the same for every state)
    and keeps the one with the highest pessimistic (min over the ensemble) Q-value; ``deterministic=False`` then
    samples one with probabilities ``softmax(Q)`` as Diffusion-QL does.

    :param observation_space: a flat ``Box``
    :param action_space: a ``Box``
    :param lr_schedule: learning-rate schedule (actor and critic)
    :param net_arch: hidden sizes, a list for both or ``dict(pi=[...], qf=[...])`` (default 3 x 256 each)
    :param activation_fn: activation of actor and critics (Mish, as Diffusion-QL)
    :param n_critics: critic ensemble size ``N`` (paper: 10)
    :param n_diffusion_steps: denoising steps of the actor (paper and Diffusion-QL: 5)
    :param beta_schedule: noise schedule, ``"vp"``, ``"linear"`` or ``"cosine"``
    :param prediction_type: the actor network's target, ``"epsilon"`` (the noise) or ``"sample"`` (the clean
        action; :class:`DiffusionActor`)
    :param use_state_products: feed the actor ``s_new`` = state + all ``X_i X_j, i < j`` (paper section V)
    :param critic_state_products: also give the critics the products (the paper reports this hurts)
    :param critic_layer_norm: LayerNorm in the critics' hidden layers, which bounds Q off the data (ReBRAC, RLPD)
    :param time_embedding_dim: size of the diffusion-step embedding
    :param n_action_samples: candidate actions per state in ``predict``
    :param predict_seed: seed of the candidates' noise in deterministic ``predict`` with ``n_action_samples > 1``
    :param deterministic_rule: the action of a deterministic ``predict`` with one sample: ``"observation_noise"``
        or ``"noise_free"`` (see above)
    :param predict_actor: the actor ``predict`` samples from: ``"ema"`` (Diffusion-QL's evaluation) or
        ``"online"`` (the trained actor itself; the EMA lags it by about ``1 / (1 - ema_decay)`` updates)
    :param dynamics_kwargs: arguments of :class:`~sb3_pola.common.dynamics.EnsembleDynamics`; ``None`` builds no model
    :param compile_activations: run Mish through a kernel fused by ``torch.compile``
        (:mod:`sb3_pola.common.activations`; same function, float rounding aside, eager fallback)
    :param optimizer_class: optimizer of actor and critic
    :param optimizer_kwargs: extra optimizer arguments
    """

    actor: DiffusionActor
    actor_ema: DiffusionActor
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
        n_critics: int = 10,
        n_diffusion_steps: int = 5,
        beta_schedule: str = "vp",
        prediction_type: str = "epsilon",
        use_state_products: bool = True,
        critic_state_products: bool = False,
        critic_layer_norm: bool = False,
        time_embedding_dim: int = 16,
        n_action_samples: int = 1,
        predict_seed: int = 0,
        predict_actor: str = "ema",
        deterministic_rule: str = "observation_noise",
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
        if n_action_samples < 1:
            raise ValueError(f"n_action_samples must be >= 1, got {n_action_samples}")
        if predict_actor not in ("ema", "online"):
            raise ValueError(f"predict_actor must be 'ema' or 'online', got {predict_actor!r}")
        self.predict_actor = predict_actor
        if deterministic_rule not in DETERMINISTIC_RULES:
            raise ValueError(f"deterministic_rule must be one of {DETERMINISTIC_RULES}, got {deterministic_rule!r}")
        self.deterministic_rule = deterministic_rule
        self.net_arch = net_arch
        self.activation_fn = activation_fn
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
        self.actor = DiffusionActor(
            self.features_extractor.features_dim,
            action_dim,
            actor_arch,
            n_diffusion_steps=n_diffusion_steps,
            beta_schedule=beta_schedule,
            time_embedding_dim=time_embedding_dim,
            activation_fn=net_activation,
            prediction_type=prediction_type,
        )
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

        self.actor.optimizer = self.optimizer_class(self.actor.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)  # type: ignore[call-arg]
        self.critic.optimizer = self.optimizer_class(self.critic.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)  # type: ignore[call-arg]

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            net_arch=self.net_arch,
            activation_fn=self.activation_fn,
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
        n = self.n_action_samples
        actor = self.actor_ema if self.predict_actor == "ema" else self.actor
        # the fast form of actor.sample (same function, float rounding aside): predict needs no gradient
        if n == 1:
            noise = None
            if deterministic and self.deterministic_rule == "observation_noise":
                noise = observation_noise(obs, actor.n_diffusion_steps, actor.action_dim, self.predict_seed)
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
        for module in (self.actor, self.critic):
            if module.training != mode:
                module.train(mode)
        self.training = mode


MlpPolicy = POLAPolicy
