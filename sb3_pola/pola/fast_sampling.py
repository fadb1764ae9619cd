"""Fast forms of the diffusion actor's reverse chain (eq. 5), beside the readable :meth:`DiffusionActor.sample`.

Both compute what :meth:`~sb3_pola.pola.actor.DiffusionActor.sample` computes (float rounding aside;
``tests/test_reference_equivalence.py`` holds them to it), from the same parameters, with fewer operations:

- :func:`sample_chain`, the training form: differentiable and traceable by ``torch.compile``. The first
  layer is split by input block, so the state's projection is computed once per sample instead of once
  per step and every step's time embedding once per call instead of once per row; the schedule's
  coefficients are Python floats (constants of a compiled graph, no tensor indexing).
- :func:`sample_no_grad`, the inference form (``predict``, the critic's target): no autograd, the weights
  rearranged into an :class:`InferencePlan` (``W^T`` GEMM operands, the step's coefficients folded into the
  last layer's ``addmm`` and the clip, in-place updates), the eager Mish with one ``exp``, row chunks.

The inference plan cannot go stale, whichever way the parameters are written (an optimizer, ``load_state_dict``,
SB3's ``polyak_update`` through ``.data``, which bumps no version counter): a cached plan's weights are views of
the parameters' own storage, so every in-place write reaches them, and the few tensors computed from weights
(the time projection and the folded last bias) are reused only while their sources equal the snapshot they
were computed from (an exact comparison of a few small tensors per call).
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from typing import TYPE_CHECKING, NamedTuple

import torch as th
from torch import nn
from torch.nn import functional as F

from sb3_pola.common.activations import inference_mish
from sb3_pola.pola.actor import densest_sample

if TYPE_CHECKING:
    from sb3_pola.pola.actor import DiffusionActor

# rows per chunk of the no-grad chain: a chunk's [rows, width] float32 temporaries stay in cache and below
# glibc's mmap threshold (larger ones are fresh mappings, which makes every elementwise op slower)
INFERENCE_CHUNK = 256


def chain_noise(
    actor: DiffusionActor, features: th.Tensor, generator: th.Generator | None, deterministic: bool
) -> th.Tensor | None:
    """``[n + 1, B, A]`` noise of the chain, ``a_T`` last, drawn as :meth:`DiffusionActor.sample` draws it
    (``None`` for the deterministic chain, which draws nothing)."""
    if deterministic:
        return None
    shape = (actor.n_diffusion_steps + 1, features.shape[0], actor.action_dim)
    return th.randn(shape, device=features.device, dtype=features.dtype, generator=generator)


def sample_chain(
    actor: DiffusionActor, features: th.Tensor, generator: th.Generator | None = None, deterministic: bool = False
) -> th.Tensor:
    """:meth:`DiffusionActor.sample` with the first layer split by input block and float coefficients.

    Differentiable w.r.t. the parameters and ``features``, and traceable by ``torch.compile``.

    :param actor: the diffusion actor
    :param features: ``[B, F]`` state features
    :param generator: draws the chain's noise from this generator
    :param deterministic: the noise-free chain from ``a_T = 0``
    :return: ``[B, A]`` actions in ``[-1, 1]``
    """
    a_dim, t_dim = actor.action_dim, actor.time_embedding_dim
    weight = actor.input_layer.weight  # [H, A + time + F]
    # constant over the chain: the state's and every step's time projection, summed per step up front
    state_proj = F.linear(features, weight[:, a_dim + t_dim :], actor.input_layer.bias)  # [B, H]
    time_proj = F.linear(actor.time_mlp(actor.step_indices), weight[:, a_dim : a_dim + t_dim])  # [n, H]
    step_bias = state_proj.unsqueeze(0) + time_proj.unsqueeze(1)  # [n, B, H]
    w_action_t = weight[:, :a_dim].t()  # [A, H]
    noise = chain_noise(actor, features, generator, deterministic)
    if noise is None:
        noise = th.zeros((actor.n_diffusion_steps + 1, features.shape[0], a_dim), device=features.device, dtype=features.dtype)
    x = noise[-1]
    for t in reversed(range(actor.n_diffusion_steps)):
        eps = actor.trunk(th.addmm(step_bias[t], x, w_action_t))
        # NoiseSchedule.step with float coefficients
        recip, recipm1, coef1, coef2, sigma = actor.schedule.step_constants[t]
        x0 = (x * recip - eps * recipm1).clamp_(-1.0, 1.0)
        x_new = th.add(x0 * coef1, x, alpha=coef2)
        x = x_new.add_(noise[t], alpha=sigma) if t > 0 else x_new
    return x.clamp(-1.0, 1.0)


class InferencePlan(NamedTuple):
    """The actor's weights rearranged for :func:`sample_no_grad` (built per call by :func:`inference_plan`)."""

    w_state_t: th.Tensor  # [F, H]: the first layer's state block, transposed
    b_in: th.Tensor  # [H]: the first layer's bias
    w_action_t: th.Tensor  # [A, H]: the first layer's action block, transposed
    time_proj: th.Tensor  # [n, H]: each step's time embedding through the first layer
    hidden: list[tuple[th.Tensor, th.Tensor] | Callable[[th.Tensor], th.Tensor]]  # (bias, W^T) pairs, activations
    w_last_t: th.Tensor  # [H, A]: W^T of the last layer
    steps: list[tuple[float, th.Tensor, float, float, float, float]]  # per step: alpha, alpha b, c1 recip, c1, c2, sigma


