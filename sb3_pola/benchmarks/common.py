"""Shared pieces of the benchmarks: synthetic in-memory datasets, models built on them, timers, matmul rooflines."""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import torch as th
from stable_baselines3.common.logger import configure
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils.flop_counter import FlopCounterMode

from sb3_pola.common.datasets import OfflineDataset

if TYPE_CHECKING:
    from sb3_pola.pola import POLA

# (obs_dim, act_dim, Gymnasium id whose termination rule the look-ahead uses)
TASK_SIZES: dict[str, tuple[int, int, str]] = {"hopper": (11, 3, "Hopper-v5"), "halfcheetah": (17, 6, "HalfCheetah-v5")}


def make_pola(data: OfflineDataset, device: str = "cpu", seed: int = 0, **kwargs: Any) -> POLA:
    """A POLA model on an in-memory dataset, ready for ``train``: buffer set up, dynamics frozen as initialised, the
    data-dependent settings of ``learn`` made (``_before_training``).

    The dynamics model is not fitted (its cost per step does not depend on its weights), so the
    benchmark measures the gradient step alone.

    :param data: the dataset
    :param device: torch device
    :param seed: seed of the networks
    :param kwargs: POLA constructor arguments
    :return: the model
    """
    from sb3_pola.pola import POLA

    model = POLA("MlpPolicy", dataset=data, seed=seed, device=device, **kwargs)
    model.set_logger(configure(None, [""]))
    if model.policy.dynamics is not None:
        model.policy.dynamics.freeze()
        model.policy.dynamics_fitted.fill_(True)  # type: ignore[operator]
    # what learn() sets up before the first step (the data's returns for the target floor, the gate and the critics'
    # start), so that the timed step is the one training takes; the frozen dynamics model is not fitted
    model._before_training()
    return model


def synchronize(device: th.device | str) -> None:
    if th.device(device).type == "cuda":
        th.cuda.synchronize()


def median_time(fn: Callable[[], Any], reps: int, device: th.device | str = "cpu", warmup: int = 1) -> float:
    """Median wall time of ``fn`` over ``reps`` calls after ``warmup`` calls, in seconds."""
    for _ in range(warmup):
        fn()
    synchronize(device)
    times = []
    for _ in range(reps):
        start = time.perf_counter()
        fn()
        synchronize(device)
        times.append(time.perf_counter() - start)
    return float(np.median(times))


_MATMULS = {th.ops.aten.mm.default, th.ops.aten.bmm.default, th.ops.aten.addmm.default, th.ops.aten.baddbmm.default}


class MatmulRecorder(TorchDispatchMode):
    """Records the matmuls a computation runs: op, and size/stride/dtype of every tensor argument."""

    def __init__(self) -> None:
        super().__init__()
        self.calls: Counter[tuple[Any, ...]] = Counter()

    def __torch_dispatch__(self, func: Any, types: Any, args: Any = (), kwargs: Any = None) -> Any:
        if func in _MATMULS:
            key = tuple((tuple(a.shape), tuple(a.stride()), a.dtype) if isinstance(a, th.Tensor) else a for a in args)
            self.calls[(func, key)] += 1
        return func(*args, **(kwargs or {}))


def _matmul_flops(func: Any, key: tuple[Any, ...]) -> int:
    # the two matrix operands are the last two tensors: [.., m, k] @ [.., k, n]
    shapes = [k[0] for k in key if isinstance(k, tuple)]
    a, b = shapes[-2], shapes[-1]
    batch = a[0] if len(a) == 3 else 1
    return 2 * batch * a[-2] * a[-1] * b[-1]


def _strided_randn(size: tuple[int, ...], stride: tuple[int, ...], dtype: th.dtype, device: th.device | str) -> th.Tensor:
    """A random tensor with this size and stride (strides may be 0: expanded views, as the step uses them)."""
    storage = 1 + sum((n - 1) * s for n, s in zip(size, stride, strict=True))
    return th.randn(storage, dtype=dtype, device=device).as_strided(size, stride)


def matmul_replay(calls: Counter[tuple[Any, ...]], device: th.device | str) -> tuple[Callable[[], None], int]:
    """A function running the recorded matmuls alone (same shapes, strides and counts), and their FLOPs.

    Timed next to the step, it gives the machine's matmul FLOP/s on the step's own shapes: the roofline's denominator.
    """
    work = []
    total_flops = 0
    for (func, key), count in calls.items():
        args = [_strided_randn(k[0], k[1], k[2], device) if isinstance(k, tuple) else k for k in key]
        work.append((func, args, count))
        total_flops += count * _matmul_flops(func, key)

    def replay() -> None:
        for func, args, count in work:
            for _ in range(count):
                func(*args)

    return replay, total_flops


def count_flops(fn: Callable[[], Any]) -> tuple[int, Counter[tuple[Any, ...]]]:
    """FLOPs of one call of ``fn`` (``torch.utils.flop_counter``) and the matmuls it ran."""
    recorder = MatmulRecorder()
    with FlopCounterMode(display=False) as counter, recorder:
        fn()
    return int(counter.get_total_flops()), recorder.calls
