"""sb3_pola.common.input_gradients: the written-out input gradient equals autograd's double backward."""

from __future__ import annotations

import pytest
import torch as th
from torch import nn

from sb3_pola.common.activations import FusedMish, TwiceDifferentiableMish
from sb3_pola.common.input_gradients import (
    _LayerNormGrad,
    _Mish,
    _MishGrad,
    autograd_input_gradients,
    explicit_input_gradients,
    input_gradient_fn,
    mish_second_derivative,
)
from sb3_pola.common.torch_layers import vectorized_mlp
from sb3_pola.pola.losses import ensemble_similarity


def _both(net: nn.Sequential, inputs: th.Tensor, n_last: int) -> list[tuple[th.Tensor, th.Tensor, list[th.Tensor]]]:
    """Q, input gradients and the weight gradients of a loss using both, by each form."""
    results = []
    for fn in (autograd_input_gradients, explicit_input_gradients):
        net.zero_grad()
        q, grads = fn(net, inputs, n_last)
        # a TD-like term, EDAC's similarity and a plain function of the gradients: every path of the graph
        loss = (q - 1.0).pow(2).mean() + ensemble_similarity(grads) + 0.1 * grads.pow(2).sum()
        loss.backward()
        results.append((q.detach(), grads.detach(), [p.grad.clone() for p in net.parameters()]))  # type: ignore[union-attr]
    return results


@pytest.mark.parametrize("activation", [TwiceDifferentiableMish, nn.Mish, nn.ReLU])
@pytest.mark.parametrize("layer_norm", [True, False])
@pytest.mark.parametrize("n_last", [3, 12])
def test_explicit_equals_autograd_float64(activation, layer_norm, n_last):
    th.manual_seed(0)
    net = vectorized_mlp(12, 1, [32, 24, 16], 4, activation, layer_norm=layer_norm).double()
    inputs = 3.0 * th.randn(20, 12, dtype=th.float64)  # wide enough to reach Mish's curved part and ReLU's kink
    (q_ref, g_ref, p_ref), (q, g, p) = _both(net, inputs, n_last)
    assert g.shape == (4, 20, n_last)
    th.testing.assert_close(q, q_ref, rtol=1e-12, atol=1e-12)
    th.testing.assert_close(g, g_ref, rtol=1e-12, atol=1e-12)
    for got, want in zip(p, p_ref, strict=True):
        th.testing.assert_close(got, want, rtol=1e-10, atol=1e-12)


def test_explicit_equals_autograd_float32_paper_size():
    th.manual_seed(1)
    net = vectorized_mlp(69, 1, [256, 256, 256], 10, TwiceDifferentiableMish, layer_norm=True)
    inputs = th.randn(64, 69)
    (q_ref, g_ref, p_ref), (q, g, p) = _both(net, inputs, 3)
    th.testing.assert_close(q, q_ref, rtol=1e-5, atol=1e-5)
    th.testing.assert_close(g, g_ref, rtol=1e-4, atol=1e-5)
    for got, want in zip(p, p_ref, strict=True):
        th.testing.assert_close(got, want, rtol=1e-3, atol=1e-5)


def test_mish_second_derivative():
    x = th.linspace(-40.0, 40.0, 4001, dtype=th.float64, requires_grad=True)
    (first,) = th.autograd.grad(nn.functional.mish(x).sum(), x, create_graph=True)
    (second,) = th.autograd.grad(first.sum(), x)
    th.testing.assert_close(mish_second_derivative(x.detach()), second, rtol=1e-9, atol=1e-12)
    # finite far out, where F.mish's own second derivative overflows to NaN (hence TwiceDifferentiableMish)
    far = th.tensor([100.0, 1e4, -100.0, -1e4])
    assert th.isfinite(mish_second_derivative(far)).all()
    assert mish_second_derivative(far).abs().max() < 1e-10