# activations as plain functions: a module's call costs more than a ReLU on the few rows of a single predict. In place
# is safe: every input is a temporary of run_plan (an addmm's output, or the noise-free chain's row of the per-call
# step bias, read once)
_INFERENCE_ACTIVATIONS: dict[type[nn.Module], Callable[[th.Tensor], th.Tensor]] = {nn.Mish: inference_mish, nn.ReLU: th.relu_}


def inference_plan(actor: DiffusionActor, copy_weights: bool = False) -> InferencePlan:
    """The current weights of ``actor`` as an :class:`InferencePlan`.

    :param actor: the diffusion actor
    :param copy_weights: copy every ``W^T`` into a contiguous tensor (worth it when the plan serves a large
        batch, as the critic's target in training does) instead of using a transposed view
    """

    def transposed(w: th.Tensor) -> th.Tensor:
        return w.t().contiguous() if copy_weights else w.t()

    a_dim, t_dim = actor.action_dim, actor.time_embedding_dim
    weight = actor.input_layer.weight  # [H, A + time + F]
    with th.no_grad():  # no detach needed: nothing here records a graph
        time_proj = F.linear(actor.time_mlp(actor.step_indices), weight[:, a_dim : a_dim + t_dim])
        modules = list(actor.trunk)
        hidden: list[tuple[th.Tensor, th.Tensor] | Callable[[th.Tensor], th.Tensor]] = [
            (m.bias, transposed(m.weight)) if isinstance(m, nn.Linear) else _INFERENCE_ACTIVATIONS.get(type(m), m)
            for m in modules[:-1]
        ]
        last = modules[-1]
        assert isinstance(last, nn.Linear)
        # the last layer with the reverse step folded in (x0 clipped): with eps = W h + b,
        # c1 x0 = clip(c1 recip x - c1 recipm1 (W h + b), -c1, c1); per step: W^T scale alpha_t, bias_t = alpha_t b
        constants = actor.schedule.step_constants
        alphas = [-recipm1 * coef1 for _, recipm1, coef1, _, _ in constants]
        biases = (th.tensor(alphas, device=last.bias.device, dtype=last.bias.dtype)[:, None] * last.bias).unbind(0)
        steps = [
            (alpha, bias_t, recip * coef1, coef1, coef2, sigma)
            for alpha, bias_t, (recip, _, coef1, coef2, sigma) in zip(alphas, biases, constants, strict=True)
        ]
        return InferencePlan(
            w_state_t=transposed(weight[:, a_dim + t_dim :]),
            b_in=actor.input_layer.bias,
            w_action_t=transposed(weight[:, :a_dim]),
            time_proj=time_proj,
            hidden=hidden,
            w_last_t=transposed(last.weight),
            steps=steps,
        )


class _CachedPlan(NamedTuple):
    plan: InferencePlan
    params: list[nn.Parameter]  # the parameter objects never change; their values and storage may
    storage: list[int]  # data_ptr of every parameter: a moved or replaced parameter leaves the views behind
    sources: list[tuple[th.Tensor, th.Tensor]]  # (live tensor, its value when the plan was built)


_view_plans: weakref.WeakKeyDictionary[DiffusionActor, _CachedPlan] = weakref.WeakKeyDictionary()


def _computed_from(actor: DiffusionActor) -> list[th.Tensor]:
    """The parameters :func:`inference_plan` computes with (the rest it only views): time MLP, time block, last bias."""
    a_dim, t_dim = actor.action_dim, actor.time_embedding_dim
    last = actor.trunk[-1]
    assert isinstance(last, nn.Linear)
    return [*actor.time_mlp.parameters(), actor.input_layer.weight[:, a_dim : a_dim + t_dim], last.bias]


def cached_view_plan(actor: DiffusionActor) -> InferencePlan:
    """:func:`inference_plan` of the current weights (``copy_weights=False``), rebuilt only when it would differ."""
    with th.no_grad():
        cached = _view_plans.get(actor)
        if (
            cached is None
            or cached.storage != [p.data_ptr() for p in cached.params]
            or not all(th.equal(live, seen) for live, seen in cached.sources)
        ):
            params = list(actor.parameters())
            sources = [(t, t.clone()) for t in _computed_from(actor)]
            cached = _CachedPlan(inference_plan(actor), params, [p.data_ptr() for p in params], sources)
            _view_plans[actor] = cached
        return cached.plan


