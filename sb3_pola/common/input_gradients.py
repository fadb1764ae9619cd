"""The critic ensemble's Q-values and their gradients with respect to the last inputs (the action), as a graph that
training differentiates once: the fast form of EDAC's similarity term (:func:`~sb3_pola.pola.losses.ensemble_similarity`).

The term needs ``g_i = grad_a Q_i(s, a)`` as a differentiable function of the weights. The readable form,
:func:`autograd_input_gradients`, asks autograd for it with ``create_graph=True``; the critic's loss is then
differentiated twice, through PyTorch's generic double-backward formulas of Mish and LayerNorm (tens of elementwise
passes per layer). :func:`explicit_input_gradients` writes that first backward pass out layer by layer instead,
with fused native kernels (``mish_backward``, ``native_layer_norm_backward``) wrapped in autograd functions whose
own backward is written by hand (Mish's second derivative; LayerNorm's double backward without affine
parameters). Same values and the same weight gradients, float rounding aside (tests/test_input_gradients.py);
:func:`input_gradient_fn` chooses the form once, for the ensembles it supports.
"""

from __future__ import annotations

from collections.abc import Callable

import torch as th
from torch import nn
from torch.autograd.function import FunctionCtx, once_differentiable

from sb3_pola.common.activations import EXP_CLAMP, FusedMish, TwiceDifferentiableMish, eager_activations
from sb3_pola.common.torch_layers import VectorizedLinear

InputGradientFn = Callable[[nn.Sequential, th.Tensor, int], tuple[th.Tensor, th.Tensor]]
MISH_TYPES = (nn.Mish, TwiceDifferentiableMish, FusedMish)


def autograd_input_gradients(q_net: nn.Sequential, inputs: th.Tensor, n_last: int) -> tuple[th.Tensor, th.Tensor]:
    """Q-values ``[N, B]`` and ``dQ_i / d inputs[..., -n_last:]`` ``[N, B, n_last]`` by ``autograd.grad`` with
    ``create_graph=True`` (the reference form).

    :param q_net: the ensemble (:func:`~sb3_pola.common.torch_layers.vectorized_mlp`, output size 1)
    :param inputs: ``[B, in]``, the input shared by every member
    :param n_last: how many trailing input dimensions to differentiate with respect to (the action's size)
    """
    first_layer = q_net[0]
    assert isinstance(first_layer, VectorizedLinear)
    n_members = first_layer.ensemble_size
    # a copy of the input per member, so that each member's input gradient is its own
    per_member = inputs.unsqueeze(0).expand(n_members, -1, -1).clone().requires_grad_(True)  # [N, B, in]
    with eager_activations():  # Mish whose second derivative stays finite
        q = q_net(per_member).squeeze(-1)  # [N, B]
    (grads,) = th.autograd.grad(q.sum(), per_member, create_graph=True)  # [N, B, in]
    return q, grads[..., -n_last:]


def mish_second_derivative(x: th.Tensor) -> th.Tensor:
    """``mish''(x)`` (the reference form of :class:`_MishGrad`'s backward; module docstring of :class:`_Mish`)."""
    e = th.exp(x.clamp(max=EXP_CLAMP))
    return _mish_second(x, e, th.reciprocal(e * (e + 2.0) + 2.0))


def _mish_second(x: th.Tensor, e: th.Tensor, r: th.Tensor) -> th.Tensor:
    # mish'' = 2 t' + x t'' = 4 e r^2 (2 (e + 1) + x (2 e + 1 - 4 e (e + 1)^2 r))
    e1 = e + 1.0
    inner = th.addcmul(e1, e, (e1 * e1).mul_(r), value=-4.0).add_(e)  # 2 e + 1 - 4 e (e + 1)^2 r
    inner = th.addcmul(e1, inner, x, value=0.5)  # (e + 1) + x (...) / 2
    return inner.mul_(e).mul_(r).mul_(r).mul_(8.0)


