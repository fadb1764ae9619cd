"""``torch.compile`` for a training step's loss functions, in one wrapper chosen once when the model is set up.

:class:`CompiledLoss` is the loss function itself (eager), or its compiled graph (forward and backward, static
shapes), with the glue compilation needs kept here, out of the algorithm's update (as d3rlpy's
``CudaGraphWrapper``):

- ``fallback_random``: random draws are those of eager PyTorch, so on CPU the compiled update gives the
  eager update's numbers up to float rounding;
- on CUDA, CUDA graphs (inductor's ``triton.cudagraphs``): the first loss of a step marks a new graph
  iteration, and the statistics are copied out, since a later graph's run may reuse their memory;
- a compilation that fails (no C++ compiler, unsupported platform) leaves the eager function, with a warning.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any, Generic, ParamSpec

import torch as th

P = ParamSpec("P")
LossAndStats = tuple[th.Tensor, dict[str, th.Tensor]]


class CompiledLoss(Generic[P]):
    """A loss function ``(*tensors) -> (loss, stats)``, eager or compiled (chosen once, at construction).

    :param loss_fn: the eager loss function; ``loss`` keeps its graph (for ``backward``), ``stats`` are detached
    :param compile: compile it with ``torch.compile`` (``False``: call ``loss_fn`` itself)
    :param cudagraphs: also capture it as a CUDA graph (CUDA devices only)
    :param starts_step: the first loss of a training step: with CUDA graphs, a new graph iteration begins here,
        after the previous step's outputs have been consumed
    """

    def __init__(
        self, loss_fn: Callable[P, LossAndStats], compile: bool = False, cudagraphs: bool = False, starts_step: bool = False
    ) -> None:
        self.eager = loss_fn
        self.compile = compile
        self.cudagraphs = compile and cudagraphs
        self.starts_step = starts_step
        self.compiled: Callable[P, LossAndStats] | None = None
        if compile:
            options: dict[str, str | int | bool | Callable[..., Any]] = {"fallback_random": True}
            if self.cudagraphs:
                options["triton.cudagraphs"] = True
            self.compiled = th.compile(loss_fn, dynamic=False, options=options)
        # None until the first compiled call: True if it compiled, False if compilation failed (eager for good)
        self.compiled_ok: bool | None = None

    def __call__(self, *args: P.args, **kwargs: P.kwargs) -> LossAndStats:
        if self.compiled is None or self.compiled_ok is False:
            return self.eager(*args, **kwargs)
        if self.cudagraphs and self.starts_step:
            th.compiler.cudagraph_mark_step_begin()  # a new iteration: earlier graph outputs are consumed
        try:
            loss, stats = self.compiled(*args, **kwargs)
        except Exception as error:
            if self.compiled_ok:
                raise  # it ran compiled before: a real error, not a compiler one
            # tracing runs on fake tensors, so a failed compilation has drawn no random numbers and changed nothing
            self.compiled_ok = False
            warnings.warn(
                f"compile_update: compilation failed ({type(error).__name__}: {str(error)[:300]}); training eagerly",
                stacklevel=2,
            )
            return self.eager(*args, **kwargs)
        self.compiled_ok = True
        if self.cudagraphs:  # the next graph's run may reuse the memory of these outputs
            stats = {key: value.clone() for key, value in stats.items()}
        return loss, stats


__all__ = ["CompiledLoss", "LossAndStats"]