def sample_no_grad(
    actor: DiffusionActor,
    features: th.Tensor,
    generator: th.Generator | None = None,
    deterministic: bool = False,
    copy_weights: bool = False,
    noise: th.Tensor | None = None,
) -> th.Tensor:
    """:meth:`DiffusionActor.sample` without autograd, through an :class:`InferencePlan` of the current weights.

    :param actor: the diffusion actor
    :param features: ``[B, F]`` state features
    :param generator: draws the chain's noise from this generator
    :param deterministic: the noise-free chain from ``a_T = 0``
    :param copy_weights: build the plan with contiguous copies of the weights (see :func:`inference_plan`);
        ``False``: the cached plan of views (:func:`cached_view_plan`)
    :param noise: ``[n + 1, B, A]`` the chain's noise (``a_T`` last), given instead of drawn
    :return: ``[B, A]`` actions in ``[-1, 1]``
    """
    with th.no_grad():
        plan = inference_plan(actor, copy_weights=True) if copy_weights else cached_view_plan(actor)
        if noise is None:
            noise = chain_noise(actor, features, generator, deterministic)
        if features.shape[0] <= INFERENCE_CHUNK:
            return run_plan(plan, features, noise)
        # rows are independent: chunks keep every temporary in cache
        chunks = features.split(INFERENCE_CHUNK)
        noises = [None] * len(chunks) if noise is None else noise.split(INFERENCE_CHUNK, dim=1)
        return th.cat([run_plan(plan, f, z) for f, z in zip(chunks, noises, strict=True)])


def run_plan(plan: InferencePlan, features: th.Tensor, noise: th.Tensor | None) -> th.Tensor:
    """The reverse chain from ``plan``'s weights: ``noise`` ``[n + 1, B, A]`` (``a_T`` last), ``None`` from ``a_T = 0``."""
    state_proj = th.addmm(plan.b_in, features, plan.w_state_t)  # [B, H]
    step_bias = state_proj.unsqueeze(0) + plan.time_proj.unsqueeze(1)  # [n, B, H]
    x = None if noise is None else noise[-1]
    for t in reversed(range(len(plan.steps))):
        h = step_bias[t] if x is None else th.addmm(step_bias[t], x, plan.w_action_t)
        for layer in plan.hidden:
            h = th.addmm(layer[0], h, layer[1]) if isinstance(layer, tuple) else layer(h)
        alpha, bias_t, x_coef, coef1, coef2, sigma = plan.steps[t]
        # x_{t-1} = c1 clip(recip x - recipm1 eps, -1, 1) + c2 x (+ sigma_t z)
        base = bias_t if x is None else th.add(bias_t, x, alpha=x_coef)
        x_new = th.addmm(base, h, plan.w_last_t, alpha=alpha).clamp_(-coef1, coef1)
        if x is not None:
            x_new.add_(x, alpha=coef2)
        if noise is not None and t > 0:
            x_new.add_(noise[t], alpha=sigma)
        x = x_new
    assert x is not None
    return x.clamp_(-1.0, 1.0)


def kernel_mode_fast(samples: th.Tensor, bandwidth: float, n_iterations: int = 10) -> th.Tensor:
    """:func:`~sb3_pola.pola.actor.kernel_mode` with the mean shift carried in the samples' weights.

    Every mean-shift point is a convex combination ``x = w S`` of the samples ``S`` (the start is one of them), so
    ``x S^T = w G`` with the Gram matrix ``G = S S^T`` computed once: a step is one ``baddbmm`` and a softmax
    instead of five operations, and ``x`` is formed once at the end. The start is the readable form's own
    (:func:`~sb3_pola.pola.actor.densest_sample`), so a near tie between two starts resolves the same way.

    :param samples: ``[B, K, A]`` candidate actions of each row
    :param bandwidth: the kernel's standard deviation, in action units
    :param n_iterations: mean-shift steps after the start
    :return: ``[B, A]``
    """
    scale = -0.5 / bandwidth**2
    start = densest_sample(samples, scale)  # [B]
    gram = samples @ samples.transpose(1, 2)  # [B, K, K]
    sq_norm = scale * samples.pow(2).sum(dim=-1).unsqueeze(1)  # [B, 1, K]
    weights = sq_norm.new_zeros(sq_norm.shape).scatter_(2, start.view(-1, 1, 1), 1.0)  # [B, 1, K]: the start, one-hot
    for _ in range(n_iterations):
        # the softmax over k of (-|a_k|^2 + 2 a_k.x) / 2h^2, with a_k.x = (w G)_k
        weights = th.softmax(th.baddbmm(sq_norm, weights, gram, alpha=-2.0 * scale), dim=-1)  # [B, 1, K]
    return (weights @ samples).squeeze(1)


__all__ = [
    "INFERENCE_CHUNK",
    "InferencePlan",
    "cached_view_plan",
    "inference_mish",
    "inference_plan",
    "kernel_mode_fast",
    "run_plan",
    "sample_chain",
    "sample_no_grad",
]
