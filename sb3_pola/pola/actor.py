"""The diffusion actor of POLA (paper section V): eq. 6's loss and eq. 5's reverse chain as one plain loop, and the
observation's own chain noise of a deterministic ``predict``. The fast forms of the chain are in
:mod:`sb3_pola.pola.fast_sampling`."""

from __future__ import annotations

import itertools
import math

import torch as th
from torch import nn
from torch.nn import functional as F

from sb3_pola.common.diffusion import NoiseSchedule
from sb3_pola.common.torch_layers import SinusoidalPosEmb


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

    def loss(self, actions: th.Tensor, features: th.Tensor, weights: th.Tensor | None = None) -> th.Tensor:
        """Behaviour-cloning loss ``L_d`` (eq. 6): noise-prediction MSE at a uniformly drawn step (or the clean
        action's MSE under ``prediction_type="sample"``). ``weights``: ``[B]`` per-row weights of the mean (the
        advantage weights of ``POLA(bc_weight_temp=...)``); ``None``: the plain mean."""
        t = th.randint(0, self.n_diffusion_steps, (actions.shape[0],), device=actions.device)
        noise = th.randn_like(actions)
        x_t = self.schedule.add_noise(actions, noise, t)
        # eq. 6: || eps - eps_theta(sqrt(abar_t) a + sqrt(1 - abar_t) eps, s_new, t) ||^2 (a in place of eps for x0)
        target = actions if self.prediction_type == "sample" else noise
        prediction = self.predict_noise(x_t, t, features)
        if weights is None:
            return F.mse_loss(prediction, target)
        return (weights * (prediction - target).pow(2).mean(dim=-1)).mean()  # [B] rows, weighted

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


DETERMINISTIC_RULES = ("observation_noise", "noise_free", "mode")


def densest_sample(samples: th.Tensor, scale: float) -> th.Tensor:
    """``[B]``: the index of each row's sample of highest Gaussian-kernel density among ``samples`` ``[B, K, A]``
    (``scale = -1 / 2h^2``), the mean shift's start."""
    sq_dist = (samples.unsqueeze(2) - samples.unsqueeze(1)).pow(2).sum(dim=-1)  # [B, K, K]
    return th.exp(scale * sq_dist).sum(dim=-1).argmax(dim=1)


def kernel_mode(samples: th.Tensor, bandwidth: float, n_iterations: int = 10) -> th.Tensor:
    """The densest point of each row's samples: mean shift with a Gaussian kernel from the sample of highest
    kernel density (the action of ``deterministic_rule="mode"``).

    On unimodal samples it lands near their mean (the chain's noise averaged out); on a mixture it stays in the
    mode its start lies in, where the samples' mean would fall between the modes.

    :param samples: ``[B, K, A]`` candidate actions of each row
    :param bandwidth: the kernel's standard deviation, in action units
    :param n_iterations: mean-shift steps after the start
    :return: ``[B, A]``
    """
    scale = -0.5 / bandwidth**2
    start = densest_sample(samples, scale)  # [B]
    x = samples.gather(1, start.view(-1, 1, 1).expand(-1, 1, samples.shape[-1]))  # [B, 1, A]
    # mean shift: x <- sum_k w_k a_k with w_k proportional to exp(-|a_k - x|^2 / 2h^2), a softmax over k of
    # (-|a_k|^2 + 2 a_k.x) / 2h^2 (the |x|^2 term is common to all k and cancels)
    sq_norm = scale * samples.pow(2).sum(dim=-1).unsqueeze(1)  # [B, 1, K]
    for _ in range(n_iterations):
        weights = th.softmax(sq_norm - 2.0 * scale * (x @ samples.transpose(1, 2)), dim=-1)  # [B, 1, K]
        x = weights @ samples  # [B, 1, A]
    return x.squeeze(1)


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
