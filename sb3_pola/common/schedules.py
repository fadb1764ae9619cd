"""Schedules of a hyperparameter over training, in SB3's convention: a function of the remaining progress."""

from __future__ import annotations

import math


class WarmupSchedule:
    """``0`` for the first ``warmup`` fraction of ``learn``, then a linear ramp to ``value`` over ``ramp``, then ``value``.

    Used for ``eta``: behaviour cloning while the critic is still far from its targets, then the Q term.
    Like SB3's schedules it is called with the remaining progress (1 at the start of ``learn``, 0 at the end),
    so fractions are of the ``total_timesteps`` that ``learn`` was given.

    :param value: the final value
    :param warmup: fraction of training at 0
    :param ramp: fraction of training over which the value rises linearly (0: a step)
    """

    def __init__(self, value: float, warmup: float = 0.1, ramp: float = 0.1) -> None:
        if not (0.0 <= warmup <= 1.0 and 0.0 <= ramp <= 1.0):
            raise ValueError(f"warmup and ramp must be fractions in [0, 1], got {warmup} and {ramp}")
        self.value, self.warmup, self.ramp = float(value), float(warmup), float(ramp)

    def __call__(self, progress_remaining: float) -> float:
        done = 1.0 - progress_remaining
        if done < self.warmup:
            return 0.0
        if self.ramp == 0.0 or done >= self.warmup + self.ramp:
            return self.value
        return self.value * (done - self.warmup) / self.ramp

    def __repr__(self) -> str:
        return f"WarmupSchedule(value={self.value}, warmup={self.warmup}, ramp={self.ramp})"


def warmup_schedule(value: float, warmup: float = 0.1, ramp: float = 0.1) -> WarmupSchedule:
    """:class:`WarmupSchedule` (SB3 style factory)."""
    return WarmupSchedule(value, warmup, ramp)


class CosineSchedule:
    """Cosine decay from ``initial`` to ``final`` (Diffusion-QL's learning-rate decay), optionally held at ``initial``
    for the first ``start`` fraction of ``learn`` and decayed over the rest (a warmup-stable-decay shape).

    Called with the remaining progress (1 at the start of ``learn``, 0 at the end), as SB3's schedules are:
    ``final + (initial - final) (1 + cos(pi x)) / 2`` with ``x = max(done - start, 0) / (1 - start)`` and
    ``done = 1 - progress_remaining``.

    :param initial: the value at the start
    :param final: the value at the end
    :param start: fraction of training held at ``initial`` before the decay begins (0: decay over all of ``learn``)
    """

    def __init__(self, initial: float, final: float = 0.0, start: float = 0.0) -> None:
        if initial < 0 or final < 0:
            raise ValueError(f"initial and final must be >= 0, got {initial} and {final}")
        if not 0.0 <= start < 1.0:
            raise ValueError(f"start must be a fraction in [0, 1), got {start}")
        self.initial, self.final, self.start = float(initial), float(final), float(start)

    def __call__(self, progress_remaining: float) -> float:
        done = min(max(1.0 - progress_remaining, 0.0), 1.0)
        x = max(done - self.start, 0.0) / (1.0 - self.start)
        return self.final + (self.initial - self.final) * 0.5 * (1.0 + math.cos(math.pi * x))

    def __repr__(self) -> str:
        return f"CosineSchedule(initial={self.initial}, final={self.final}, start={self.start})"


def cosine_schedule(initial: float, final: float = 0.0, start: float = 0.0) -> CosineSchedule:
    """:class:`CosineSchedule` (SB3 style factory)."""
    return CosineSchedule(initial, final, start)
