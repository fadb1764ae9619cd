"""Every form of Mish in one place: the one-``exp`` identity (:func:`mish_exp`), its compiled, fused kernel
(:func:`compiled_mish`, :class:`FusedMish`), the form with a finite second derivative
(:class:`TwiceDifferentiableMish`) and the eager in-place form of the no-grad chain (:func:`inference_mish`).

Eager ``F.mish`` evaluates ``x * tanh(log1p(exp(x)))`` with three transcendental functions and its
backward recomputes them; on CPU it costs about as much as the matmul before it. The compiled form uses
the identity ``tanh(softplus(x)) = n / (n + 2)``, ``n = e^x (e^x + 2)``: a single ``exp``, fused by
``torch.compile`` (inductor) into one kernel forward and one backward. Same function, float rounding aside
(max abs difference ~1e-6). If compilation is impossible (no C++ compiler, unsupported platform) it
falls back to ``F.mish`` with a warning.
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Callable, Iterator

import torch as th
from torch import nn
from torch.nn import functional as F
from torch.utils._python_dispatch import _get_current_dispatch_mode

# e^x (e^x + 2) overflows float32 beyond x ~ 44; from x = 20 on, n / (n + 2) == 1 in float32
EXP_CLAMP = 20.0


def mish_exp(x: th.Tensor) -> th.Tensor:
    """``mish(x) = x * n / (n + 2)``, ``n = e^x (e^x + 2)``: Mish with one ``exp`` (meant to be compiled)."""
    e = th.exp(x.clamp(max=EXP_CLAMP))
    n = e * (e + 2.0)
    return x * n / (n + 2.0)


def inference_mish(x: th.Tensor) -> th.Tensor:
    """Mish for the no-grad chain, eager and in place: ``x n / (n + 2)``, ``n = e^x (e^x + 2)`` (one ``exp``
    instead of ``F.mish``'s three transcendentals) on tensors of a few thousand elements or more; ``F.mish``
    below, where each extra kernel launch costs more than it saves. No autograd."""
    if x.numel() < 4096 or x.device.type != "cpu":  # on GPUs F.mish is one fused kernel already
        return F.mish(x)
    e = x.clamp(max=EXP_CLAMP).exp_()
    n = e.add(2.0).mul_(e)  # e^x (e^x + 2)
    return n.div_(n + 2.0).mul_(x)


# below this many elements the eager kernel wins: a compiled call's fixed overhead (guards) exceeds the saving
MIN_COMPILED_NUMEL = 16_384

_compiled: Callable[[th.Tensor], th.Tensor] | None = None
_failed = False
_eager_depth = 0


@contextlib.contextmanager
def eager_activations() -> Iterator[None]:
    """Mish as plain differentiable operations (:func:`mish_exp`) inside this block: for graphs that are
    differentiated twice (``create_graph=True``), which a compiled kernel's backward does not support and where
    ``F.mish``'s second derivative overflows."""
    global _eager_depth
    _eager_depth += 1
    try:
        yield
    finally:
        _eager_depth -= 1


def compiled_mish(x: th.Tensor) -> th.Tensor:
    """Mish through a fused kernel compiled once (dynamic shapes); ``F.mish`` if compilation fails."""
    global _compiled, _failed
    if th.compiler.is_compiling():  # inside a graph being compiled (compile_update): inline the one-exp form
        return mish_exp(x)
    # eager for small tensors, and under a dispatch mode (FLOP counters, profilers' modes), which would make
    # dynamo recompile for every mode until its cache limit, after which it runs mish_exp unfused
    if _eager_depth:  # differentiated twice: the one-exp form, whose second derivative stays finite
        return mish_exp(x)
    if _failed or x.numel() < MIN_COMPILED_NUMEL or _get_current_dispatch_mode() is not None:
        return F.mish(x)
    if _compiled is None:
        _compiled = th.compile(mish_exp, dynamic=True)
    try:
        return _compiled(x)
    except Exception as error:  # no compiler, unsupported backend: keep training, eagerly
        _failed = True
        warnings.warn(f"Compiled Mish unavailable ({type(error).__name__}: {error}); using eager F.mish", stacklevel=2)
        return F.mish(x)


class FusedMish(nn.Module):
    """``nn.Mish`` computed by :func:`compiled_mish` (a drop-in: no parameters, same state dict)."""

    def forward(self, x: th.Tensor) -> th.Tensor:
        return compiled_mish(x)


class TwiceDifferentiableMish(nn.Module):
    """``nn.Mish`` (``F.mish``), except inside :func:`eager_activations`, where it is :func:`mish_exp`: the second
    derivative of ``F.mish`` overflows to NaN for inputs above about 90 (0 * inf), which diverged long runs of the
    critic's similarity term; ``mish_exp`` clamps its ``exp``."""

    def forward(self, x: th.Tensor) -> th.Tensor:
        return mish_exp(x) if _eager_depth else F.mish(x)


def twice_differentiable(activation_fn: type[nn.Module]) -> type[nn.Module]:
    """The counterpart of an activation class that is safe to differentiate twice (``nn.Mish``), else the class."""
    return TwiceDifferentiableMish if activation_fn is nn.Mish else activation_fn


def fused_activation(activation_fn: type[nn.Module]) -> type[nn.Module]:
    """The compiled counterpart of an activation class where one exists (``nn.Mish``), else the class itself."""
    return FusedMish if activation_fn is nn.Mish else activation_fn


__all__: list[str] = [
    "EXP_CLAMP",
    "FusedMish",
    "TwiceDifferentiableMish",
    "compiled_mish",
    "eager_activations",
    "fused_activation",
    "mish_exp",
    "twice_differentiable",
]
