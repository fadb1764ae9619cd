"""The critic ensemble of POLA (paper section IV): ``N`` Q-networks as one vectorised module."""

from __future__ import annotations

import torch as th
from torch import nn

from sb3_pola.common.torch_layers import StateProductsExtractor, VectorizedLinear, vectorized_mlp


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

    @property
    def output_layer(self) -> VectorizedLinear:
        """The members' last linear layer (its bias ``[N, 1, 1]`` sets where Q starts)."""
        layer = self.q_net[-1]
        assert isinstance(layer, VectorizedLinear)
        return layer

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