def test_mish_pieces_and_hand_backwards_pass_gradcheck():
    x = (4.0 * th.randn(6, 5, dtype=th.float64)).requires_grad_(True)
    y, first, _, _ = _Mish.apply(x)
    th.testing.assert_close(y, nn.functional.mish(x.detach()))
    th.testing.assert_close(first, th.ops.aten.mish_backward(th.ones_like(x), x.detach()))
    assert th.autograd.gradcheck(lambda t: _Mish.apply(t)[0], (x,))
    grad = th.randn(6, 5, dtype=th.float64, requires_grad=True)

    def mish_grad(g: th.Tensor, t: th.Tensor) -> th.Tensor:
        _, first, e, r = _Mish.apply(t)
        return _MishGrad.apply(g, t, first, e, r)

    assert th.autograd.gradcheck(mish_grad, (grad, x))


def test_layer_norm_hand_double_backward_passes_gradcheck():
    x = th.randn(3, 4, 7, dtype=th.float64, requires_grad=True)
    grad = th.randn(3, 4, 7, dtype=th.float64, requires_grad=True)

    def layer_norm_grad(g: th.Tensor, t: th.Tensor) -> th.Tensor:
        y, mean, rstd = th.native_layer_norm(t, [t.shape[-1]], None, None, 1e-5)
        return _LayerNormGrad.apply(g, t, y, mean, rstd)

    assert th.autograd.gradcheck(layer_norm_grad, (grad, x))
    # its value is the layer norm's input gradient
    (want,) = th.autograd.grad(nn.functional.layer_norm(x, [7]), x, grad)
    th.testing.assert_close(layer_norm_grad(grad, x), want)


@pytest.mark.parametrize(
    "net, explicit",
    [
        (vectorized_mlp(5, 1, [8, 8], 3, TwiceDifferentiableMish, layer_norm=True), True),
        (vectorized_mlp(5, 1, [8, 8], 3, FusedMish), True),
        (vectorized_mlp(5, 1, [8], 3, nn.ReLU), True),
        (vectorized_mlp(5, 1, [8, 8], 3, nn.Tanh), False),  # no hand-written form: autograd's
        (vectorized_mlp(5, 2, [8], 3, nn.ReLU), False),  # not a Q-network
    ],
)
def test_input_gradient_fn_chooses_once(net, explicit):
    assert (input_gradient_fn(net) is explicit_input_gradients) == explicit
    if not explicit:
        with pytest.raises(ValueError, match="supports"):
            explicit_input_gradients(net, th.randn(4, 5), 2)


def test_pola_critic_uses_the_explicit_form_and_matches_autograd():
    """The model's EDAC update: written out by default, the same loss and weight gradients as autograd's."""
    from sb3_pola import POLA
    from sb3_pola.common.datasets import synthetic_dataset

    model = POLA(
        "MlpPolicy",
        dataset=synthetic_dataset(300, 4, 2),
        n_critics=3,
        batch_size=32,
        rollout_length=0,
        policy_kwargs=dict(net_arch=[16, 16]),
        critic_diversity=1.0,
        seed=0,
    )
    assert model._input_gradients is explicit_input_gradients
    batch = model.replay_buffer.sample(32)
    args = (batch.observations, batch.actions, batch.next_observations, batch.rewards.flatten(), batch.dones.flatten())
    results = []
    for fn in (explicit_input_gradients, autograd_input_gradients):
        model._input_gradients = fn
        model.critic.zero_grad()
        th.manual_seed(3)  # the target's chain draws noise
        loss, stats = model._critic_loss(*args)
        loss.backward()
        results.append((loss.detach(), stats["critic_similarity"], [p.grad.clone() for p in model.critic.parameters()]))
    (loss, sim, grads), (loss_ref, sim_ref, grads_ref) = results
    th.testing.assert_close(loss, loss_ref, rtol=1e-5, atol=1e-6)
    th.testing.assert_close(sim, sim_ref, rtol=1e-5, atol=1e-6)
    for got, want in zip(grads, grads_ref, strict=True):  # float32: EDAC's unit vectors amplify rounding
        assert th.linalg.vector_norm(got - want) <= 1e-3 * th.linalg.vector_norm(want)
