"""Network pieces shared by the actor, the critic ensemble and the dynamics ensemble."""

from __future__ import annotations

import math

import gymnasium as gym
import torch as th
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn


class VectorizedLinear(nn.Module):
    """``E`` independent linear layers evaluated as one batched matmul (CORL's ensemble layer).

    Input ``[E, B, in]`` -> output ``[E, B, out]``. Each member is initialised like ``nn.Linear``.

    :param in_features: input size of every member
    :param out_features: output size of every member
    :param ensemble_size: number of members ``E``
    """

    def __init__(self, in_features: int, out_features: int, ensemble_size: int) -> None:
        super().__init__()
        self.in_features = in_features
        self.out_features = out_features
        self.ensemble_size = ensemble_size
        self.weight = nn.Parameter(th.empty(ensemble_size, in_features, out_features))
        self.bias = nn.Parameter(th.empty(ensemble_size, 1, out_features))
        self.reset_parameters()

    def reset_parameters(self) -> None:
        # nn.Linear's default init, member by member (kaiming_uniform with a=sqrt(5) on [out, in]).
        for member in range(self.ensemble_size):
            nn.init.kaiming_uniform_(self.weight[member].T, a=math.sqrt(5))
        bound = 1.0 / math.sqrt(self.in_features)
        nn.init.uniform_(self.bias, -bound, bound)

    def forward(self, x: th.Tensor) -> th.Tensor:
        # [E, B, in] @ [E, in, out] + [E, 1, out] -> [E, B, out]
        return th.baddbmm(self.bias, x, self.weight)

    def extra_repr(self) -> str:
        return f"in_features={self.in_features}, out_features={self.out_features}, ensemble_size={self.ensemble_size}"


def vectorized_mlp(
    in_dim: int,
    out_dim: int,
    net_arch: list[int],
    ensemble_size: int,
    activation_fn: type[nn.Module] = nn.ReLU,
    layer_norm: bool = False,
) -> nn.Sequential:
    """An ensemble of MLPs ``in_dim -> net_arch -> out_dim``, all members in one set of batched matmuls.

    ``layer_norm``: a LayerNorm (no affine parameters, so the members stay independent) before each hidden
    activation; it bounds the features, and so the output, off the data (ReBRAC's and RLPD's critics).
    """
    layers: list[nn.Module] = []
    last = in_dim
    for width in net_arch:
        layers.append(VectorizedLinear(last, width, ensemble_size))
        if layer_norm:
            layers.append(nn.LayerNorm(width, elementwise_affine=False))
        layers.append(activation_fn())
        last = width
    layers.append(VectorizedLinear(last, out_dim, ensemble_size))
    return nn.Sequential(*layers)


class SinusoidalPosEmb(nn.Module):
    """Sinusoidal embedding of the diffusion step ``t`` (as in DDPM / Diffusion-QL).

    :param dim: embedding size (even)
    """

    freqs: th.Tensor

    def __init__(self, dim: int) -> None:
        super().__init__()
        if dim % 2 != 0:
            raise ValueError(f"time embedding size must be even, got {dim}")
        half = dim // 2
        freqs = th.exp(th.arange(half, dtype=th.float32) * -(math.log(10000.0) / max(half - 1, 1)))
        self.register_buffer("freqs", freqs, persistent=False)

    def forward(self, t: th.Tensor) -> th.Tensor:
        # t: [B] -> [B, dim]
        args = t.float()[:, None] * self.freqs[None, :]
        return th.cat((args.sin(), args.cos()), dim=-1)


def pairwise_products(x: th.Tensor) -> th.Tensor:
    """All products ``X_i X_j`` with ``i < j`` (paper, section V), in row-major order of ``(i, j)``.

    ``[..., n] -> [..., n (n - 1) / 2]``.
    """
    n = x.shape[-1]
    i, j = th.triu_indices(n, n, offset=1, device=x.device)
    return x[..., i] * x[..., j]


class StateProductsExtractor(BaseFeaturesExtractor):
    """Normalised state with all pairwise products appended: ``s_new`` of the paper's section V.

    ``(X_1..X_n) -> (X_1..X_n, X_1 X_2, X_1 X_3, ..., X_{n-1} X_n)``, size ``n + n (n - 1) / 2``.
    Normalisation (dataset mean and std, stored as buffers so they travel with the model)
    happens first, so the products are products of standardised dimensions: correlations.

    :param observation_space: a flat ``Box``
    :param use_state_products: append the products (``False`` gives the normalised state alone)
    """

    obs_mean: th.Tensor
    obs_std: th.Tensor
    idx_i: th.Tensor
    idx_j: th.Tensor

    def __init__(self, observation_space: gym.spaces.Box, use_state_products: bool = True) -> None:
        n = int(math.prod(observation_space.shape))
        features_dim = n + n * (n - 1) // 2 if use_state_products else n
        super().__init__(observation_space, features_dim)
        self.use_state_products = use_state_products
        self.register_buffer("obs_mean", th.zeros(n))
        self.register_buffer("obs_std", th.ones(n))
        i, j = th.triu_indices(n, n, offset=1)
        self.register_buffer("idx_i", i, persistent=False)
        self.register_buffer("idx_j", j, persistent=False)

    def set_normalization(self, mean: th.Tensor, std: th.Tensor) -> None:
        self.obs_mean.copy_(th.as_tensor(mean, dtype=th.float32))
        self.obs_std.copy_(th.as_tensor(std, dtype=th.float32))

    def normalize(self, observations: th.Tensor) -> th.Tensor:
        return (observations.flatten(1).float() - self.obs_mean) / self.obs_std

    def forward(self, observations: th.Tensor) -> th.Tensor:
        x = self.normalize(observations)
        if not self.use_state_products:
            return x
        # [B, n] -> [B, n + n(n-1)/2]
        return th.cat((x, x[:, self.idx_i] * x[:, self.idx_j]), dim=-1)