class _Mish(th.autograd.Function):
    """Mish, and the pieces its derivatives reuse, from one ``exp``: with ``e = e^x``, ``n = e (e + 2)`` and
    ``r = 1 / (n + 2)``, ``tanh(softplus(x)) = t = n r``, ``t' = 4 e (e + 1) r^2``, ``mish = x t``,
    ``mish' = t + x t'`` and ``mish'' = 2 t' + x t''`` with ``t'' = 4 e r^2 (2 e + 1 - 4 e (e + 1)^2 r)``.
    ``e`` is clamped as in :func:`~sb3_pola.common.activations.mish_exp` (finite for any ``x``).

    Returns ``(mish(x), mish'(x), e, r)``; only the first is differentiable.
    """

    @staticmethod
    def forward(ctx: FunctionCtx, x: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
        e = x.clamp(max=EXP_CLAMP).exp_()
        n = (e + 2.0).mul_(e)
        r = (n + 2.0).reciprocal_()
        t = n.mul_(r)
        first = th.addcmul(t, (e + 1.0).mul_(e).mul_(r).mul_(r), x, value=4.0)  # t + x t'
        ctx.save_for_backward(first)
        ctx.mark_non_differentiable(first, e, r)
        return x * t, first, e, r

    @staticmethod
    @once_differentiable
    def backward(ctx: FunctionCtx, grad: th.Tensor, *_: th.Tensor) -> th.Tensor:
        (first,) = ctx.saved_tensors  # type: ignore[attr-defined]
        return grad * first


class _MishGrad(th.autograd.Function):
    """``grad * mish'(x)``, differentiable once more: by hand, with ``mish''`` (from :class:`_Mish`'s pieces)."""

    @staticmethod
    def forward(ctx: FunctionCtx, grad: th.Tensor, x: th.Tensor, first: th.Tensor, e: th.Tensor, r: th.Tensor) -> th.Tensor:
        ctx.save_for_backward(grad, x, first, e, r)
        return grad * first

    @staticmethod
    @once_differentiable
    def backward(ctx: FunctionCtx, upstream: th.Tensor) -> tuple[th.Tensor | None, th.Tensor | None, None, None, None]:
        grad, x, first, e, r = ctx.saved_tensors  # type: ignore[attr-defined]
        needs_grad, needs_x = ctx.needs_input_grad[:2]  # type: ignore[attr-defined]
        d_grad = upstream * first if needs_grad else None
        d_x = _mish_second(x, e, r).mul_(upstream).mul_(grad) if needs_x else None
        return d_grad, d_x, None, None, None


class _LayerNormGrad(th.autograd.Function):
    """The input gradient of a LayerNorm without affine parameters (one native kernel), differentiable once more.

    ``dx = rstd P g`` with the projection ``P g = g - mean(g) - y mean(g y)``, ``y`` the normalised input. Its
    derivative: with respect to ``g``, ``rstd P v`` (``P`` is symmetric: the same kernel); with respect to ``x``,
    ``-rstd^2 (mean(v P g) y + mean(g y) P v + mean(v y) P g)`` (from ``d rstd / dx = -rstd^2 y / H`` and
    ``dy / dx = rstd P``).
    """

    @staticmethod
    def forward(ctx: FunctionCtx, grad: th.Tensor, x: th.Tensor, y: th.Tensor, mean: th.Tensor, rstd: th.Tensor) -> th.Tensor:
        first = th.ops.aten.native_layer_norm_backward(grad, x, [x.shape[-1]], mean, rstd, None, None, [True, False, False])[0]
        ctx.save_for_backward(grad, x, y, mean, rstd, first)
        return first

    @staticmethod
    @once_differentiable
    def backward(ctx: FunctionCtx, upstream: th.Tensor) -> tuple[th.Tensor | None, th.Tensor | None, None, None, None]:
        grad, x, y, mean, rstd, first = ctx.saved_tensors  # type: ignore[attr-defined]
        needs_grad, needs_x = ctx.needs_input_grad[:2]  # type: ignore[attr-defined]
        p_v = th.ops.aten.native_layer_norm_backward(upstream, x, [x.shape[-1]], mean, rstd, None, None, [True, False, False])[
            0
        ]  # rstd P v
        d_x = None
        if needs_x:  # with P g = first / rstd: -(rstd^2 mean(v P g) y + rstd mean(g y) (rstd P v) + rstd mean(v y) first)
            v_pg = (upstream * first).mean(-1, keepdim=True).mul_(rstd)  # rstd^2 mean(v P g): [N, B, 1]
            g_y = (grad * y).mean(-1, keepdim=True).mul_(rstd)
            v_y = (upstream * y).mean(-1, keepdim=True).mul_(rstd)
            d_x = (p_v * g_y).addcmul_(y, v_pg).addcmul_(first, v_y).neg_()
        return (p_v if needs_grad else None), d_x, None, None, None


def _layer_kinds(q_net: nn.Sequential) -> list[tuple[VectorizedLinear, bool, str]] | None:
    """``(linear, layer_norm, activation)`` per hidden layer (activation ``"mish"`` or ``"relu"``) and the output
    layer as the last entry (no norm, ``""``), or ``None`` for a layout :func:`explicit_input_gradients` lacks."""
    modules = list(q_net)
    layers: list[tuple[VectorizedLinear, bool, str]] = []
    i = 0
    while i < len(modules):
        linear = modules[i]
        if not isinstance(linear, VectorizedLinear):
            return None
        i += 1
        if i == len(modules):
            layers.append((linear, False, ""))
            return layers if linear.out_features == 1 else None
        norm = isinstance(modules[i], nn.LayerNorm)
        if norm:
            layer_norm = modules[i]
            if layer_norm.elementwise_affine or layer_norm.eps != 1e-5:
                return None
            i += 1
        if isinstance(modules[i], MISH_TYPES):
            layers.append((linear, norm, "mish"))
        elif isinstance(modules[i], nn.ReLU):
            layers.append((linear, norm, "relu"))
        else:
            return None
        i += 1
    return None


def explicit_input_gradients(q_net: nn.Sequential, inputs: th.Tensor, n_last: int) -> tuple[th.Tensor, th.Tensor]:
    """:func:`autograd_input_gradients` with the input gradient's backward pass written out (module docstring).

    Supports :func:`~sb3_pola.common.torch_layers.vectorized_mlp` ensembles with Mish or ReLU and optional
    LayerNorm (no affine parameters); :func:`input_gradient_fn` checks that before choosing it.
    """
    layers = _layer_kinds(q_net)
    if layers is None:
        raise ValueError("explicit_input_gradients supports vectorized_mlp ensembles with Mish or ReLU")
    n_members = layers[0][0].ensemble_size
    h = inputs.unsqueeze(0).expand(n_members, -1, -1)  # [N, B, in], a view: the input needs no gradient here
    saved: list[tuple[th.Tensor, th.Tensor | None, th.Tensor | None, th.Tensor, tuple[th.Tensor, ...]]] = []
    for linear, norm, activation in layers[:-1]:
        z = linear(h)  # [N, B, H]
        mean = rstd = None
        u = z
        if norm:
            u, mean, rstd = th.native_layer_norm(z, [z.shape[-1]], None, None, 1e-5)
        pieces: tuple[th.Tensor, ...] = ()
        if activation == "mish":
            h, *pieces = _Mish.apply(u)
        else:
            h = th.relu(u)
        saved.append((z, mean, rstd, u, pieces))
    out = layers[-1][0]
    q = out(h).squeeze(-1)  # [N, B]
    # the backward pass of sum(Q_i) to the input, each step differentiable once more
    delta = out.weight.transpose(1, 2).expand(-1, h.shape[1], -1)  # dQ/dh: [N, 1, H] -> [N, B, H]
    for (linear, norm, activation), (z, mean, rstd, u, pieces) in zip(reversed(layers[:-1]), reversed(saved), strict=True):
        delta = _MishGrad.apply(delta, u, *pieces) if activation == "mish" else delta * (u > 0)
        if norm:
            delta = _LayerNormGrad.apply(delta, z, u, mean, rstd)
        weight = linear.weight if linear is not layers[0][0] else linear.weight[:, -n_last:, :]  # [N, in, H]
        delta = th.bmm(delta, weight.transpose(1, 2))  # [N, B, in] (the first layer: only the last n_last inputs)
    return q, delta


def input_gradient_fn(q_net: nn.Sequential) -> InputGradientFn:
    """:func:`explicit_input_gradients` for the ensembles it supports, else :func:`autograd_input_gradients`."""
    return explicit_input_gradients if _layer_kinds(q_net) is not None else autograd_input_gradients


__all__ = [
    "autograd_input_gradients",
    "explicit_input_gradients",
    "input_gradient_fn",
    "mish_second_derivative",
]
