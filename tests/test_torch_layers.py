import gymnasium as gym
import numpy as np
import torch as th
from torch import nn

from sb3_pola.common.torch_layers import StateProductsExtractor, VectorizedLinear, vectorized_mlp


def test_vectorized_linear_equals_loop_of_linears():
    th.manual_seed(0)
    layer = VectorizedLinear(5, 3, ensemble_size=4)
    x = th.randn(4, 7, 5)
    out = layer(x)
    for member in range(4):
        single = nn.Linear(5, 3)
        single.weight.data = layer.weight[member].T.clone()
        single.bias.data = layer.bias[member, 0].clone()
        assert th.allclose(out[member], single(x[member]), atol=1e-6)


def test_vectorized_mlp_members_are_independent():
    th.manual_seed(0)
    net = vectorized_mlp(4, 1, [8, 8], ensemble_size=3)
    x = th.randn(3, 5, 4)
    out = net(x)
    assert out.shape == (3, 5, 1)
    # changing member 1's input leaves members 0 and 2 unchanged
    x2 = x.clone()
    x2[1] += 1.0
    out2 = net(x2)
    assert th.equal(out[0], out2[0]) and th.equal(out[2], out2[2]) and not th.equal(out[1], out2[1])
    # members start different (independent init)
    assert not th.equal(net[0].weight[0], net[0].weight[1])


def test_state_products_values_and_order():
    extractor = StateProductsExtractor(gym.spaces.Box(-np.inf, np.inf, (4,), np.float32))  # mean 0, std 1
    x = th.tensor([[1.0, 2.0, 3.0, 4.0]])
    products = th.tensor([[2.0, 3.0, 4.0, 6.0, 8.0, 12.0]])  # (0,1) (0,2) (0,3) (1,2) (1,3) (2,3)
    assert th.equal(extractor(x), th.cat((x, products), dim=-1))


def test_state_products_extractor_shapes_and_normalisation():
    for n, expected in [(11, 66), (17, 153)]:  # Hopper, HalfCheetah/Walker2d (paper section V)
        space = gym.spaces.Box(-np.inf, np.inf, (n,), np.float32)
        assert StateProductsExtractor(space).features_dim == expected
        assert StateProductsExtractor(space, use_state_products=False).features_dim == n
    space = gym.spaces.Box(-np.inf, np.inf, (3,), np.float32)
    extractor = StateProductsExtractor(space)
    extractor.set_normalization(th.tensor([1.0, 2.0, 3.0]), th.tensor([2.0, 2.0, 2.0]))
    obs = th.tensor([[3.0, 4.0, 7.0]])
    z = th.tensor([[1.0, 1.0, 2.0]])
    assert th.allclose(extractor(obs), th.cat([z, th.tensor([[1.0, 2.0, 2.0]])], dim=1))
    # statistics travel with the state dict
    assert set(extractor.state_dict()) == {"obs_mean", "obs_std"}
